"""Who the autopilot is and what mode it is in, decoded from its HEARTBEAT.

The mode tables are pymavlink's (``mavutil``), which track ArduPilot's and PX4's own headers.
"""

from __future__ import annotations

from dataclasses import dataclass

from pymavlink import mavutil

from avoidd.mavlink import codec as mav

ARDUPILOT = "ArduPilot"
PX4 = "PX4"

_GUIDED_MODES = {ARDUPILOT: {"GUIDED"}, PX4: {"OFFBOARD"}}
"""Modes that fly velocity setpoints (ArduPilot's GUIDED_NOGPS takes attitude targets only)."""
_FAILSAFE_STATES = {
    mav.MAV_STATE_CRITICAL,
    mav.MAV_STATE_EMERGENCY,
    mav.MAV_STATE_FLIGHT_TERMINATION,
}
"""MAV_STATE values that say a failsafe is in effect."""


@dataclass(frozen=True)
class FlightMode:
    """The decoded state of an autopilot heartbeat.

    Attributes:
        autopilot: "ArduPilot", "PX4" or "other (MAV_AUTOPILOT n)".
        vehicle_type: MAV_TYPE of the vehicle.
        name: Flight mode name as the autopilot's own ground stations show it.
        armed: Whether the motors are armed.
        guided: Whether external setpoints are obeyed in this mode (GUIDED, OFFBOARD).
        failsafe: The heartbeat's ``system_status`` says a failsafe is in effect (CRITICAL or
            worse). PX4 sends CRITICAL while armed with a failsafe action running (its
            offboard-loss fallback among them); ArduPilot while any of its failsafes is set.
    """

    autopilot: str
    vehicle_type: int
    name: str
    armed: bool
    guided: bool
    failsafe: bool = False


def autopilot_name(autopilot: int) -> str:
    """Name of a MAV_AUTOPILOT value."""
    if autopilot == mav.MAV_AUTOPILOT_ARDUPILOTMEGA:
        return ARDUPILOT
    if autopilot == mav.MAV_AUTOPILOT_PX4:
        return PX4
    return f"other (MAV_AUTOPILOT {autopilot})"


def decode_mode(
    autopilot: int,
    vehicle_type: int,
    base_mode: int,
    custom_mode: int,
    system_status: int = mav.MAV_STATE_ACTIVE,
) -> FlightMode:
    """Decode the flight mode, armed and failsafe state of an autopilot HEARTBEAT.

    Args:
        autopilot: HEARTBEAT.autopilot.
        vehicle_type: HEARTBEAT.type.
        base_mode: HEARTBEAT.base_mode.
        custom_mode: HEARTBEAT.custom_mode.
        system_status: HEARTBEAT.system_status (MAV_STATE).

    Returns:
        The decoded mode; unknown numbers come out as ``"MODE n"`` rather than failing.
    """
    who = autopilot_name(autopilot)
    armed = bool(base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED)
    name = f"MODE {custom_mode}"
    if not base_mode & mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
        name = "NO CUSTOM MODE"
    elif who == ARDUPILOT:
        table = mavutil.mode_mapping_bynumber(vehicle_type) or {}
        name = table.get(custom_mode, name)
    elif who == PX4:
        px4_name = mavutil.interpret_px4_mode(base_mode, custom_mode)
        if px4_name != "UNKNOWN":
            name = px4_name
    return FlightMode(
        autopilot=who,
        vehicle_type=vehicle_type,
        name=name,
        armed=armed,
        guided=name in _GUIDED_MODES.get(who, set()),
        failsafe=system_status in _FAILSAFE_STATES,
    )
