"""The speed law: how fast the vehicle may fly toward what it has room for, and with what delay."""

from __future__ import annotations

import math

from avoidd.planner.tuning import DEFAULT, Tuning


def stopping_speed_m_s(free_m: float, accel_m_s2: float, latency_s: float) -> float:
    """The largest speed that can still stop within ``free_m`` after a delay of ``latency_s``.

    Solves ``v = sqrt(2 a (d - v t))``.
    """
    if free_m <= 0.0:
        return 0.0
    a, t = accel_m_s2, latency_s
    return -a * t + math.sqrt(a * a * t * t + 2.0 * a * free_m)


def perception_speed_m_s(
    thin_range_m: float, clearance_m: float, accel_m_s2: float, latency_s: float
) -> float:
    """The top speed the cameras can stop for: what is first read at ``thin_range_m``.

    The speed law stops short of what has been read; an obstacle not read yet cannot slow the
    vehicle. The thinnest obstacle the heads promise is first read at ``thin_range_m``, so the
    vehicle must be able to stop within that less its clearance after ``latency_s``.

    Args:
        thin_range_m: Where the heads first read their smallest obstacle.
        clearance_m: Vehicle radius plus margin.
        accel_m_s2: Deceleration available.
        latency_s: Capture to the vehicle acting on a setpoint.

    Returns:
        m/s (0 when the range is within the clearance).
    """
    return stopping_speed_m_s(thin_range_m - clearance_m, accel_m_s2, latency_s)


AUTOPILOT_RESPONSE_S = DEFAULT.autopilot_response_s
"""Time an autopilot's velocity controller takes to act on a new setpoint (part of latency)."""


def effective_latency_s(
    configured_s: float, scan_age_s: float, setpoint_rate_hz: float, tuning: Tuning = DEFAULT
) -> float:
    """The delay the speed law allows for: the configured latency, or more with an old scan.

    What the vehicle does next rests on the newest scan: until a new setpoint acts, the world
    is as old as that scan plus one setpoint period plus the autopilot's response. Perception
    slowed by a loaded machine thus slows the vehicle instead of shrinking its margin.

    Args:
        configured_s: ``avoidance.latency_ms`` in seconds (the floor).
        scan_age_s: Age of the newest scan the planner has (capture to now).
        setpoint_rate_hz: Setpoints per second.
        tuning: The planner's constants (the autopilot's response time).

    Returns:
        Seconds.
    """
    measured_s = max(0.0, scan_age_s) + 1.0 / setpoint_rate_hz + tuning.autopilot_response_s
    return max(configured_s, measured_s)


def drift_speed_limit_m_s(
    drift_m_s: float, max_speed_m_s: float, tuning: Tuning = DEFAULT
) -> float:
    """The speed a vehicle whose positions drift toward a near obstacle flies at, at most.

    An autopilot's velocity estimate can disagree with how its positions move (PX4 SITL under
    CPU load: 0.2-0.8 m/s toward a wall flown along at 1.6 m/s, while it reported flying
    away), and it follows a sideways setpoint slowly at speed. The drift correction asks the
    drift back; flying slower along the obstacle meanwhile leaves the correction more time
    before the clearance is used up, and a disagreement that grows with speed shrinks with
    it. The limit falls by ``drift_slowing`` of the maximum speed per ``back_away_max_m_s``
    of drift, to ``drift_slowest`` of it at most.

    Args:
        drift_m_s: The drift toward the obstacle being asked back (0: none).
        max_speed_m_s: The configured maximum speed.
        tuning: The planner's constants.

    Returns:
        The speed limit (the maximum speed without drift).
    """
    share = 1.0 - tuning.drift_slowing * drift_m_s / tuning.back_away_max_m_s
    return max_speed_m_s * max(tuning.drift_slowest, min(1.0, share))
