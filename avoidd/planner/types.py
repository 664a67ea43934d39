"""The planner's records: the vehicle's state, the goal, and what the planner decides."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Pose:
    """The vehicle's state in the autopilot's local frame.

    Attributes:
        t_ns: When it was true (local monotonic clock).
        north_m: Position north of the origin.
        east_m: Position east.
        down_m: Position down (negative above the origin).
        yaw_rad: Heading, radians from north, clockwise.
        north_m_s: Velocity north (the autopilot's estimate).
        east_m_s: Velocity east.
        track_ne_m_s: Velocity (north, east) fitted to the recent positions (see
            :mod:`avoidd.planner.track`); None when too few are known.
    """

    t_ns: int
    north_m: float
    east_m: float
    down_m: float
    yaw_rad: float
    north_m_s: float = 0.0
    east_m_s: float = 0.0
    track_ne_m_s: tuple[float, float] | None = None


@dataclass(frozen=True)
class Goal:
    """Where to go: local frame, altitude above the origin."""

    north_m: float
    east_m: float
    altitude_m: float
    label: str = "goal"


@dataclass(frozen=True)
class Decision:
    """What the planner wants now.

    Attributes:
        velocity_ned: Velocity setpoint, m/s (north, east, down).
        yaw_rate_rad_s: Yaw rate setpoint.
        state: ``moving``, ``arrived``, ``dead end`` (holding, turning to look), ``no path``,
            ``stale`` (perception is not fresh: holding).
        direction_deg: The chosen direction (degrees from north), if moving.
        speed_limit_m_s: The speed law's limit that way.
        free_m: Free distance along the chosen direction.
        goal_distance_m: Horizontal distance to the goal.
    """

    velocity_ned: tuple[float, float, float]
    yaw_rate_rad_s: float
    state: str
    direction_deg: float | None = None
    speed_limit_m_s: float = 0.0
    free_m: float | None = None
    goal_distance_m: float | None = None

    @property
    def holding(self) -> bool:
        """Whether the setpoint asks for no horizontal motion.

        A hold that backs away or asks a drift back asks for some: its state says that it
        holds.
        """
        return self.velocity_ned[0] == 0.0 and self.velocity_ned[1] == 0.0
