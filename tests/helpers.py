"""Test helpers: config writers and a minimal MAVLink peer on real sockets."""

from __future__ import annotations

import asyncio
import itertools
import math
import os
import socket
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

os.environ["MAVLINK20"] = "1"
from pymavlink.dialects.v20 import ardupilotmega as dialect

REPO = Path(__file__).resolve().parent.parent

RIG_320 = {
    "width": 320,
    "height": 240,
    "fx": 200.0,
    "fy": 200.0,
    "cx": 159.5,
    "cy": 119.5,
    "baseline_m": 0.12,
    "doffs": 0.0,
}


def write_yaml(path: Path, data: Any) -> Path:
    path.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    return path


def write_rectified_calibration(folder: Path, rig: dict[str, Any] | None = None) -> Path:
    return write_yaml(folder / "calib.yaml", {"version": 1, "rectified": rig or RIG_320})


def synthetic_config(
    folder: Path,
    connection: str,
    *,
    rig: dict[str, Any] | None = None,
    source: dict[str, Any] | None = None,
    heads: list[dict[str, Any]] | None = None,
    pipeline: dict[str, Any] | None = None,
    rate_hz: float = 15.0,
    mavlink: dict[str, Any] | None = None,
    sections: dict[str, Any] | None = None,
) -> Path:
    """A complete config with one synthetic head (or the given heads) and the given link.

    ``sections`` adds or replaces whole top-level sections (``avoidance``, ``perception``).
    """
    calibration = write_rectified_calibration(folder, rig)
    head = {
        "name": "front",
        "calibration": str(calibration),
        "source": source or {"kind": "synthetic", "fps": 15, "seed": 3},
    }
    config = {
        "version": 1,
        "heads": heads or [head],
        "mavlink": {
            "connection": connection,
            "system_id": 7,
            "obstacle_distance": {
                "rate_hz": rate_hz,
                "min_distance_cm": 20,
                "max_distance_cm": 2000,
            },
            **(mavlink or {}),
        },
        "pipeline": pipeline or {"max_age_ms": 400, "log_interval_s": 1.0},
    } | (sections or {})
    return write_yaml(folder / "avoidd.yaml", config)


@dataclass
class Received:
    t_s: float
    message: Any


@dataclass
class MavlinkPeer:
    """Decodes every MAVLink message that reaches it and remembers it with its arrival time."""

    messages: list[Received] = field(default_factory=list)
    parse_errors: int = 0

    def __post_init__(self) -> None:
        self._mav = dialect.MAVLink(None, srcSystem=1, srcComponent=1)
        self._mav.robust_parsing = True
        self.raw_first_bytes: list[int] = []
        self.raw: list[bytes] = []

    def feed(self, data: bytes) -> None:
        if data:
            self.raw_first_bytes.append(data[0])
            self.raw.append(data)
        for message in self._mav.parse_buffer(data) or []:
            if message.get_type() == "BAD_DATA":
                self.parse_errors += 1
            else:
                self.messages.append(Received(time.monotonic(), message))

    def of_type(self, kind: str) -> list[Any]:
        return [r.message for r in self.messages if r.message.get_type() == kind]

    def times_of(self, kind: str) -> list[float]:
        return [r.t_s for r in self.messages if r.message.get_type() == kind]

    def heartbeat_bytes(self) -> bytes:
        msg = self._mav.heartbeat_encode(
            dialect.MAV_TYPE_QUADROTOR, dialect.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4
        )
        return bytes(msg.pack(self._mav))


class LoopbackSocket(asyncio.DatagramProtocol):
    """A UDP socket on loopback: its transport, its port, closing it."""

    transport: Any = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        # Python 3.11's selector transport does not subclass DatagramTransport.
        self.transport = transport

    @property
    def port(self) -> int:
        assert self.transport is not None
        return int(self.transport.get_extra_info("sockname")[1])

    def close(self) -> None:
        if self.transport is not None:
            self.transport.close()


class UdpPeer(MavlinkPeer, LoopbackSocket):
    """A MAVLink peer on a real loopback UDP socket."""

    def __init__(self) -> None:
        MavlinkPeer.__init__(self)
        self.last_addr: Any = None

    def datagram_received(self, data: bytes, addr: Any) -> None:
        self.last_addr = addr
        self.feed(data)


async def open_udp_peer(host: str = "127.0.0.1", port: int = 0) -> UdpPeer:
    loop = asyncio.get_running_loop()
    _, peer = await loop.create_datagram_endpoint(UdpPeer, local_addr=(host, port))
    return peer


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


async def wait_for(predicate: Any, timeout_s: float, step_s: float = 0.02) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        await asyncio.sleep(step_s)
    return bool(predicate())


async def start_daemon(config_path: Path) -> tuple[Any, asyncio.Task[int]]:
    """Load a config and run the daemon in this event loop."""
    from avoidd.daemon import Daemon
    from avoidd.loading import load_all

    config, calibrations = load_all(config_path)
    daemon = Daemon(config, calibrations)
    return daemon, asyncio.create_task(daemon.run())


async def stop_daemon(daemon: Any, task: asyncio.Task[int]) -> None:
    """Stop a daemon started by :func:`start_daemon` and check it exited cleanly.

    The bound is generous: a head thread in the middle of a frame on a machine whose cores are
    all busy (a CI run beside a simulation batch) took more than 10 s to be joined.
    """
    daemon.stop()
    assert await asyncio.wait_for(task, timeout=30.0) == 0


def noisy_grey_pair(scene: Any, rig: Any, seed: int, sigma: float) -> tuple[Any, Any, Any]:
    """Render a synthetic scene and return its grey views with sensor noise, and the truth."""
    import numpy as np

    from avoidd.sources.scene import render_pair, to_uint8
    from avoidd.vision.preprocess import to_grey

    rendered = render_pair(scene, rig)
    rng = np.random.default_rng(seed)
    views = [
        to_grey(to_uint8(view, rng.normal(0.0, sigma, view.shape).astype(np.float32)))
        for view in (rendered.left, rendered.right)
    ]
    return views[0], views[1], rendered.truth


class UdpHub(LoopbackSocket):
    """A tiny MAVLink router on loopback: every datagram goes to every other peer heard so far.

    Like mavlink-router's UDP server endpoints, it lets a ground-station tool, avoidd and an
    autopilot all share one port (``udpout:127.0.0.1:<port>`` for each).
    """

    def __init__(self) -> None:
        self.peers: list[Any] = []

    def datagram_received(self, data: bytes, addr: Any) -> None:
        if addr not in self.peers:
            self.peers.append(addr)
        assert self.transport is not None
        for peer in self.peers:
            if peer != addr:
                self.transport.sendto(data, peer)


async def start_hub() -> UdpHub:
    loop = asyncio.get_running_loop()
    _, hub = await loop.create_datagram_endpoint(UdpHub, local_addr=("127.0.0.1", 0))
    return hub


def great_circle_ne(
    origin_lat_deg: float, origin_lon_deg: float, lat_deg: float, lon_deg: float
) -> tuple[float, float]:
    """North and east of a point from an origin by haversine distance and initial bearing.

    An oracle independent of avoidd's flat projection (WGS-84 equatorial radius).
    """
    phi1, phi2 = math.radians(origin_lat_deg), math.radians(lat_deg)
    d_lambda = math.radians(lon_deg - origin_lon_deg)
    h = math.sin((phi2 - phi1) / 2) ** 2
    h += math.cos(phi1) * math.cos(phi2) * math.sin(d_lambda / 2) ** 2
    distance_m = 2 * 6378137.0 * math.asin(math.sqrt(h))
    bearing = math.atan2(
        math.sin(d_lambda) * math.cos(phi2),
        math.cos(phi1) * math.sin(phi2) - math.sin(phi1) * math.cos(phi2) * math.cos(d_lambda),
    )
    return distance_m * math.cos(bearing), distance_m * math.sin(bearing)


async def _beat_generic(peer: UdpPeer, daemon: Any, system_id: int) -> None:
    mav = dialect.MAVLink(None, srcSystem=system_id, srcComponent=1)
    heartbeat = bytes(
        mav.heartbeat_encode(
            dialect.MAV_TYPE_QUADROTOR, dialect.MAV_AUTOPILOT_GENERIC, 0, 0, 4
        ).pack(mav)
    )
    while getattr(daemon.link.transport, "socket_fileno", lambda: None)() is None:
        await asyncio.sleep(0.02)
    port = daemon.link.transport.local_port
    while True:
        peer.transport.sendto(heartbeat, ("127.0.0.1", port))
        await asyncio.sleep(0.5)


def beat_as_generic_autopilot(peer: UdpPeer, daemon: Any, system_id: int = 7) -> asyncio.Task[None]:
    """Make ``peer`` an autopilot that is neither ArduPilot nor PX4 for a ``udpout`` daemon.

    It sends the daemon's socket a MAV_AUTOPILOT_GENERIC heartbeat twice a second (cancel the
    task to stop): such an autopilot gets DISTANCE_SENSOR whenever it is enabled.
    """
    return asyncio.create_task(_beat_generic(peer, daemon, system_id))


def obstacle_distance_times(autopilot: Any, start_ns: int, end_ns: int) -> list[float]:
    """When a mock autopilot decoded each OBSTACLE_DISTANCE in a window (monotonic seconds)."""
    return [
        r.received_ns / 1e9
        for r in autopilot.recorded
        if r.message.get_type() == "OBSTACLE_DISTANCE" and start_ns <= r.received_ns <= end_ns
    ]


@dataclass
class Flow:
    """OBSTACLE_DISTANCE as an autopilot heard it over a window: its rate and longest gap."""

    rate_hz: float
    longest_gap_s: float
    longest_gap_at_s: float = math.nan
    """When the longest gap began, from the start of the window."""

    @classmethod
    def of(cls, autopilot: Any, start_ns: int, end_ns: int) -> Flow:
        times = obstacle_distance_times(autopilot, start_ns, end_ns)
        gaps = [(b - a, a) for a, b in itertools.pairwise(times)]
        window_s = max((end_ns - start_ns) / 1e9, 1e-9)
        gap_s, at_s = max(gaps, default=(math.inf, math.nan))
        return cls(len(times) / window_s, gap_s, at_s - start_ns / 1e9)

    def kept_up_with(self, control: Flow) -> bool:
        """Whether this window's flow is as good as a control window's on the same machine.

        A loaded machine (two busy loops, a simulation beside) slows the daemon with or
        without the fault: the fault's window is held to the control window measured just
        before it (at least 60% of its rate, a longest gap at most three times its own), never
        to less than what the autopilot needs (a message at least every 0.5 s, after which
        both autopilots drop the data).
        """
        gap_bound_s = max(0.5, 3.0 * control.longest_gap_s + 0.1)
        return self.rate_hz >= 0.6 * control.rate_hz and self.longest_gap_s <= gap_bound_s

    def __str__(self) -> str:
        return (
            f"{self.rate_hz:.1f} Hz, longest gap {self.longest_gap_s:.3f} s "
            f"(at {self.longest_gap_at_s:.1f} s)"
        )


def elsewhere() -> None:
    """``preexec_fn`` of a process that stands for another machine (a flooder, web clients).

    Niced, so that on a loaded machine it takes the CPU left over rather than the daemon's
    share: on a vehicle the stranger's flood or the viewers' browsers run on other computers.
    """
    os.nice(10)
