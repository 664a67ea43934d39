"""The ``avoidance`` section: avoidd flies the vehicle to a goal around obstacles (if enabled)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

from pydantic import Field, model_validator

from avoidd.config.base import Lax, Strict


class GoalConfig(Strict):
    """A goal in the autopilot's local frame (NED from its origin), for tests and bench work.

    Attributes:
        north_m: North of the origin.
        east_m: East of the origin.
        altitude_m: Height above the origin (up positive).
    """

    north_m: float = Field(ge=-10_000.0, le=10_000.0)
    east_m: float = Field(ge=-10_000.0, le=10_000.0)
    altitude_m: float = Field(ge=-100.0, le=1000.0)


class AvoidanceConfig(Strict):
    """The local planner and its velocity setpoints.

    Attributes:
        enabled: Send setpoints at all (also switchable in flight with the AVD_ENABLE
            parameter).
        vehicle_radius_m: Radius of the vehicle's footprint, propellers included.
        margin_m: Clearance kept beyond the radius (ArduPilot's ``AVOID_MARGIN`` should be no
            larger, or its own avoidance stops the vehicle first).
        min_margin_m: The smallest margin the ``AVD_MARGIN`` parameter may set (no more than
            ``margin_m``).
        max_speed_m_s: Horizontal speed limit.
        max_accel_m_s2: Deceleration assumed available for the speed law.
        max_yaw_rate_deg_s: Yaw rate limit.
        acceptance_radius_m: A goal within this horizontal distance is reached.
        latency_ms: Time from capture to the vehicle acting on a setpoint (the speed law keeps
            the distance covered meanwhile); a floor: with an older newest scan, its age plus
            one setpoint period plus 0.2 s counts instead.
        setpoint_rate_hz: Setpoints per second (PX4 needs more than 2 Hz).
        memory_s: How long an obstacle that left the cameras' view is remembered.
        unknown: ``blocked``: never plan a move toward a direction nothing measured (as
            PX4's ``CP_GO_NO_DATA 0``); the back-away from an obstacle the vehicle is inside
            the clearance of and the correction of a drift toward one may still go there, at
            most 0.75 m/s; ``free``: treat it as clear.
        climb_rate_m_s: Vertical speed toward the goal altitude.
        dead_end_scan_s: Time spent turning to look for a way before "no path to goal".
        no_progress_s: Also "no path to goal" when the vehicle has not come 0.5 m nearer to
            the goal for this long (it can only go round and round, or back and forth).
        px4_prestream: While armed with a goal in another mode, stream hold-here setpoints
            so that PX4 can be switched to OFFBOARD (it needs a stream above 2 Hz first); not
            after the vehicle left OFFBOARD while armed, nor when avoidd starts while it is
            armed in another mode (PX4 would take the stream back into OFFBOARD by itself),
            until a new goal or a new arming; and never while the autopilot's heartbeat says
            a failsafe is in effect (MAV_STATE_CRITICAL: setpoints would end PX4's
            offboard-loss failsafe and put it back in OFFBOARD), until the pilot picks a mode.
        follow_mission: Fly the autopilot's mission (NAV_WAYPOINT items) as goals.
        goal: A goal to fly to from start (tests, bench work); goals from MAVLink replace it.
        params_file: Where the AVD_* parameters set in flight are kept (JSON, read back at
            start; None: not kept). Under systemd: ``/var/lib/avoidd/params.json``.
    """

    enabled: bool = False
    vehicle_radius_m: float = Field(0.5, gt=0.0, le=5.0)
    margin_m: float = Field(1.0, ge=0.0, le=10.0)
    min_margin_m: float = Field(0.5, ge=0.0, le=10.0)
    max_speed_m_s: float = Field(3.0, gt=0.0, le=20.0)
    max_accel_m_s2: float = Field(2.0, gt=0.0, le=10.0)
    max_yaw_rate_deg_s: float = Field(60.0, gt=0.0, le=360.0)
    acceptance_radius_m: float = Field(1.0, ge=0.1, le=50.0)
    latency_ms: int = Field(400, ge=0, le=2000)
    setpoint_rate_hz: float = Field(20.0, ge=3.0, le=50.0)
    memory_s: float = Field(10.0, ge=0.0, le=60.0)
    unknown: Literal["blocked", "free"] = "blocked"
    climb_rate_m_s: float = Field(1.0, gt=0.0, le=10.0)
    dead_end_scan_s: float = Field(12.0, ge=1.0, le=120.0)
    no_progress_s: float = Field(40.0, ge=5.0, le=600.0)
    px4_prestream: bool = True
    follow_mission: bool = False
    goal: GoalConfig | None = None
    params_file: Annotated[Path, Lax] | None = None

    @model_validator(mode="after")
    def _margin_floor(self) -> AvoidanceConfig:
        if self.margin_m < self.min_margin_m:
            raise ValueError(
                f"margin_m {self.margin_m:g} is below min_margin_m {self.min_margin_m:g}; "
                "raise the margin, or lower min_margin_m too if that is meant"
            )
        return self
