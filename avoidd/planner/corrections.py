"""Corrections to the plan: backing away from what is too near, drift, and braking an overrun.

An autopilot does not fly its setpoint exactly. These stages add to or brake the planned
velocity so that the vehicle's positions stay where the plan wants them: the back-away from
what the vehicle is inside the clearance of (growing while it stays inside), the drift
correction (its positions moving toward a near obstacle faster than its velocity report
says), and braking where the vehicle outruns the plan, along its travel or toward a near
side. Every correction only ever points away from what is near: it costs pace, never margin.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from avoidd.planner.speed import stopping_speed_m_s
from avoidd.planner.surroundings import Surroundings
from avoidd.planner.tuning import DEFAULT, Tuning
from avoidd.planner.types import Pose

Vector = tuple[float, float]


class BackAway:
    """The speed away from remembered obstacles the vehicle is too near, and its growth.

    An autopilot does not follow its setpoint exactly (a loaded or lagging controller drifts
    a few tenths of a metre per second off it), so a vehicle flying along a wall at its
    clearance drifts inside it with nothing to bring it back: the ways toward the wall are
    closed, the way along it is not. Within the clearance by more than ``inside_slack_m``,
    this adds a speed away from that side that grows with the depth
    (``back_away_gain_per_s``) and, while the vehicle stays inside, with time
    (``back_away_growth_per_s2``), up to ``back_away_max_m_s`` (as ArduPilot backs away at
    ``AVOID_BACKUP_SPD``). The growth is what settles an autopilot that follows a sideways
    setpoint only in part while its positions drift toward the wall: depth alone balanced PX4
    SITL about 0.2 m inside its clearance for seconds on end (it flew 60-75 % of the speed
    away it was asked while its positions drifted 0.5 m/s toward the wall).

    The growth is a velocity kept between calls; only its part away from the side now near is
    sent, so what grew against one obstacle never pushes toward another. Calls at one
    position time grow it once.

    Args:
        tuning: The planner's constants.
    """

    def __init__(self, tuning: Tuning = DEFAULT) -> None:
        self.tuning = tuning
        self.grown_ne_m_s: Vector = (0.0, 0.0)
        self._grown_ns: int | None = None

    def velocity(self, around: Surroundings) -> Vector:
        """A velocity (north, east) away from what the vehicle is inside the clearance of."""
        t = self.tuning
        depth_m = around.depth_inside_m
        toward = around.side_within(around.clearance_m) if depth_m > 0.0 else None
        grown_n, grown_e = self.grow(around.pose.t_ns, depth_m, toward)
        if toward is None:
            return (0.0, 0.0)
        away_n, away_e = -math.cos(toward), -math.sin(toward)
        grown_m_s = max(0.0, grown_n * away_n + grown_e * away_e)
        speed = min(
            t.back_away_max_m_s,
            t.back_away_gain_per_s * max(0.0, depth_m - t.inside_slack_m) + grown_m_s,
        )
        if speed <= 0.0:
            return (0.0, 0.0)
        return (speed * away_n, speed * away_e)

    def grow(self, t_ns: int, depth_m: float, toward: float | None) -> Vector:
        """The back-away's growth (north, east) at position time ``t_ns``.

        More than ``inside_slack_m`` inside the clearance (``depth_m``) of one side
        (``toward``), it grows away from that side with the depth beyond that over time, each
        step counted up to ``back_away_step_s``, to ``back_away_max_m_s`` at most. Within the
        slack it is kept as it is, so the speed away does not drop to nothing while the
        vehicle is still inside. Outside the clearance it fades over the time that passed
        (``back_away_fade_s``). Inside with no one side (a corridor narrower than the
        clearance), or after a pause without positions, it starts from nothing. A position
        older than the last one changes nothing.
        """
        t = self.tuning
        if self._grown_ns is not None and t_ns - self._grown_ns > t.pause_ns:
            self.grown_ne_m_s, self._grown_ns = (0.0, 0.0), None
        if self._grown_ns is None:
            self._grown_ns = t_ns
        if t_ns <= self._grown_ns:
            return self.grown_ne_m_s
        elapsed_s = (t_ns - self._grown_ns) / 1e9
        self._grown_ns = t_ns
        north, east = self.grown_ne_m_s
        if depth_m <= 0.0:
            fade = math.exp(-elapsed_s / t.back_away_fade_s)
            north, east = north * fade, east * fade
        elif toward is None:
            north, east = 0.0, 0.0
        elif depth_m > t.inside_slack_m:
            step_s = min(t.back_away_step_s, elapsed_s)
            added = t.back_away_growth_per_s2 * (depth_m - t.inside_slack_m) * step_s
            north, east = north - added * math.cos(toward), east - added * math.sin(toward)
            size = math.hypot(north, east)
            if size > t.back_away_max_m_s:
                north = north * t.back_away_max_m_s / size
                east = east * t.back_away_max_m_s / size
        self.grown_ne_m_s = (north, east)
        return self.grown_ne_m_s


def drift_back_m_s(around: Surroundings) -> Vector:
    """A velocity (north, east) that cancels the drift toward a near obstacle.

    The autopilot flies its own velocity estimate, which need not agree with how its position
    moves (:mod:`avoidd.planner.track`): told to fly along a wall and reporting that it does,
    the vehicle can close on it at 0.2-0.5 m/s for seconds. That disagreement (the track
    velocity less the reported one) carries over to whatever is commanded, so where remembered
    obstacles lie within the clearance plus ``drift_band_m``, all on one side, the part of it
    toward that side (less ``drift_slack_m_s`` of noise, and at most ``back_away_max_m_s``) is
    asked the other way: the autopilot flies that much away in its own frame, which leaves the
    positions where the plan wants them. It is added to the back-away and never points toward
    what is near.

    Args:
        around: The vehicle's surroundings (its pose: reported and track velocity).

    Returns:
        The velocity to add (zeros: none).
    """
    pose, t = around.pose, around.tuning
    if pose.track_ne_m_s is None:
        return (0.0, 0.0)
    toward = around.near_side_rad()
    if toward is None:
        return (0.0, 0.0)
    side_n, side_e = math.cos(toward), math.sin(toward)
    drift_n = pose.track_ne_m_s[0] - pose.north_m_s
    drift_e = pose.track_ne_m_s[1] - pose.east_m_s
    closing_m_s = drift_n * side_n + drift_e * side_e - t.drift_slack_m_s
    if closing_m_s <= 0.0:
        return (0.0, 0.0)
    closing_m_s = min(closing_m_s, t.back_away_max_m_s)
    return (-closing_m_s * side_n, -closing_m_s * side_e)


def held_correction_m_s(
    around: Surroundings,
    backing: Vector,
    max_speed_m_s: float,
    accel_m_s2: float,
    latency_s: float,
) -> Vector:
    """What a hold sends: the back-away plus the drift correction, within what is known.

    A hold plans nothing, so the correction is checked here: no drift part for a
    disagreement beyond ``drift_jump_m_s`` (a position reset) or without a track, no drift
    part against the back-away (:func:`away_m_s`), and no faster than the maximum speed or
    than a stop before the remembered obstacles that way (the speed law's, with the scan's
    age in its delay: stale frames slow it further). When that leaves nothing, the back-away
    alone is checked so. Ground the cameras have not looked at does not stop it, it only caps
    it at ``back_away_max_m_s``: the way out of a wall's clearance is away from where the
    cameras look, so it is seldom seen, and blocking it cancelled every hold's correction
    (PX4 SITL under load: a dead-end hold sent zero for three seconds while its positions
    closed on the wall at 0.4-0.5 m/s, into it).

    Args:
        around: The vehicle's surroundings.
        backing: The back-away (zeros for an arrival: its goal may lie within the clearance
            of a wall, and backing out of the acceptance radius would start the flight again).
        max_speed_m_s: The configured maximum speed.
        accel_m_s2: The deceleration the speed law counts on.
        latency_s: The speed law's delay now.
    """
    pose, t = around.pose, around.tuning
    drifting: Vector = (0.0, 0.0)
    track = pose.track_ne_m_s
    if (
        track is not None
        and math.hypot(track[0] - pose.north_m_s, track[1] - pose.east_m_s) <= t.drift_jump_m_s
    ):
        drifting = drift_back_m_s(around)
    limits = (max_speed_m_s, accel_m_s2, latency_s)
    held = _within_stop(around, away_m_s(backing, drifting), *limits)
    if held == (0.0, 0.0) and backing != (0.0, 0.0):
        held = _within_stop(around, backing, *limits)
    return held


def _within_stop(
    around: Surroundings,
    velocity: Vector,
    max_speed_m_s: float,
    accel_m_s2: float,
    latency_s: float,
) -> Vector:
    """``velocity`` no faster than the maximum speed or a stop before remembered obstacles.

    Toward ground the cameras have not looked at (with ``unknown: blocked``), no faster than a
    back-away at most.
    """
    north, east = velocity
    speed = math.hypot(north, east)
    if speed == 0.0:
        return (0.0, 0.0)
    heading = np.array([math.atan2(east, north)])
    free_m = float(around.obstacle_free_m(heading)[0])
    limit = min(max_speed_m_s, stopping_speed_m_s(free_m, accel_m_s2, latency_s))
    if float(around.free_m(heading)[0]) < free_m:
        limit = min(limit, around.tuning.back_away_max_m_s)
    if speed <= limit:
        return (north, east)
    return (north * limit / speed, east * limit / speed)


def brake_overspeed(
    planned_m_s: Vector,
    away_m_s: Vector,
    pose: Pose,
    max_speed_m_s: float,
    tuning: Tuning = DEFAULT,
) -> Vector:
    """The planned velocity with extra braking where the vehicle outruns it.

    The speed law and the turning buffer take it that the vehicle follows its setpoint within
    a few tenths of a second. An autopilot may not: PX4's velocity loop on a vehicle with
    drag holds about 80 % of a steady setpoint with its integrator, and when the setpoint
    drops (the speed law braking for a wall, or a turn along it) that wound-up integrator
    keeps the vehicle going: measured in SITL it flew on at 1.5 m/s for half a second after
    the setpoint had fallen to 1.2, and 0.6 m farther toward the wall than the plan after a
    turn. So where the vehicle moves faster along its own direction of travel than the plan
    wants that way (none: a plan the other way counts as zero), by more than a vehicle
    following its setpoint lags it anyway (``overspeed_slack_m_s``), the setpoint also asks
    for the excess back, against that direction; the correction fades as the vehicle slows
    to the plan.

    The correction only ever brakes: a part of it along the planned velocity or against the
    speed away from what the vehicle is too near is not sent; when both cannot be kept out,
    none of it is. It shares the maximum speed with the plan, which is kept whole.

    Args:
        planned_m_s: The planned velocity (north, east), back-away included.
        away_m_s: The back-away part of it (zeros: none).
        pose: The vehicle's state (its measured velocity).
        max_speed_m_s: The setpoint's speed stays within this.
        tuning: The planner's constants.

    Returns:
        The velocity to command (north, east).
    """
    unit = _unit((pose.north_m_s, pose.east_m_s))
    if unit is None:
        return planned_m_s
    moving_m_s = math.hypot(pose.north_m_s, pose.east_m_s)
    planned = np.array(planned_m_s, dtype=np.float64)
    wanted_m_s = max(0.0, float(planned @ unit))
    excess_m_s = moving_m_s - wanted_m_s - tuning.overspeed_slack_m_s
    if excess_m_s <= 0.0:
        return planned_m_s
    correction = -tuning.overspeed_gain * excess_m_s * unit
    plan_unit = _unit(planned_m_s)
    away_unit = _unit(away_m_s)
    if plan_unit is not None:
        correction -= max(0.0, float(correction @ plan_unit)) * plan_unit
    if away_unit is not None:
        correction -= min(0.0, float(correction @ away_unit)) * away_unit
    if (plan_unit is not None and float(correction @ plan_unit) > 1e-9) or (
        away_unit is not None and float(correction @ away_unit) < -1e-9
    ):
        return planned_m_s
    return with_back_away((float(correction[0]), float(correction[1])), planned_m_s, max_speed_m_s)


def brake_closing(
    command_m_s: Vector,
    planned_m_s: Vector,
    pose: Pose,
    side_rad: float,
    max_speed_m_s: float,
    tuning: Tuning = DEFAULT,
) -> Vector:
    """The command with the vehicle's excess speed toward a near side asked back.

    :func:`brake_overspeed` looks along the vehicle's own direction of travel. Flying along a
    wall, PX4 SITL also kept closing on it sideways at 0.1-0.2 m/s for two seconds while the
    plan asked 0.1-0.3 m/s away (its velocity loop winding down from braking for the wall
    before the turn): its own velocity report showed it, so the drift check did not. Here the
    part of the reported velocity toward the near side beyond what the plan wants that way
    (none when the plan points away), less a slack and whatever the command already asks back
    that way, is asked back, up to ``back_away_max_m_s``. The slack is ``drift_slack_m_s``
    when the plan flies along or away from the side, and grows to ``overspeed_slack_m_s``
    over the first ``closing_ramp_m_s`` the plan wants toward it. It only ever points away
    from the side.

    Args:
        command_m_s: The velocity to command so far (north, east).
        planned_m_s: The plan before any braking (back-away included).
        pose: The vehicle's state (its reported velocity).
        side_rad: Bearing of the near side (see :meth:`Surroundings.near_side_rad`).
        max_speed_m_s: The setpoint's speed stays within this.
        tuning: The planner's constants.

    Returns:
        The velocity to command (north, east).
    """
    t = tuning
    side = np.array((math.cos(side_rad), math.sin(side_rad)))
    closing_m_s = float(np.array((pose.north_m_s, pose.east_m_s)) @ side)
    wanted_m_s = max(0.0, float(np.array(planned_m_s) @ side))
    asked_back_m_s = max(0.0, float((np.array(planned_m_s) - np.array(command_m_s)) @ side))
    share = min(1.0, wanted_m_s / t.closing_ramp_m_s)
    slack_m_s = t.drift_slack_m_s + share * (t.overspeed_slack_m_s - t.drift_slack_m_s)
    excess_m_s = closing_m_s - wanted_m_s - slack_m_s - asked_back_m_s
    if excess_m_s <= 0.0:
        return command_m_s
    back = -min(excess_m_s, t.back_away_max_m_s) * side
    return with_back_away(command_m_s, (float(back[0]), float(back[1])), max_speed_m_s)


def away_m_s(backing: Vector, drifting: Vector) -> Vector:
    """The back-away plus the drift correction, no part of the drift against the back-away.

    The back-away flees what the vehicle is inside the clearance of; the drift correction
    flees the side of what is near within the clearance plus ``drift_band_m``, which can be
    another obstacle on the other side. The drift's part against the back-away would push the
    vehicle at what it is already too near, so it is dropped; its part across it stays.

    Args:
        backing: :meth:`BackAway.velocity`.
        drifting: :func:`drift_back_m_s`.

    Returns:
        The velocity to add (north, east).
    """
    back_m_s = math.hypot(*backing)
    drift_n, drift_e = drifting
    if back_m_s > 0.0:
        unit_n, unit_e = backing[0] / back_m_s, backing[1] / back_m_s
        along = drift_n * unit_n + drift_e * unit_e
        if along < 0.0:
            drift_n, drift_e = drift_n - along * unit_n, drift_e - along * unit_e
    return (backing[0] + drift_n, backing[1] + drift_e)


def with_back_away(way: Vector, away: Vector, max_speed_m_s: float) -> Vector:
    """The velocity along the way chosen plus the one away from what is too near.

    The speed away is kept whole (up to the maximum speed); the speed along the way gives way
    so that the sum stays within the maximum.
    """
    away_speed = math.hypot(*away)
    if away_speed == 0.0:
        return way
    if away_speed > max_speed_m_s:
        away = (away[0] * max_speed_m_s / away_speed, away[1] * max_speed_m_s / away_speed)
        away_speed = max_speed_m_s
    way_sq = way[0] ** 2 + way[1] ** 2
    north, east = way[0] + away[0], way[1] + away[1]
    if way_sq == 0.0 or math.hypot(north, east) <= max_speed_m_s:
        return (north, east)
    # The largest share s of the way with |s * way + away| = max speed.
    dot = way[0] * away[0] + way[1] * away[1]
    root = math.sqrt(max(0.0, dot * dot - way_sq * (away_speed**2 - max_speed_m_s**2)))
    share = max(0.0, min(1.0, (root - dot) / way_sq))
    return (share * way[0] + away[0], share * way[1] + away[1])


def _unit(vector: Vector) -> npt.NDArray[np.float64] | None:
    """The direction of a horizontal vector (None for a zero one)."""
    size = math.hypot(*vector)
    return None if size == 0.0 else np.array(vector, dtype=np.float64) / size
