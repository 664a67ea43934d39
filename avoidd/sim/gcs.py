"""A ground-station stand-in: commands, parameters and stream requests over a MAVLink link.

Tests and simulation runners use it where an operator would use QGroundControl or MAVProxy:
to keep an autopilot's GCS port served, arm it, take off, switch modes, set parameters and
ask for the messages they watch. It speaks through avoidd's own codec and transports.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import socket
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from pymavlink import mavutil

from avoidd.aio import cancel_task
from avoidd.config.connection import parse_connection
from avoidd.errors import LinkError
from avoidd.mavlink import codec as mav
from avoidd.mavlink.mission import MissionItem
from avoidd.mavlink.transport import Transport, create_transport

logger = logging.getLogger(__name__)

GCS_SYSTEM_ID = 255
GCS_COMPONENT_ID = 190  # MAV_COMP_ID_MISSIONPLANNER
MAV_TYPE_GCS = 6
MAV_PARAM_TYPE_REAL32 = 9
_FORCE_DISARM = 21196.0  # MAV_CMD_COMPONENT_ARM_DISARM param 2: disarm even when flying


@dataclass
class Heard:
    """One message the ground station decoded, with its local receive time."""

    received_ns: int
    message: mav.Message


@dataclass
class GroundStation:
    """A ground station on one link.

    Attributes:
        connection: ``tcp:HOST:PORT``, ``udpin:...`` or ``udpout:...``.
        target_system: The autopilot's system id.
        target_component: The autopilot's component id.
        heard: Every decoded message, oldest first (bounded: the last ``keep``).
    """

    connection: str
    target_system: int = 1
    target_component: int = 1
    keep: int = 200_000
    heard: list[Heard] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.codec = mav.Codec(GCS_SYSTEM_ID, GCS_COMPONENT_ID)
        self.transport: Transport | None = None
        self._task: asyncio.Task[None] | None = None
        self._waiters: list[tuple[Callable[[mav.Message], bool], asyncio.Future[mav.Message]]] = []

    # --- link ----------------------------------------------------------------------------

    async def open(self) -> None:
        """Open the link and start the 1 Hz heartbeat."""
        self.transport = create_transport(parse_connection(self.connection), self._on_bytes)
        await self.transport.open()
        self._task = asyncio.create_task(self._heartbeat(), name="gcs-heartbeat")

    async def close(self) -> None:
        """Stop and close the link."""
        await cancel_task(self._task)
        self._task = None
        if self.transport is not None:
            await self.transport.close()
            self.transport = None

    @property
    def connected(self) -> bool:
        """Whether the transport is up."""
        return self.transport is not None and self.transport.connected

    def send(self, message: mav.Message) -> None:
        """Pack and send one message."""
        if self.transport is not None:
            self.transport.send(self.codec.pack(message))

    def sticks(self, rate_hz: float = 20.0, forward: int = 0) -> StickStream:
        """Start a pilot's sticks: MANUAL_CONTROL at ``rate_hz`` from a thread of its own.

        PX4 in Position mode needs manual control and fails safe (Hold) after
        ``COM_RC_LOSS_T`` (0.5 s) without it. A task on the event loop missed that on a
        loaded machine (the loop shares it with avoidd); a thread sending on a copy of the
        link's UDP socket keeps its pace whatever the loop does. Only ``udpin`` and
        ``udpout`` links can do that.

        Args:
            rate_hz: Messages a second.
            forward: The pitch stick to start with (see :attr:`StickStream.forward`).

        Raises:
            LinkError: The link is not open, or not UDP.
        """
        transport = self.transport
        fileno = getattr(transport, "socket_fileno", lambda: None)()
        if transport is None or fileno is None:
            raise LinkError(f"ground station {self.connection}: sticks need an open UDP link")
        stream = StickStream(
            socket.socket(fileno=os.dup(fileno)),
            lambda: getattr(transport, "peer", None),
            rate_hz,
            self.target_system,
        )
        stream.forward = forward
        stream.start()
        return stream

    async def _heartbeat(self) -> None:
        while True:
            self.send(self.codec.build("HEARTBEAT", MAV_TYPE_GCS, 8, 0, 0, 4))
            await asyncio.sleep(1.0)

    def _on_bytes(self, data: bytes) -> None:
        now_ns = time.monotonic_ns()
        for message in self.codec.decode(data):
            self.heard.append(Heard(now_ns, message))
            for predicate, future in list(self._waiters):
                if not future.done() and predicate(message):
                    future.set_result(message)
        if len(self.heard) > self.keep:
            del self.heard[: len(self.heard) - self.keep]

    # --- what it heard -------------------------------------------------------------------

    def from_autopilot(self, message: mav.Message) -> bool:
        """Whether a message comes from the autopilot itself.

        An ArduPilot forwards what other components of its system send (avoidd's heartbeat
        and STATUSTEXT among them) to its ground stations.
        """
        return bool(
            message.get_srcSystem() == self.target_system
            and message.get_srcComponent() == self.target_component
        )

    def of_type(self, kind: str, since_ns: int = 0) -> list[mav.Message]:
        """Messages of one type from the autopilot, oldest first, received after ``since_ns``."""
        return [
            h.message
            for h in self.heard
            if h.received_ns >= since_ns
            and h.message.get_type() == kind
            and self.from_autopilot(h.message)
        ]

    async def next_message(
        self, predicate: Callable[[mav.Message], bool], timeout_s: float
    ) -> mav.Message | None:
        """The next message (from now) that satisfies ``predicate``, or None after the timeout."""
        future: asyncio.Future[mav.Message] = asyncio.get_running_loop().create_future()
        entry = (predicate, future)
        self._waiters.append(entry)
        try:
            return await asyncio.wait_for(future, timeout_s)
        except TimeoutError:
            return None
        finally:
            self._waiters.remove(entry)

    # --- commands --------------------------------------------------------------------------

    async def command(
        self, command: int, *params: float, timeout_s: float = 1.0, tries: int = 5
    ) -> int | None:
        """Send a COMMAND_LONG until acknowledged; the MAV_RESULT, or None without an answer."""
        values = [float(p) for p in params] + [0.0] * (7 - len(params))
        for attempt in range(tries):
            ack = asyncio.ensure_future(
                self.next_message(
                    lambda m: m.get_type() == "COMMAND_ACK" and m.command == command, timeout_s
                )
            )
            await asyncio.sleep(0)
            self.send(
                self.codec.build(
                    "COMMAND_LONG",
                    self.target_system,
                    self.target_component,
                    command,
                    attempt,
                    *values,
                )
            )
            answer = await ack
            if answer is not None:
                return int(answer.result)
        return None

    async def request_message_interval(self, name: str, rate_hz: float) -> int | None:
        """Ask the autopilot to stream a message at ``rate_hz`` on this link."""
        interval_us = round(1e6 / rate_hz) if rate_hz > 0 else -1
        return await self.command(
            mav.MAV_CMD_SET_MESSAGE_INTERVAL, mav.message_id(name), interval_us
        )

    async def set_param(self, name: str, value: float) -> bool:
        """Set a REAL32 parameter and wait for its PARAM_VALUE echo (up to five tries).

        Integer parameters are not offered: PX4 takes an INT32 as the integer's four bytes in
        the float field, ArduPilot as the value converted to float.
        """
        param_type = MAV_PARAM_TYPE_REAL32
        for _ in range(5):
            echo = asyncio.ensure_future(
                self.next_message(
                    lambda m: m.get_type() == "PARAM_VALUE" and m.param_id == name, 1.0
                )
            )
            await asyncio.sleep(0)
            self.send(
                self.codec.build(
                    "PARAM_SET",
                    self.target_system,
                    self.target_component,
                    name.encode(),
                    float(value),
                    param_type,
                )
            )
            answer = await echo
            if answer is not None and abs(answer.param_value - value) < 1e-3 * max(1, abs(value)):
                return True
        return False

    async def set_mode(self, autopilot: str, name: str) -> int | None:
        """Switch flight mode with MAV_CMD_DO_SET_MODE (ArduPilot copter or PX4 mode names)."""
        if autopilot == "px4":
            base, main, sub = mavutil.px4_map[name]
            return await self.command(176, base, main, sub)
        mapping = mavutil.mode_mapping_byname(mav.MAV_TYPE_QUADROTOR) or {}
        return await self.command(176, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, mapping[name])

    async def arm(self, retry_s: float = 60.0) -> bool:
        """Arm, retrying (pre-arm checks fail until the estimator settles) for ``retry_s``."""
        deadline = time.monotonic() + retry_s
        while time.monotonic() < deadline:
            if await self.command(400, 1.0) == mav.MAV_RESULT_ACCEPTED:
                return True
            await asyncio.sleep(1.0)
        return False

    async def disarm_to_retry(self) -> int | None:
        """Disarm now, in the air too (a simulated vehicle only: it drops where it is).

        A take-off that stalls a few decimetres up (PX4 SITL on a loaded machine: TAKEOFF mode,
        0.3 m) is "not landed", so a plain disarm is denied and arming again changes nothing;
        MAV_CMD_COMPONENT_ARM_DISARM's force value (param 2 = 21196) ends it.
        """
        return await self.command(400, 0.0, _FORCE_DISARM)

    async def upload_mission(self, items: Sequence[MissionItem], timeout_s: float = 15.0) -> int:
        """Upload a mission with the mission protocol, answering the autopilot's requests.

        Returns:
            The MAV_MISSION_RESULT of the autopilot's MISSION_ACK (0: accepted).

        Raises:
            LinkError: No MISSION_ACK within the timeout.
        """
        kinds = {"MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK"}

        def answer(message: mav.Message) -> bool:
            return bool(
                message.get_type() in kinds
                and self.from_autopilot(message)
                and message.target_system == GCS_SYSTEM_ID
            )

        to = (self.target_system, self.target_component)
        outgoing = self.codec.build("MISSION_COUNT", *to, len(items), 0)
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            reply = asyncio.ensure_future(self.next_message(answer, 1.0))
            await asyncio.sleep(0)
            self.send(outgoing)  # again after a second without an answer
            message = await reply
            if message is None:
                continue
            if message.get_type() == "MISSION_ACK":
                return int(message.type)
            item = items[int(message.seq)]
            outgoing = self.codec.build(
                "MISSION_ITEM_INT", *to, item.seq, item.frame, item.command, 0, 1,
                0.0, 0.0, 0.0, 0.0, item.x, item.y, item.z, 0,
            )  # fmt: skip
        raise LinkError(f"ground station on {self.connection}: mission upload not acknowledged")

    async def wait_heartbeat(self, timeout_s: float) -> mav.Message:
        """The autopilot's next heartbeat.

        Raises:
            LinkError: None came within the timeout.
        """
        beat = await self.next_message(
            lambda m: m.get_type() == "HEARTBEAT" and self.from_autopilot(m), timeout_s
        )
        if beat is None:
            raise LinkError(f"ground station on {self.connection}: no heartbeat in {timeout_s} s")
        return beat


class StickStream:
    """MANUAL_CONTROL at a steady rate from a thread (see :meth:`GroundStation.sticks`).

    Attributes:
        forward: Pitch stick, -1000 (back) to 1000 (forward); read at every send.
        yaw: Yaw stick, -1000 (turn left) to 1000 (turn right, clockwise seen from above, as
            PX4 reads MANUAL_CONTROL's ``r``); read at every send.
        target_system: The autopilot's system id; read at every send.
        sent: Messages sent.
        longest_gap_s: Longest time between two sends (a starved thread shows here).
    """

    def __init__(
        self,
        sock: socket.socket,
        peer: Callable[[], tuple[Any, ...] | None],
        rate_hz: float,
        target_system: int,
    ) -> None:
        self.forward = 0
        self.yaw = 0
        self.target_system = target_system
        self.sent = 0
        self.longest_gap_s = 0.0
        self._socket = sock
        self._peer = peer
        self._period_s = 1.0 / rate_hz
        self._codec = mav.Codec(GCS_SYSTEM_ID, GCS_COMPONENT_ID)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="gcs-sticks", daemon=True)

    def start(self) -> None:
        """Start sending."""
        self._thread.start()

    def stop(self) -> None:
        """Stop sending and close the socket copy."""
        self._stop.set()
        self._thread.join(5.0)
        self._socket.close()

    def _run(self) -> None:
        due = time.monotonic()
        last: float | None = None
        while not self._stop.wait(max(0.0, due - time.monotonic())):
            peer = self._peer()
            if peer is not None:
                message = self._codec.build(
                    "MANUAL_CONTROL", self.target_system, self.forward, 0, 500, self.yaw, 0
                )
                with contextlib.suppress(OSError):
                    self._socket.sendto(self._codec.pack(message), peer)
                    self.sent += 1
                now = time.monotonic()
                if last is not None:
                    self.longest_gap_s = max(self.longest_gap_s, now - last)
                last = now
            # The next send a period on; after a stall, from now (no burst to catch up).
            due = max(due + self._period_s, time.monotonic())
