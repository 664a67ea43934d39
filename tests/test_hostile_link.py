"""Strangers on avoidd's ``udpin`` port (issue 52, items 4 and 7): they cannot become the
autopilot, and their flood does not starve what the autopilot receives.

Real sockets on loopback. The autopilot is the mock on 127.0.0.1 (``udpout`` to avoidd's port,
as ArduPilot SITL's SERIAL1); a stranger sends from 127.0.0.2 (the whole of 127/8 is
loopback), so that ``mavlink.autopilot_address: 127.0.0.1`` tells them apart while the
autopilot may come back from another port. Everything is asserted from the two far ends:
what the mock autopilot heard, and what reached the stranger's socket (nothing).
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from avoidd.errors import ConfigError
from avoidd.loading import load_all
from avoidd.mavlink import codec as mav
from avoidd.mavlink.mock_autopilot import MockAutopilot
from avoidd.mavlink.senders import AddressPin
from avoidd.mavlink.signing import wall_timestamp
from tests.helpers import REPO, Flow, free_udp_port, synthetic_config, wait_for
from tests.helpers import start_daemon as start
from tests.helpers import stop_daemon as stop

KEY = bytes(range(40, 72))
RATE_HZ = 15.0


class Stranger:
    """A socket on 127.0.0.2 that sends forged autopilot heartbeats and records what it gets."""

    def __init__(self, target_port: int, system_id: int = 7, key: bytes | None = None) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.2", 0))
        self.sock.setblocking(False)
        self.target = ("127.0.0.1", target_port)
        self.codec = mav.Codec(system_id, mav.MAV_COMP_ID_AUTOPILOT1)
        if key is not None:
            self.codec.enable_signing(key, wall_timestamp(), lambda _msg_id: False)
        self.received: list[bytes] = []
        self._task: asyncio.Task[None] | None = None

    def heartbeat(self) -> bytes:
        base = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        return self.codec.pack(
            self.codec.build(
                "HEARTBEAT", mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_ARDUPILOTMEGA, base, 4, 4
            )
        )

    def start(self, hz: float = 10.0) -> None:
        async def run() -> None:
            while True:
                self.sock.sendto(self.heartbeat(), self.target)
                self._drain()
                await asyncio.sleep(1.0 / hz)

        self._task = asyncio.create_task(run())

    def _drain(self) -> None:
        while True:
            try:
                self.received.append(self.sock.recv(65536))
            except BlockingIOError:
                return

    async def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()
            await asyncio.gather(self._task, return_exceptions=True)
        self._drain()
        self.sock.close()


def _od_count(autopilot: MockAutopilot) -> int:
    return len(autopilot.of_type("OBSTACLE_DISTANCE"))


async def _adoption_case(
    tmp_path: Path, mavlink: dict[str, Any], stranger: Stranger, autopilot: MockAutopilot
) -> Any:
    """Start the daemon, the stranger first, then the real autopilot: avoidd must pick it."""
    port = stranger.target[1]
    daemon, task = await start(
        synthetic_config(tmp_path, f"udpin:127.0.0.1:{port}", mavlink=mavlink)
    )
    try:
        stranger.start()
        assert await wait_for(lambda: daemon.link.bytes_received or daemon.link.strangers, 10.0)
        await asyncio.sleep(1.0)  # the stranger's heartbeats come first, ten a second
        await autopilot.start(f"udpout:127.0.0.1:{port}")
        assert await wait_for(lambda: _od_count(autopilot) >= 10, 20.0), dict(daemon.link.sent)
        assert daemon.vehicle.link_up and daemon.vehicle.system_id == autopilot.system_id
        assert daemon.link.autopilot_sender[0] == "127.0.0.1"
        await asyncio.sleep(0.5)
    finally:
        await stop(daemon, task)
        await stranger.stop()
        await autopilot.stop()
    assert stranger.received == [], f"{len(stranger.received)} datagrams reached the stranger"
    return daemon


async def test_a_pinned_address_is_the_only_autopilot_even_through_a_reboot(
    tmp_path: Path,
) -> None:
    port = free_udp_port()
    stranger = Stranger(port)
    mavlink = {"autopilot_address": "127.0.0.1", "link_timeout_s": 1.0}
    config = synthetic_config(tmp_path, f"udpin:127.0.0.1:{port}", mavlink=mavlink)
    daemon, task = await start(config)
    first, second = MockAutopilot(system_id=7), MockAutopilot(system_id=7)
    try:
        stranger.start()
        await asyncio.sleep(1.0)  # the stranger speaks first
        assert daemon.vehicle.system_id == 7 and not daemon.vehicle.link_up
        await first.start(f"udpout:127.0.0.1:{port}")
        assert await wait_for(lambda: _od_count(first) >= 5, 20.0)
        # The autopilot reboots: silent for three link timeouts, the stranger goes on.
        await first.stop()
        assert await wait_for(lambda: not daemon.vehicle.link_up, 10.0)
        await asyncio.sleep(2.0)
        assert not daemon.vehicle.link_up and daemon.link.autopilot_sender[0] == "127.0.0.1"
        # It comes back from another port of its address: taken at once.
        await second.start(f"udpout:127.0.0.1:{port}")
        assert await wait_for(lambda: _od_count(second) >= 5, 20.0)
        assert daemon.vehicle.link_up
    finally:
        await stop(daemon, task)
        await stranger.stop()
        await first.stop()
        await second.stop()
    assert stranger.received == [], f"{len(stranger.received)} datagrams reached the stranger"
    (name,) = daemon.link.strangers
    assert name.startswith("127.0.0.2:") and daemon.link.strangers[name].datagrams >= 30
    assert daemon.link.received["HEARTBEAT"] == first.sent["HEARTBEAT"] + second.sent["HEARTBEAT"]


async def test_on_a_signed_link_an_unsigned_heartbeat_never_adopts(tmp_path: Path) -> None:
    key_file = tmp_path / "key"
    key_file.write_bytes(KEY)
    # The worst case: the allow-list lets unsigned heartbeats through to avoidd's handlers.
    signing = {"key_file": str(key_file), "allow_unsigned": ["HEARTBEAT", "RADIO_STATUS"]}
    port = free_udp_port()
    daemon = await _adoption_case(
        tmp_path,
        {"system_id": "auto", "signing": signing},
        Stranger(port, system_id=42),
        MockAutopilot(system_id=7, key=KEY),
    )
    assert daemon.vehicle.system_id == 7


async def test_a_stranger_with_a_wrong_key_never_adopts(tmp_path: Path) -> None:
    key_file = tmp_path / "key"
    key_file.write_bytes(KEY)
    port = free_udp_port()
    daemon = await _adoption_case(
        tmp_path,
        {"system_id": "auto", "signing": {"key_file": str(key_file)}},
        Stranger(port, system_id=42, key=bytes(32)),
        MockAutopilot(system_id=7, key=KEY),
    )
    assert daemon.link.signature_rejects >= 10


async def test_with_a_fixed_system_id_another_systems_heartbeat_gets_nothing(
    tmp_path: Path,
) -> None:
    port = free_udp_port()
    await _adoption_case(
        tmp_path, {"system_id": 7}, Stranger(port, system_id=9), MockAutopilot(system_id=7)
    )


_FLOOD = """
import os, socket, sys, time
os.environ["MAVLINK20"] = "1"
from pymavlink.dialects.v20 import ardupilotmega as dialect
port, rate, seconds = int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3])
mav = dialect.MAVLink(None, srcSystem=7, srcComponent=1)
frame = mav.attitude_encode(1000, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0).pack(mav)
sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
sock.bind(("127.0.0.2", 0))
start, sent = time.monotonic(), 0
while sent < rate * seconds and time.monotonic() - start < 3 * seconds:
    due = min(int((time.monotonic() - start) * rate), int(rate * seconds))
    while sent < due:
        sock.sendto(frame, ("127.0.0.1", port))
        sent += 1
    time.sleep(0.001)
print(sent, time.monotonic() - start)
"""


async def _flooding(
    autopilot: MockAutopilot, daemon: Any, port: int
) -> tuple[Flow, int, int, float]:
    """Flood ``port`` (20,000 datagrams a second for 5 s, from 127.0.0.2) and watch.

    Returns:
        What the autopilot heard meanwhile, how often the link was seen down (ten times a
        second), the datagrams sent and how long sending them took.
    """
    flood = await asyncio.create_subprocess_exec(
        sys.executable, "-c", _FLOOD, str(port), "20000", "5", cwd=REPO, stdout=subprocess.PIPE
    )
    start_ns = time.monotonic_ns()
    link_down = 0
    while flood.returncode is None:
        link_down += not daemon.vehicle.link_up
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(flood.wait(), 0.1)
    end_ns = time.monotonic_ns()
    out, _ = await flood.communicate()
    sent, took_s = out.split()
    return Flow.of(autopilot, start_ns, end_ns), link_down, int(sent), float(took_s)


async def test_a_flood_of_20000_messages_a_second_leaves_obstacle_distance_at_its_rate(
    tmp_path: Path,
) -> None:
    port = free_udp_port()
    config = synthetic_config(tmp_path, f"udpin:127.0.0.1:{port}", rate_hz=RATE_HZ)
    daemon, task = await start(config)
    autopilot = MockAutopilot(system_id=7, mode="GUIDED")
    try:
        # Its link is open once it tries to send (and drops: nobody to send to yet).
        assert await wait_for(lambda: daemon.link.dropped["HEARTBEAT"] >= 1, 20.0)
        await autopilot.start(f"udpout:127.0.0.1:{port}")
        assert await wait_for(lambda: _od_count(autopilot) >= 15, 20.0)
        # The control: the same flood, for as long, at a socket of this test that is never
        # read, so that the machine carries the same load while avoidd hears nothing of it.
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as deaf:
            deaf.bind(("127.0.0.1", 0))
            control, _, sham, _ = await _flooding(autopilot, daemon, deaf.getsockname()[1])
        assert sham == 100_000
        heartbeats_before = autopilot.sent["HEARTBEAT"]
        during, link_down, sent, took_s = await _flooding(autopilot, daemon, port)
        assert sent == 100_000
        print(
            f"flood: {sent} datagrams in {took_s:.2f} s; OBSTACLE_DISTANCE {during} (the same "
            f"flood elsewhere: {control})"
        )
        # What the autopilot heard while the flood lasted: OBSTACLE_DISTANCE at its rate.
        assert during.kept_up_with(control), (during, control)
        assert link_down == 0 and daemon.vehicle.link_up
        await autopilot.stop()
        heard = autopilot.sent["HEARTBEAT"]
        assert heard - heartbeats_before >= 4
        # Every heartbeat of the autopilot was heard: none lost in a full socket.
        assert await wait_for(lambda: daemon.received["HEARTBEAT"] >= heard, 5.0), (
            daemon.received["HEARTBEAT"],
            heard,
            heartbeats_before,
            daemon.link.counters(),
        )
        assert daemon.received["HEARTBEAT"] == heard
        assert daemon.vehicle.reboots == 0 and all(
            abs(a.roll_rad) < 0.5 for a in daemon.vehicle.attitude._samples
        )
        (name,) = daemon.link.strangers
        assert daemon.link.strangers[name].datagrams == 100_000
    finally:
        await stop(daemon, task)
        await autopilot.stop()


@pytest.mark.parametrize(
    ("connection", "address", "fragment"),
    [
        ("udpin:127.0.0.1:14550", "drone.local", "not an IP address"),
        ("udpin:127.0.0.1:14550", "127.0.0.1:0", "port must be a number from 1 to 65535"),
        ("udpin:127.0.0.1:14550", "[::1", "write an IPv6 address as [ADDR]"),
        ("udpout:127.0.0.1:14550", "127.0.0.1", "autopilot_address is for a udpin connection"),
    ],
)
def test_a_bad_autopilot_address_is_one_config_line(
    tmp_path: Path, connection: str, address: str, fragment: str
) -> None:
    path = synthetic_config(tmp_path, connection, mavlink={"autopilot_address": address})
    with pytest.raises(ConfigError) as caught:
        load_all(path)
    (line,) = caught.value.lines
    assert "mavlink" in line and fragment in line, line


def test_an_address_pin_matches_its_host_and_port_only() -> None:
    assert AddressPin.parse("127.0.0.1").matches(("127.0.0.1", 5))
    assert not AddressPin.parse("127.0.0.1").matches(("127.0.0.2", 5))
    assert AddressPin.parse("127.0.0.1:14555").matches(("127.0.0.1", 14555))
    assert not AddressPin.parse("127.0.0.1:14555").matches(("127.0.0.1", 14556))
    assert AddressPin.parse("[::1]:9").matches(("::1", 9, 0, 0))
    assert AddressPin.parse("127.0.0.1").matches(("::ffff:127.0.0.1", 9, 0, 0))
    assert str(AddressPin.parse("[::1]:9")) == "[::1]:9"
