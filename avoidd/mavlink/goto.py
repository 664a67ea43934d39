"""Sending avoidd a goal as a ground station would (``avoidd goto``).

The client announces itself with a GCS HEARTBEAT (avoidd takes goals only from the vehicle's
own system or a ground station), finds avoidd by its HEARTBEAT from component 196, and sends
the goal addressed to that component once a second until avoidd answers:

- a local goal as ``SET_POSITION_TARGET_LOCAL_NED``: the answer is avoidd's STATUSTEXT
  ("avoidd: goal N.. E.. A.." or "avoidd: goal refused: ...");
- a global goal as ``COMMAND_INT`` ``MAV_CMD_DO_REPOSITION``: the answer is COMMAND_ACK, and
  a refusal's reason is the STATUSTEXT avoidd sends with it.

Without an answer the text says which of two things happened: no avoidd was heard at all
(nothing from component 196 reached the connection), or avoidd was heard and did not answer.
"""

from __future__ import annotations

import asyncio
import math
import time
from dataclasses import dataclass

from avoidd.config.connection import parse_connection
from avoidd.mavlink import codec as mav
from avoidd.mavlink.transport import create_transport

GCS_SYSTEM_ID = 255
GCS_COMPONENT_ID = 190  # MAV_COMP_ID_MISSIONPLANNER
_POSITION_ONLY = 0x0FF8
_RESEND_S = 1.0
_REASON_WAIT_S = 2.0
"""How long a refusal's COMMAND_ACK waits for the STATUSTEXT that says why."""
_REFUSED = "avoidd: goal refused: "


@dataclass(frozen=True)
class LocalGoal:
    """North, east (metres from the autopilot's origin) and height above it."""

    north_m: float
    east_m: float
    altitude_m: float


@dataclass(frozen=True)
class GlobalGoal:
    """Latitude, longitude (degrees) and altitude: above home, or above sea level if ``amsl``."""

    lat_deg: float
    lon_deg: float
    altitude_m: float
    amsl: bool = False


@dataclass(frozen=True)
class Answer:
    """What avoidd said.

    Attributes:
        accepted: Whether it took the goal (None: no answer before the timeout).
        text: Its words (STATUSTEXT, or the COMMAND_ACK result by name).
        system_id: The vehicle system avoidd speaks for (None if never heard).
    """

    accepted: bool | None
    text: str
    system_id: int | None


def _goal_message(codec: mav.Codec, goal: LocalGoal | GlobalGoal, system_id: int) -> mav.Message:
    me = mav.MAV_COMP_ID_OBSTACLE_AVOIDANCE
    if isinstance(goal, LocalGoal):
        return codec.build(
            "SET_POSITION_TARGET_LOCAL_NED", 0, system_id, me, mav.MAV_FRAME_LOCAL_NED,
            _POSITION_ONLY, goal.north_m, goal.east_m, -goal.altitude_m,
            0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
        )  # fmt: skip
    frame = mav.MAV_FRAME_GLOBAL_INT if goal.amsl else mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
    return codec.build(
        "COMMAND_INT", system_id, me, frame, mav.MAV_CMD_DO_REPOSITION, 0, 0,
        -1.0, 0.0, 0.0, math.nan, round(goal.lat_deg * 1e7), round(goal.lon_deg * 1e7),
        goal.altitude_m,
    )  # fmt: skip


def _answer(message: mav.Message, goal: LocalGoal | GlobalGoal) -> tuple[bool, str] | None:
    kind = message.get_type()
    if isinstance(goal, LocalGoal) and kind == "STATUSTEXT":
        text = str(message.text)
        if text.startswith(_REFUSED):
            return False, text
        if text.startswith("avoidd: goal N"):
            return True, text
    if isinstance(goal, GlobalGoal) and kind == "COMMAND_ACK":
        if message.command != mav.MAV_CMD_DO_REPOSITION or message.target_system not in (
            0,
            GCS_SYSTEM_ID,
        ):
            return None
        name = mav.result_name(int(message.result))
        return message.result == mav.MAV_RESULT_ACCEPTED, name
    return None


async def _reason(heard: asyncio.Queue[mav.Message], target: int, deadline: float) -> str | None:
    """The reason of a refusal: avoidd's STATUSTEXT, waited for a little after its ACK."""
    until = min(deadline, time.monotonic() + _REASON_WAIT_S)
    while (left := until - time.monotonic()) > 0:
        try:
            message = await asyncio.wait_for(heard.get(), left)
        except TimeoutError:
            break
        if (
            message.get_srcSystem() == target
            and message.get_srcComponent() == mav.MAV_COMP_ID_OBSTACLE_AVOIDANCE
            and message.get_type() == "STATUSTEXT"
            and str(message.text).startswith(_REFUSED)
        ):
            return str(message.text)[len(_REFUSED) :]
    return None


async def send_goal(
    connection: str,
    goal: LocalGoal | GlobalGoal,
    system_id: int | None = None,
    timeout_s: float = 10.0,
) -> Answer:
    """Send a goal to avoidd and wait for its answer.

    Args:
        connection: Where avoidd's traffic can be reached (``udpout:HOST:PORT`` of a router's
            ground-station endpoint, a TCP port, a serial line).
        goal: Where to go.
        system_id: The vehicle's system id (default: learned from avoidd's HEARTBEAT).
        timeout_s: Give up after this long.

    Returns:
        avoidd's answer, or ``accepted=None`` when none came in time.
    """
    codec = mav.Codec(GCS_SYSTEM_ID, GCS_COMPONENT_ID)
    heard: asyncio.Queue[mav.Message] = asyncio.Queue()

    def received(data: bytes) -> None:
        for message in codec.decode(data):
            heard.put_nowait(message)

    transport = create_transport(parse_connection(connection), received)
    await transport.open()
    heartbeat = codec.build(
        "HEARTBEAT", mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, mav.MAV_STATE_ACTIVE
    )
    target = system_id
    reason: str | None = None
    heard_avoidd = False
    first_goal_s: float | None = None
    deadline = time.monotonic() + timeout_s
    next_send = 0.0
    try:
        while (now := time.monotonic()) < deadline:
            if now >= next_send:
                transport.send(codec.pack(heartbeat))
                if target is not None:
                    transport.send(codec.pack(_goal_message(codec, goal, target)))
                    first_goal_s = now if first_goal_s is None else first_goal_s
                next_send = now + _RESEND_S
            try:
                message = await asyncio.wait_for(heard.get(), min(0.1, deadline - now))
            except TimeoutError:
                continue
            from_avoidd = message.get_srcComponent() == mav.MAV_COMP_ID_OBSTACLE_AVOIDANCE
            if not from_avoidd:
                continue
            heard_avoidd = True
            if target is None and message.get_type() == "HEARTBEAT":
                target = message.get_srcSystem()
                next_send = 0.0
                continue
            if message.get_srcSystem() != target:
                continue
            if (
                first_goal_s is not None
                and message.get_type() == "STATUSTEXT"
                and str(message.text).startswith(_REFUSED)
            ):
                reason = str(message.text)[len(_REFUSED) :]  # said after our goal went out
            answer = _answer(message, goal)
            if answer is None:
                continue
            accepted, text = answer
            if isinstance(goal, GlobalGoal) and not accepted:
                if reason is None and target is not None:
                    reason = await _reason(heard, target, deadline)
                text = f"refused ({text}): {reason or 'no reason given'}"
            return Answer(accepted, text, target)
        if not heard_avoidd:
            return Answer(
                None,
                f"no avoidd heard within {timeout_s:g} s: nothing from MAVLink component "
                f"{mav.MAV_COMP_ID_OBSTACLE_AVOIDANCE} reached {connection} (is avoidd running, "
                "and does this connection reach it? avoidd's own mavlink.gcs_connection or a "
                "MAVLink router's ground-station endpoint does; see docs/mavlink.md)",
                None,
            )
        return Answer(
            None,
            f"avoidd (system {target}) heard, but it did not answer the goal within "
            f"{timeout_s:g} s (its log says why)",
            target,
        )
    finally:
        await transport.close()
