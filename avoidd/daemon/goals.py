"""Goals from MAVLink: what a ground station or the mission asks for, in avoidd's local frame.

Pure functions from a message (or mission item) to a :class:`~avoidd.planner.core.Goal` or a
:class:`Refusal` that says why not, with the MAV_RESULT a COMMAND_ACK carries. Global positions
go to the autopilot's local frame through its origin (GPS_GLOBAL_ORIGIN); altitudes above home
through home's height above that origin (HOME_POSITION).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from avoidd.mavlink import codec as mav
from avoidd.mavlink.codec import Message
from avoidd.mavlink.geo import GlobalPoint, north_east_m, valid_lat_lon
from avoidd.mavlink.mission import MissionItem
from avoidd.planner.core import Goal

MIN_ALTITUDE_M = 0.5
"""Lowest goal height above the ground (avoidd does not land): above home when home is known
(a PX4 estimator's origin can sit 2 m above or below the ground), else above the origin."""
MAX_DISTANCE_M = 10_000.0
"""Farthest goal from the origin."""

_AMSL_FRAMES = {mav.MAV_FRAME_GLOBAL, mav.MAV_FRAME_GLOBAL_INT}
_ABOVE_HOME_FRAMES = {mav.MAV_FRAME_GLOBAL_RELATIVE_ALT, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT}


@dataclass(frozen=True)
class Refusal:
    """Why a goal was not taken.

    Attributes:
        result: MAV_RESULT for a COMMAND_ACK.
        reason: Short text for the log and STATUSTEXT.
    """

    result: int
    reason: str
    """At most 28 characters: it ends a 50-character STATUSTEXT."""


@dataclass(frozen=True)
class Frame:
    """What avoidd knows of the autopilot's frame when a goal arrives.

    Attributes:
        origin: GPS_GLOBAL_ORIGIN (None until the autopilot reported it).
        home_up_m: Home's height above the origin (None until HOME_POSITION).
        altitude_m: The vehicle's height above the origin now (None without a position).
    """

    origin: GlobalPoint | None
    home_up_m: float | None
    altitude_m: float | None


def _checked(goal: Goal, frame: Frame | None) -> Goal | Refusal:
    values = (goal.north_m, goal.east_m, goal.altitude_m)
    if not all(math.isfinite(v) for v in values):
        return Refusal(mav.MAV_RESULT_DENIED, "position not finite")
    ground_m = frame.home_up_m if frame is not None and frame.home_up_m is not None else 0.0
    if goal.altitude_m - ground_m < MIN_ALTITUDE_M:
        return Refusal(mav.MAV_RESULT_DENIED, "less than 0.5 m above ground")
    if math.hypot(goal.north_m, goal.east_m) > MAX_DISTANCE_M:
        return Refusal(mav.MAV_RESULT_DENIED, "more than 10 km from origin")
    return goal


def local_target(message: Message, frame: Frame | None = None) -> Goal | Refusal:
    """A SET_POSITION_TARGET_LOCAL_NED with a position in MAV_FRAME_LOCAL_NED.

    Args:
        message: The message.
        frame: The autopilot's home (the ground), when known.
    """
    if message.coordinate_frame != mav.MAV_FRAME_LOCAL_NED or message.type_mask & 0x7:
        return Refusal(mav.MAV_RESULT_DENIED, "need LOCAL_NED and a position")
    goal = Goal(float(message.x), float(message.y), -float(message.z), "GCS goal")
    return _checked(goal, frame)


def global_goal(
    frame_id: int, lat_e7: int, lon_e7: int, alt_m: float, frame: Frame, label: str
) -> Goal | Refusal:
    """A global position (AMSL or above home) as a local goal.

    Args:
        frame_id: MAV_FRAME of the altitude (GLOBAL[_INT] or GLOBAL_RELATIVE_ALT[_INT]).
        lat_e7: Latitude in 1e-7 degrees.
        lon_e7: Longitude in 1e-7 degrees.
        alt_m: Altitude in that frame; NaN keeps the vehicle's current altitude.
        frame: The autopilot's origin and home.
        label: The goal's name in reports.

    Returns:
        The goal, or why it cannot be taken (no origin yet, an unsupported frame, ...).
    """
    lat_deg, lon_deg = lat_e7 / 1e7, lon_e7 / 1e7
    if not valid_lat_lon(lat_deg, lon_deg):
        return Refusal(mav.MAV_RESULT_DENIED, "latitude/longitude invalid")
    if frame.origin is None:
        return Refusal(mav.MAV_RESULT_TEMPORARILY_REJECTED, "no GPS origin yet")
    north_m, east_m = north_east_m(frame.origin, lat_deg, lon_deg)
    if math.isnan(alt_m):
        if frame.altitude_m is None:
            return Refusal(mav.MAV_RESULT_TEMPORARILY_REJECTED, "no position yet")
        altitude_m = frame.altitude_m
    elif frame_id in _AMSL_FRAMES:
        altitude_m = alt_m - frame.origin.alt_m
    elif frame_id in _ABOVE_HOME_FRAMES:
        if frame.home_up_m is None:
            return Refusal(mav.MAV_RESULT_TEMPORARILY_REJECTED, "no home position yet")
        altitude_m = alt_m + frame.home_up_m
    else:
        return Refusal(mav.MAV_RESULT_DENIED, f"frame {frame_id} not supported")
    return _checked(Goal(north_m, east_m, altitude_m, label), frame)


def global_target(message: Message, frame: Frame) -> Goal | Refusal:
    """A SET_POSITION_TARGET_GLOBAL_INT with its position used (type_mask bits 0-2 clear)."""
    if message.type_mask & 0x7:
        return Refusal(mav.MAV_RESULT_DENIED, "need a position (mask)")
    return global_goal(
        int(message.coordinate_frame),
        int(message.lat_int),
        int(message.lon_int),
        float(message.alt),
        frame,
        "GCS goal",
    )


def reposition(message: Message, frame: Frame) -> Goal | Refusal:
    """A COMMAND_INT MAV_CMD_DO_REPOSITION (x, y: lat/lon in 1e-7 degrees, z: altitude)."""
    return global_goal(
        int(message.frame), int(message.x), int(message.y), float(message.z), frame, "GCS goal"
    )


def mission_goal(item: MissionItem, number: int, frame: Frame) -> Goal | Refusal:
    """A NAV_WAYPOINT mission item as a goal named ``waypoint <number>``."""
    return global_goal(item.frame, item.x, item.y, item.z, frame, f"waypoint {number}")
