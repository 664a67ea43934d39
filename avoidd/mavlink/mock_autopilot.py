"""A mock autopilot that speaks real MAVLink 2 bytes, for tests, benchmarks and sitl/.

It sends ArduPilot- or PX4-flavoured heartbeats with a decodable flight mode, streams ATTITUDE,
LOCAL_POSITION_NED, a downward DISTANCE_SENSOR and SYSTEM_TIME at whatever interval it is asked
for with MAV_CMD_SET_MESSAGE_INTERVAL, acknowledges commands, and records every message it decodes.
It listens on UDP or TCP, dials out, or owns a pty whose other end is a "serial port" at a fixed
path (a symlink), like a flight controller on USB.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import os
import pty
import signal
import time
import tty
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from pymavlink import mavutil

from avoidd.aio import cancel_task
from avoidd.config.connection import parse_connection
from avoidd.errors import LinkError
from avoidd.mavlink import codec as mav
from avoidd.mavlink.mission import MissionItem
from avoidd.mavlink.signing import wall_timestamp
from avoidd.mavlink.transport import ReceiveCallback, Transport, create_transport

logger = logging.getLogger(__name__)

FLAVOURS = ("ardupilot", "px4")
AttitudeFn = Callable[[float], tuple[float, float, float]]
"""Given seconds since boot: roll, pitch, yaw in radians."""


def default_attitude(t_s: float) -> tuple[float, float, float]:
    """A gentle, smooth sway, so that interpolation is testable: roll, pitch, yaw (rad)."""
    return (
        0.20 * math.sin(1.3 * t_s),
        0.10 * math.cos(0.7 * t_s),
        math.remainder(0.5 * t_s, math.tau),
    )


@dataclass
class Recorded:
    """One message the mock decoded."""

    received_ns: int
    message: mav.Message


class PtyTransport:
    """The autopilot's end of a pty; the other end appears at ``link_path`` (a symlink)."""

    def __init__(self, link_path: Path, on_receive: ReceiveCallback) -> None:
        self.link_path = link_path
        self._on_receive = on_receive
        self._master: int | None = None
        self._slave: int | None = None

    @property
    def connected(self) -> bool:
        """Whether the pty exists."""
        return self._master is not None

    async def open(self) -> None:
        """Create the pty and its symlink."""
        master, slave = pty.openpty()
        tty.setraw(slave)  # no echo, no line discipline: a clean byte pipe
        os.set_blocking(master, False)
        # Keeping our copy of the slave open means the master never reads EIO while the other
        # side is between opens.
        self._master, self._slave = master, slave
        with contextlib.suppress(FileNotFoundError):
            self.link_path.unlink()
        self.link_path.symlink_to(os.ttyname(slave))
        asyncio.get_running_loop().add_reader(master, self._readable)

    def _readable(self) -> None:
        if self._master is None:
            return
        try:
            data = os.read(self._master, 4096)
        except (BlockingIOError, OSError):
            return
        if data:
            self._on_receive(data)

    def send(self, data: bytes) -> bool:
        """Write bytes to the serial line (False when they could not all be written)."""
        if self._master is None:
            return False
        try:
            return os.write(self._master, data) == len(data)
        except OSError:
            return False

    async def close(self) -> None:
        """Close the pty and remove the symlink."""
        if self._master is not None:
            asyncio.get_running_loop().remove_reader(self._master)
        for fd in (self._master, self._slave):
            if fd is not None:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self._master = self._slave = None
        with contextlib.suppress(FileNotFoundError):
            self.link_path.unlink()


def _mode_fields(flavour: str, vehicle_type: int, mode: str, armed: bool) -> tuple[int, int]:
    """HEARTBEAT base_mode and custom_mode for a named flight mode."""
    armed_flag = mav.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0
    if flavour == "px4":
        if mode not in mavutil.px4_map:
            raise ValueError(f"unknown PX4 mode '{mode}'; one of {', '.join(mavutil.px4_map)}")
        base, main, sub = mavutil.px4_map[mode]
        return base | armed_flag, (main << 16) | (sub << 24)
    table = mavutil.mode_mapping_byname(vehicle_type) or {}
    if mode not in table:
        raise ValueError(f"unknown ArduPilot mode '{mode}'; one of {', '.join(table)}")
    return mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | armed_flag, int(table[mode])


@dataclass
class MockAutopilot:
    """A scriptable autopilot.

    Attributes:
        flavour: "ardupilot" or "px4".
        system_id: Its system id.
        vehicle_type: MAV_TYPE it reports.
        mode: Flight mode name (ArduPilot's or PX4's spelling).
        armed: Armed state.
        failsafe: A failsafe is in effect: armed, its HEARTBEAT says MAV_STATE_CRITICAL (as
            PX4 and ArduPilot do).
        key: Signing key; when set it signs everything and ignores unsigned messages.
        attitude: The attitude it reports over time.
        utc: Whether SYSTEM_TIME carries a UTC time (as with a GPS fix).
        refuse: Message names whose stream requests it answers with MAV_RESULT_UNSUPPORTED.
        acknowledge: Whether it answers commands at all.
        forget_once: Message names whose first accepted stream request it then forgets (as an
            autopilot that reboots between the acknowledgement and the first message).
        fixed_streams: Streams at fixed rates (msg name -> Hz), sent whether asked or not.
        rangefinder_m: Distance its downward rangefinder reports.
        position_ned: The local position it reports (north, east, down; metres).
        origin: Its EKF origin (latitude, longitude in degrees, altitude AMSL in metres),
            sent as GPS_GLOBAL_ORIGIN when asked with MAV_CMD_REQUEST_MESSAGE; None: no fix.
        home_up_m: Home's height above the origin (HOME_POSITION z is its negative).
        mission: Its mission (served with the mission protocol); None: no mission support.
        mission_drops: Answers to leave out once each, as (message name, seq) pairs, for
            loss tests (seq -1 for MISSION_COUNT).
        mission_repeats: Whether every mission answer is sent twice.
    """

    flavour: str = "ardupilot"
    system_id: int = 1
    vehicle_type: int = mav.MAV_TYPE_QUADROTOR
    mode: str = ""
    armed: bool = False
    failsafe: bool = False
    key: bytes | None = None
    attitude: AttitudeFn = default_attitude
    utc: bool = True
    refuse: set[str] = field(default_factory=set)
    acknowledge: bool = True
    forget_once: set[str] = field(default_factory=set)
    fixed_streams: dict[str, float] = field(default_factory=dict)
    rangefinder_m: float = 1.5
    position_ned: tuple[float, float, float] = (0.0, 0.0, -1.5)
    origin: tuple[float, float, float] | None = None
    home_up_m: float = 0.0
    mission: list[MissionItem] | None = None
    mission_drops: set[tuple[str, int]] = field(default_factory=set)
    mission_repeats: bool = False
    recorded: list[Recorded] = field(default_factory=list)
    streams: dict[int, float] = field(default_factory=dict)
    counts: Counter[str] = field(default_factory=Counter)
    sent: Counter[str] = field(default_factory=Counter)

    def __post_init__(self) -> None:
        if self.flavour not in FLAVOURS:
            raise ValueError(f"flavour must be one of {FLAVOURS}")
        if not self.mode:
            self.mode = "POSCTL" if self.flavour == "px4" else "STABILIZE"
        _mode_fields(self.flavour, self.vehicle_type, self.mode, self.armed)
        self.codec = mav.Codec(self.system_id, mav.MAV_COMP_ID_AUTOPILOT1)
        if self.key is not None:
            self.codec.enable_signing(self.key, wall_timestamp(), lambda _msg_id: False)
        self.boot_ns = time.monotonic_ns()
        self.transport: Transport | PtyTransport | None = None
        self._task: asyncio.Task[None] | None = None
        self._due_s: dict[int, float] = {}
        for name, hz in self.fixed_streams.items():
            self.streams[mav.message_id(name)] = 1.0 / hz

    # --- what it sends -----------------------------------------------------------------------

    def boot_ms(self) -> int:
        """Milliseconds since this autopilot 'booted'."""
        return (time.monotonic_ns() - self.boot_ns) // 1_000_000

    def heartbeat(self) -> mav.Message:
        """Its HEARTBEAT for the current mode and armed state."""
        base_mode, custom_mode = _mode_fields(
            self.flavour, self.vehicle_type, self.mode, self.armed
        )
        autopilot = (
            mav.MAV_AUTOPILOT_PX4 if self.flavour == "px4" else mav.MAV_AUTOPILOT_ARDUPILOTMEGA
        )
        status = mav.MAV_STATE_ACTIVE if self.armed else mav.MAV_STATE_STANDBY
        if self.armed and self.failsafe:
            status = mav.MAV_STATE_CRITICAL
        return self.codec.build(
            "HEARTBEAT", self.vehicle_type, autopilot, base_mode, custom_mode, status
        )

    def stream_message(self, msg_id: int) -> mav.Message | None:
        """The current value of a streamable message, or None for ones it cannot produce."""
        t_ms = self.boot_ms()
        t_s = t_ms / 1000.0
        name = mav.message_name(msg_id)
        if name == "ATTITUDE":
            roll, pitch, yaw = self.attitude(t_s)
            return self.codec.build("ATTITUDE", t_ms, roll, pitch, yaw, 0.0, 0.0, 0.0)
        if name == "LOCAL_POSITION_NED":
            north, east, down = self.position_ned
            return self.codec.build("LOCAL_POSITION_NED", t_ms, north, east, down, 0.0, 0.0, 0.0)
        if name == "DISTANCE_SENSOR":
            return self.codec.distance_sensor(
                t_ms,
                10,
                4000,
                round(self.rangefinder_m * 100),
                mav.MAV_SENSOR_ROTATION_PITCH_270,
                signal_quality=100,
            )
        if name == "SYSTEM_TIME":
            unix_us = time.time_ns() // 1000 if self.utc else 0
            return self.codec.build("SYSTEM_TIME", unix_us, t_ms)
        return None

    def send(self, message: mav.Message) -> None:
        """Pack and send one message now."""
        if self.transport is not None and self.transport.send(self.codec.pack(message)):
            self.sent[message.get_type()] += 1

    # --- what it hears -----------------------------------------------------------------------

    def of_type(self, kind: str) -> list[mav.Message]:
        """Every recorded message of one type, oldest first."""
        return [r.message for r in self.recorded if r.message.get_type() == kind]

    def _on_bytes(self, data: bytes) -> None:
        now_ns = time.monotonic_ns()
        for message in self.codec.decode(data):
            self.recorded.append(Recorded(now_ns, message))
            self.counts[message.get_type()] += 1
            if message.get_type() == "COMMAND_LONG":
                self._on_command(message)
            elif message.get_type() in ("MISSION_REQUEST_LIST", "MISSION_REQUEST_INT"):
                self._on_mission_request(message)

    def _on_mission_request(self, message: mav.Message) -> None:
        if self.mission is None or message.target_system != self.system_id:
            return
        kind = message.get_type()
        seq = -1 if kind == "MISSION_REQUEST_LIST" else int(message.seq)
        answer = "MISSION_COUNT" if seq < 0 else "MISSION_ITEM_INT"
        if (answer, seq) in self.mission_drops:
            self.mission_drops.discard((answer, seq))
            return
        to = (message.get_srcSystem(), message.get_srcComponent())
        kind_mission = mav.MAV_MISSION_TYPE_MISSION
        if seq < 0:
            reply = self.codec.build("MISSION_COUNT", *to, len(self.mission), kind_mission)
        elif seq < len(self.mission):
            item = self.mission[seq]
            reply = self.codec.build(
                "MISSION_ITEM_INT",
                *to,
                seq,
                item.frame,
                item.command,
                0,
                1,
                0.0,
                0.0,
                0.0,
                0.0,
                item.x,
                item.y,
                item.z,
                kind_mission,
            )
        else:
            return
        for _ in range(2 if self.mission_repeats else 1):
            self.send(reply)

    def _on_command(self, message: mav.Message) -> None:
        if message.target_system not in (0, self.system_id) or message.target_component not in (
            0,
            mav.MAV_COMP_ID_AUTOPILOT1,
        ):
            return
        result = mav.MAV_RESULT_UNSUPPORTED
        later: mav.Message | None = None
        if message.command == mav.MAV_CMD_REQUEST_MESSAGE and self.origin is not None:
            lat_deg, lon_deg, alt_m = self.origin
            lat, lon, alt_mm = round(lat_deg * 1e7), round(lon_deg * 1e7), round(alt_m * 1000)
            if int(message.param1) == 49:
                result = mav.MAV_RESULT_ACCEPTED
                later = self.codec.build("GPS_GLOBAL_ORIGIN", lat, lon, alt_mm, 0)
            elif int(message.param1) == 242:
                result = mav.MAV_RESULT_ACCEPTED
                home_alt_mm = alt_mm + round(self.home_up_m * 1000)
                q = [1.0, 0.0, 0.0, 0.0]
                later = self.codec.build(
                    "HOME_POSITION", lat, lon, home_alt_mm, 0, 0, -self.home_up_m, q, 0, 0, 0, 0
                )
        if message.command == mav.MAV_CMD_SET_MESSAGE_INTERVAL:
            msg_id = int(message.param1)
            interval_us = message.param2
            name = mav.message_name(msg_id)
            if name not in self.refuse and self.stream_message(msg_id) is not None:
                result = mav.MAV_RESULT_ACCEPTED
                if name in self.forget_once:
                    self.forget_once.discard(name)
                elif interval_us < 0:
                    self.streams.pop(msg_id, None)
                else:
                    self.streams[msg_id] = max(interval_us, 1000.0) / 1e6
                    self._due_s[msg_id] = time.monotonic()
        if self.acknowledge:
            self.send(
                self.codec.build(
                    "COMMAND_ACK",
                    message.command,
                    result,
                    0,
                    0,
                    message.get_srcSystem(),
                    message.get_srcComponent(),
                )
            )
        if later is not None:
            self.send(later)

    def reboot(self) -> None:
        """Reboot at once, as ArduPilot SITL does in under 3 s.

        The boot clock starts over and every requested stream is forgotten (the fixed ones
        stay).
        """
        self.boot_ns = time.monotonic_ns()
        fixed = {mav.message_id(name) for name in self.fixed_streams}
        self.streams = {k: v for k, v in self.streams.items() if k in fixed}

    # --- running -----------------------------------------------------------------------------

    async def start(self, connection: str) -> None:
        """Open the link and start sending.

        Args:
            connection: ``udpin:``/``udpout:``/``tcpin:``/``tcp:`` as for avoidd, or
                ``pty:PATH`` to create a pty whose serial end is linked at PATH.
        """
        if connection.startswith("pty:"):
            self.transport = PtyTransport(Path(connection.removeprefix("pty:")), self._on_bytes)
        else:
            self.transport = create_transport(parse_connection(connection), self._on_bytes)
        await self.transport.open()
        self._task = asyncio.create_task(self._run(), name="mock-autopilot")

    async def _run(self) -> None:
        next_heartbeat_s = time.monotonic()
        while True:
            now_s = time.monotonic()
            if now_s >= next_heartbeat_s:
                self.send(self.heartbeat())
                if self.mission is not None:
                    total = len(self.mission)
                    self.send(self.codec.build("MISSION_CURRENT", 0, total, 0, 0))
                next_heartbeat_s = now_s + 1.0
            for msg_id, interval_s in list(self.streams.items()):
                due_s = self._due_s.setdefault(msg_id, now_s)
                if now_s - due_s > 0.5:
                    due_s = now_s  # far behind: do not burst to catch up
                while due_s <= now_s:
                    message = self.stream_message(msg_id)
                    if message is not None:
                        self.send(message)
                    due_s += interval_s
                self._due_s[msg_id] = due_s
            await asyncio.sleep(0.002)

    async def stop(self) -> None:
        """Stop sending and close the link."""
        await cancel_task(self._task)
        self._task = None
        if self.transport is not None:
            await self.transport.close()
            self.transport = None


async def serve(autopilot: MockAutopilot, connection: str, duration_s: float | None) -> None:
    """Run a mock autopilot until SIGINT or SIGTERM, cancelled, or for ``duration_s``.

    However it ends, it stops cleanly and logs what it heard.
    """
    try:
        await autopilot.start(connection)
    except (LinkError, OSError) as exc:
        raise LinkError(f"mock autopilot on {connection}: {exc}") from exc
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    handled = []
    for signum in (signal.SIGINT, signal.SIGTERM):
        # Only the main thread may handle signals; elsewhere cancellation stops it.
        with contextlib.suppress(NotImplementedError, RuntimeError, ValueError):
            loop.add_signal_handler(signum, stop.set)
            handled.append(signum)
    logger.info(
        "mock %s autopilot, system %d, mode %s, on %s",
        autopilot.flavour,
        autopilot.system_id,
        autopilot.mode,
        connection,
    )
    try:
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(stop.wait(), duration_s)
    finally:
        for signum in handled:
            loop.remove_signal_handler(signum)
        await autopilot.stop()
        logger.info(
            "mock autopilot stopped; heard %s, sent %s",
            dict(autopilot.counts),
            dict(autopilot.sent),
        )
