"""The local planner's step: from the vehicle's state, the obstacles and a goal to a velocity.

VFH+ in spirit, over 72 world directions (5 degrees from north):

- every obstacle point is enlarged by the vehicle's radius plus the margin, exactly for a disc
  (:func:`~avoidd.planner.geometry.free_distance`): each direction gets the distance it is free
  for; a direction whose scan bin (or a neighbour) is unknown is blocked, unless unknown is
  configured free;
- a binary histogram with two thresholds (hysteresis): a direction is admissible once it is
  free for ``enter`` metres, and stays so until it is free for less than ``leave``;
- among admissible directions the cheapest wins, ``mu1 |goal delta| + mu2 |heading delta| +
  mu3 |previous delta|`` with ``mu1 > mu2 + mu3``; once the vehicle has turned to one side of
  the goal direction to pass an obstacle, the other side costs extra until the goal direction
  is admissible again (no flipping between the two sides of a pole);
- speed along it: ``v <= min(v_max, sqrt(2 a (d - v latency)))``, ``d`` the free distance that
  way (radius and margin already taken off), and no faster than stopping at the goal; the
  latency is the configured one, or more when the newest scan is older than it allows for (a
  loaded machine): its age, one setpoint period and the autopilot's response
  (:func:`effective_latency_s`);
- a vehicle that outruns the plan (its autopilot slow to brake or to leave the old direction
  in a turn) is asked for the excess back (:func:`brake_overspeed`);
- yaw toward the direction of travel (rate-limited), so a forward camera sees the way, and
  going round something as far toward the goal as keeps the way in view (a corridor's turn or
  a wall's end is seen early);
- no admissible direction: hold, then turn up to 180 degrees each way looking for one toward
  the goal's side; none within ``dead_end_scan_s``: hold and say "no path to goal". Never
  crawl forward. Also "no path" once the vehicle has gone a whole turn round the goal without
  once seeing the line to it clear (what blocks it encloses the goal).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from avoidd.config import AvoidanceConfig
from avoidd.planner.geometry import directions_rad, free_distance, gap_headings, wrap_rad
from avoidd.planner.memory import ObstacleMemory
from avoidd.planner.visibility import VisibilityGrid
from avoidd.types import SECTOR_COUNT, SECTOR_WIDTH_DEG

MU_GOAL = 5.0
MU_HEADING = 2.0
MU_PREVIOUS = 2.0
MU_OBSTRUCTED = 5.0
COMMITMENT_COST = 3.0 * math.pi * MU_GOAL
"""Extra cost of the side of the goal direction the vehicle is not committed to."""
MAX_SIDE_CHANGES = 2
"""Side changes allowed while going round one obstacle (the goal direction blocked); a third
would be dithering: the planner looks for a way on the side it is on, then gives up."""
_ALTITUDE_GAIN = 1.0
_BUFFER_M = 0.25
_BUFFER_S = 0.15
"""Turning buffer: metres, and metres per m/s of speed (see :meth:`Planner.decide`)."""
_SLOW_FOR_GAP_M_S = (1.0, 0.5)
"""Speeds at which the turning buffer lets a gap open that is too narrow at full speed."""
_PASSING_RAD = math.radians(30.0)
"""A way this much nearer the goal's direction than the one flown is worth slowing down for."""
_ONWARD_RAD = math.radians(100.0)
"""Ways within this of the goal's direction go onward; beyond it the vehicle backs out."""
_BACK_RAD = math.radians(170.0)
"""Ways at least this far from the goal's direction lead straight back."""
_LEAVE_M = 0.4
"""A way stays admissible down to this much free distance (it becomes admissible from 1 m):
the speed law brings the vehicle up to its margin and it stops there, not half a metre short."""
_STRAIGHT_RAD = math.radians(5.0)
"""Ways within this of the vehicle's velocity need no turning room (see :meth:`Planner.decide`)."""
_YAW_GAIN = 2.0
_PAUSE_NS = 1_000_000_000
"""A gap this long between decisions means planning was paused (its timers restart)."""
_INSIDE_SLACK_M = 0.05
"""Within the clearance of a point, the ways that bring the vehicle this much nearer close."""
_TOWARD_RAD = math.radians(88.0)
"""Ways this close to the side of what is within the clearance bring the vehicle nearer."""
_ONE_SIDED = 0.5
"""How one-sided the points within the clearance must be for that side to count."""
_BACK_AWAY_GAIN = 2.0
"""Speed away from what the vehicle is within the clearance of, m/s per metre inside."""
_BACK_AWAY_MAX_M_S = 0.75
"""At most this fast (ArduPilot's ``AVOID_BACKUP_SPD`` default)."""
_BACK_AWAY_GROWTH = 2.0
"""While the vehicle stays inside the clearance, its back-away grows by this many m/s per
metre inside per second (see :meth:`Planner.back_away_m_s`)."""
_BACK_AWAY_FADE_S = 1.0
"""Outside the clearance, what the back-away grew by fades with this time constant."""
_BACK_AWAY_STEP_S = 0.25
"""The longest step the growth integrates over (a longer gap between positions counts so)."""
_ARRIVED_ALTITUDE_M = 0.5
_BACK_OUT_AFTER_NS = 300_000_000
"""A way back must stay the choice this long before the vehicle turns back (it brakes first)."""
_TURN_BACK_M_S = 0.5
"""Slower than this, turning back needs no braking first."""
_TURN_BACK_RAD = math.radians(100.0)
"""A way this far from the vehicle's velocity turns it back on itself (it brakes first)."""
_OVERSPEED_GAIN = 1.0
"""Extra braking, m/s of setpoint per m/s the vehicle is faster than the plan (see
:func:`brake_overspeed`)."""
_OVERSPEED_SLACK_M_S = 0.25
"""Faster than the plan by at most this is ordinary lag (a vehicle that follows its setpoint within
the latency the speed law allows for lags it so while braking): no extra braking."""
_DRIFT_BAND_M = 1.0
"""Drift toward what is within the clearance plus this is checked (see
:meth:`Planner.drift_back_m_s`): about a second of the drift seen in SITL before it would reach
the clearance."""
_DRIFT_SLACK_M_S = 0.1
"""Disagreement between the track and the reported velocity up to this is noise (see
:meth:`Planner.drift_back_m_s`)."""
_CLOSING_RAMP_M_S = 0.25
"""Over this much planned speed toward a near side the closing brake's slack grows from the
drift's noise to the overspeed brake's (see :func:`brake_closing`)."""
_DRIFT_JUMP_M_S = 1.5
"""A disagreement between the track and the reported velocity beyond this is a position reset
(a jump fitted as a speed), not a drift: a hold sends nothing for it."""
_DRIFT_SLOWING = 0.5
"""While the positions drift toward a near obstacle, the speed falls by this share of the
maximum speed per :data:`_BACK_AWAY_MAX_M_S` of drift (see :func:`drift_speed_limit_m_s`)."""
_DRIFT_SLOWEST = 0.5
"""The drift never slows the vehicle below this share of its maximum speed."""
_LOOK_ASIDE_RAD = math.radians(90.0)
"""When the way chosen is this far from the best way were unseen ground free (the vehicle is
about to turn away from it), the cameras look at the first unseen part of that best way."""


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


def stopping_speed_m_s(free_m: float, accel_m_s2: float, latency_s: float) -> float:
    """The largest speed that can still stop within ``free_m`` after a delay of ``latency_s``.

    Solves ``v = sqrt(2 a (d - v t))``.
    """
    if free_m <= 0.0:
        return 0.0
    a, t = accel_m_s2, latency_s
    return -a * t + math.sqrt(a * a * t * t + 2.0 * a * free_m)


AUTOPILOT_RESPONSE_S = 0.2
"""Time an autopilot's velocity controller takes to act on a new setpoint (part of latency)."""


def effective_latency_s(configured_s: float, scan_age_s: float, setpoint_rate_hz: float) -> float:
    """The delay the speed law allows for: the configured latency, or more with an old scan.

    What the vehicle does next rests on the newest scan: until a new setpoint acts, the world
    is as old as that scan plus one setpoint period plus the autopilot's response. Perception
    slowed by a loaded machine thus slows the vehicle instead of shrinking its margin.

    Args:
        configured_s: ``avoidance.latency_ms`` in seconds (the floor).
        scan_age_s: Age of the newest scan the planner has (capture to now).
        setpoint_rate_hz: Setpoints per second.

    Returns:
        Seconds.
    """
    measured_s = max(0.0, scan_age_s) + 1.0 / setpoint_rate_hz + AUTOPILOT_RESPONSE_S
    return max(configured_s, measured_s)


@dataclass
class Planner:
    """The planner of one vehicle: its memory, hysteresis and commitment between steps.

    Args:
        config: The ``avoidance`` section.
        max_range_m: The sensors' maximum range (a clear bin sees this far).
    """

    config: AvoidanceConfig
    max_range_m: float
    memory: ObstacleMemory = field(init=False)
    _admissible: np.ndarray = field(init=False)
    _previous_rad: float | None = None
    _side: int = 0
    _side_changes: int = 0
    _dead_end_since_ns: int | None = None
    _turned_rad: float = 0.0
    _last_yaw_rad: float = 0.0
    _last_scan_ns: int = -1
    _best_goal_m: float = math.inf
    _best_since_ns: int | None = None
    _given_up: bool = False
    _goal_bearing_rad: float | None = None
    _circled_rad: float = 0.0
    _scan_side: float = 1.0
    _last_decide_ns: int | None = None
    _back_since_ns: int | None = None
    _grown_ne_m_s: tuple[float, float] = (0.0, 0.0)
    _grown_ns: int | None = None
    _in_view: np.ndarray = field(init=False)
    _view_margin_rad: float = field(init=False)

    def __post_init__(self) -> None:
        self._in_view = np.zeros(SECTOR_COUNT, dtype=np.bool_)
        self.memory = ObstacleMemory(self.config.memory_s)
        self.visibility = VisibilityGrid()
        config = self.config
        latency_s = config.latency_ms / 1000.0
        # Beyond the stopping distance at full speed nothing unseen matters yet.
        self._look_m = (
            config.max_speed_m_s**2 / (2 * config.max_accel_m_s2)
            + config.max_speed_m_s * latency_s
            + 1.0
        )
        # The way flown stays this far inside the view when the cameras turn toward the goal:
        # the corridor the vehicle sweeps, seen from a stop away, and one bin of jitter.
        self._view_margin_rad = math.atan2(self.clearance_m, self._look_m) + math.radians(
            SECTOR_WIDTH_DEG
        )
        self._directions = directions_rad()
        self._admissible = np.zeros(self._directions.size, dtype=np.bool_)

    def reconfigure(self, config: AvoidanceConfig) -> None:
        """Take new settings (parameters set in flight); the memory is kept."""
        memory, visibility, in_view = self.memory, self.visibility, self._in_view
        self.config = config
        self.__post_init__()
        self.memory, self.visibility, self._in_view = memory, visibility, in_view
        self.memory.memory_s = config.memory_s

    @property
    def clearance_m(self) -> float:
        """Vehicle radius plus margin: how far every obstacle is kept."""
        return self.config.vehicle_radius_m + self.config.margin_m

    def reset(self) -> None:
        """Start over for a new goal.

        The memory is kept (the obstacles did not move), and so is the back-away's growth
        (:meth:`_grow`: the autopilot's drift did not change either).
        """
        self._admissible[:] = False
        self._previous_rad = None
        self._side = 0
        self._side_changes = 0
        self._dead_end_since_ns = None
        self._best_goal_m = math.inf
        self._best_since_ns = None
        self._given_up = False
        self._goal_bearing_rad = None
        self._circled_rad = 0.0
        self._back_since_ns = None

    def observe_scan(
        self, distance_m: np.ndarray, t_capture_ns: int, pose_at_capture: Pose
    ) -> None:
        """Take a fresh merged scan (body bins) with the vehicle's pose at its capture."""
        if t_capture_ns <= self._last_scan_ns:
            return
        self._last_scan_ns = t_capture_ns
        self._in_view |= ~np.isnan(distance_m)  # the bins the heads cover (their mounts are fixed)
        where = (pose_at_capture.north_m, pose_at_capture.east_m)
        self.memory.add_scan(
            distance_m, t_capture_ns, where, pose_at_capture.yaw_rad, self.max_range_m
        )
        self.visibility.mark(
            where, pose_at_capture.yaw_rad, distance_m, t_capture_ns, self.max_range_m
        )

    def hold(
        self, state: str, goal_distance_m: float | None = None, pose: Pose | None = None
    ) -> Decision:
        """Stay here: no turning, no planned motion (not a decision: planning is paused).

        With the vehicle's ``pose``, "here" is where its positions are and outside the
        clearance of what it remembers: inside it, the hold backs away
        (:meth:`back_away_m_s`), and a drift of the positions toward a near remembered
        obstacle that the reported velocity does not show is asked back
        (:meth:`drift_back_m_s`), as on the move. Told to hold zero, PX4 SITL under CPU load
        let its positions close on a wall at 0.3-0.4 m/s for five seconds, reporting about
        zero, and ran into it while avoidd held on stale frames; with the drift asked back but
        no back-away, holds flickering with moves (frames just over ``max_age_ms`` old) halved
        the back-away PX4 saw and it closed from 1.1 to 0.35 m of the wall's edge.
        """
        north, east = (0.0, 0.0) if pose is None else self._held_correction_m_s(pose)
        return Decision((north, east, 0.0), 0.0, state, goal_distance_m=goal_distance_m)

    def _held_correction_m_s(self, pose: Pose, back_away: bool = True) -> tuple[float, float]:
        """What a hold sends: the back-away plus the drift correction, within what is known.

        A hold plans nothing, so the correction is checked here: no drift part for a
        disagreement beyond :data:`_DRIFT_JUMP_M_S` (a position reset) or without a track, no
        drift part against the back-away (:func:`away_m_s`), and no faster than the maximum
        speed or than a stop before the remembered obstacles that way (the speed law's, with
        the scan's age in its delay: stale frames slow it further). When that leaves nothing,
        the back-away alone is checked so. Ground the cameras have not looked at does not
        stop it (``unknown: blocked`` does for planned moves), it only caps it at
        :data:`_BACK_AWAY_MAX_M_S`: the way out of a wall's clearance is away from where the
        cameras look, so it is seldom seen, and blocking it cancelled every hold's correction
        (PX4 SITL under load: a dead-end hold sent zero for three seconds while its positions
        closed on the wall at 0.4-0.5 m/s, into it). A move adds the back-away unchecked by
        what was seen; an arrival's drift correction goes through here too.

        Args:
            pose: The vehicle's state.
            back_away: Back away from what the vehicle is inside the clearance of (an arrival
                does not: its goal may lie within the clearance of a wall, and backing out of
                the acceptance radius would start the flight again).
        """
        self.memory.expire(pose.t_ns)
        backing = self.back_away_m_s(pose) if back_away else (0.0, 0.0)
        drifting = (0.0, 0.0)
        track = pose.track_ne_m_s
        if (
            track is not None
            and math.hypot(track[0] - pose.north_m_s, track[1] - pose.east_m_s) <= _DRIFT_JUMP_M_S
        ):
            drifting = self.drift_back_m_s(pose)
        held = self._within_stop(pose, away_m_s(backing, drifting))
        if held == (0.0, 0.0) and backing != (0.0, 0.0):
            held = self._within_stop(pose, backing)
        return held

    def _within_stop(self, pose: Pose, velocity: tuple[float, float]) -> tuple[float, float]:
        """``velocity`` no faster than the maximum speed or a stop before remembered obstacles.

        Toward ground the cameras have not looked at (with ``unknown: blocked``), no faster
        than a back-away at most (:data:`_BACK_AWAY_MAX_M_S`).
        """
        north, east = velocity
        speed = math.hypot(north, east)
        if speed == 0.0:
            return (0.0, 0.0)
        heading = np.array([math.atan2(east, north)])
        free_m = float(self.obstacle_free_m(pose, heading)[0])
        limit = min(
            self.config.max_speed_m_s,
            stopping_speed_m_s(free_m, self.config.max_accel_m_s2, self._latency_s(pose.t_ns)),
        )
        if float(self.free_m(pose, heading)[0]) < free_m:
            limit = min(limit, _BACK_AWAY_MAX_M_S)
        if speed <= limit:
            return (north, east)
        return (north * limit / speed, east * limit / speed)

    def obstacle_free_m(
        self, pose: Pose, headings_rad: np.ndarray, buffer_m: float | np.ndarray = 0.0
    ) -> np.ndarray:
        """Free distance along each heading among the remembered obstacles only.

        Where the vehicle's disc (radius, margin and ``buffer_m``) would meet a remembered
        obstacle point.
        """
        offsets, ranges_m = self.memory.near((pose.north_m, pose.east_m))
        clearance = self.clearance_m + buffer_m
        if not offsets.size:
            return free_distance(offsets, headings_rad, clearance)
        # Already nearer than that to something (pushed by wind, stopped at a wall with the
        # overshoot of stereo, or the buffer is wider than the corridor): keep at least the
        # distance there is, so that the ways along or away from it stay open.
        nearest_m = float(np.min(ranges_m))
        inside = max(nearest_m - _INSIDE_SLACK_M, self.config.vehicle_radius_m)
        free = free_distance(offsets, headings_rad, np.minimum(clearance, inside))
        # That alone lets the vehicle creep in a few centimetres a cycle along a slant (each
        # cycle's nearest point is the new limit): the ways toward what is within the
        # clearance close, toward the side it is on as a whole (a wall's points within the
        # clearance, weighted by how far in; none when they surround the vehicle evenly, as a
        # corridor narrower than the clearance does).
        toward = self._side_within(offsets, ranges_m, self.clearance_m)
        if toward is not None:
            closer = np.abs(wrap_rad(headings_rad - toward)) < _TOWARD_RAD
            free = np.where(closer, 0.0, free)
        return free

    @staticmethod
    def _side_within(offsets: np.ndarray, ranges_m: np.ndarray, within_m: float) -> float | None:
        """The bearing (radians) of the side the points nearer than ``within_m`` are on.

        The points are weighted by how far in they are; None when none is that near, or when
        they surround the vehicle evenly (a corridor narrower than that).
        """
        within = ranges_m < within_m
        if not within.any():
            return None
        depth = (within_m - ranges_m[within]) / ranges_m[within]
        push = (depth[:, None] * offsets[within]).sum(axis=0)
        if float(np.hypot(*push)) < _ONE_SIDED * float(depth.sum() * np.min(ranges_m)):
            return None
        return math.atan2(float(push[1]), float(push[0]))

    def back_away_m_s(self, pose: Pose) -> tuple[float, float]:
        """A velocity (north, east) away from remembered obstacles the vehicle is too near.

        An autopilot does not follow its setpoint exactly (a loaded or lagging controller
        drifts a few tenths of a metre per second off it), so a vehicle flying along a wall at
        its clearance drifts inside it with nothing to bring it back: the ways toward the wall
        are closed, the way along it is not. Within the clearance by more than a few
        centimetres, this adds a speed away from that side that grows with the depth
        (:data:`_BACK_AWAY_GAIN`) and, while the vehicle stays inside, with time
        (:data:`_BACK_AWAY_GROWTH`), up to :data:`_BACK_AWAY_MAX_M_S` (as ArduPilot backs away
        at ``AVOID_BACKUP_SPD``). The growth is what settles an autopilot that follows a
        sideways setpoint only in part while its positions drift toward the wall: depth alone
        balanced PX4 SITL about 0.2 m inside its clearance for seconds on end (it flew
        60-75 % of the speed away it was asked while its positions drifted 0.5 m/s toward the
        wall).

        The growth is a velocity kept between calls (:meth:`_grow`); only its part away from
        the side now near is sent, so what grew against one obstacle never pushes toward
        another. This is the one place it changes: the planner calls this once per cycle, and
        calls at one position time grow it once.
        """
        offsets, ranges_m = self.memory.near((pose.north_m, pose.east_m))
        depth_m = self.clearance_m - float(np.min(ranges_m)) if offsets.size else 0.0
        toward = None
        if depth_m > 0.0:
            toward = self._side_within(offsets, ranges_m, self.clearance_m)
        grown_n, grown_e = self._grow(pose.t_ns, depth_m, toward)
        if toward is None:
            return (0.0, 0.0)
        away_n, away_e = -math.cos(toward), -math.sin(toward)
        grown_m_s = max(0.0, grown_n * away_n + grown_e * away_e)
        speed = min(
            _BACK_AWAY_MAX_M_S,
            _BACK_AWAY_GAIN * max(0.0, depth_m - _INSIDE_SLACK_M) + grown_m_s,
        )
        if speed <= 0.0:
            return (0.0, 0.0)
        return (speed * away_n, speed * away_e)

    def _grow(self, t_ns: int, depth_m: float, toward: float | None) -> tuple[float, float]:
        """The back-away's growth (north, east) at position time ``t_ns``.

        More than :data:`_INSIDE_SLACK_M` inside the clearance (``depth_m``) of one side
        (``toward``), it grows away from that side with the depth beyond that over time, each
        step counted up to :data:`_BACK_AWAY_STEP_S`, to :data:`_BACK_AWAY_MAX_M_S` at most.
        Within the slack it is kept as it is, so the speed away does not drop to nothing while
        the vehicle is still inside. Outside the clearance it fades over the time that passed
        (:data:`_BACK_AWAY_FADE_S`). Inside with no one side (a corridor narrower than the
        clearance), or after more than a second without a position, it starts from nothing.
        A position older than the last one changes nothing.
        """
        if self._grown_ns is not None and t_ns - self._grown_ns > _PAUSE_NS:
            self._grown_ne_m_s, self._grown_ns = (0.0, 0.0), None
        if self._grown_ns is None:
            self._grown_ns = t_ns
        if t_ns <= self._grown_ns:
            return self._grown_ne_m_s
        elapsed_s = (t_ns - self._grown_ns) / 1e9
        self._grown_ns = t_ns
        north, east = self._grown_ne_m_s
        if depth_m <= 0.0:
            fade = math.exp(-elapsed_s / _BACK_AWAY_FADE_S)
            north, east = north * fade, east * fade
        elif toward is None:
            north, east = 0.0, 0.0
        elif depth_m > _INSIDE_SLACK_M:
            added = (
                _BACK_AWAY_GROWTH * (depth_m - _INSIDE_SLACK_M) * min(_BACK_AWAY_STEP_S, elapsed_s)
            )
            north, east = north - added * math.cos(toward), east - added * math.sin(toward)
            size = math.hypot(north, east)
            if size > _BACK_AWAY_MAX_M_S:
                north, east = north * _BACK_AWAY_MAX_M_S / size, east * _BACK_AWAY_MAX_M_S / size
        self._grown_ne_m_s = (north, east)
        return self._grown_ne_m_s

    def near_side_rad(self, pose: Pose) -> float | None:
        """The bearing of the side remembered obstacles near the vehicle are on.

        Near: within the clearance plus :data:`_DRIFT_BAND_M`, all on one side (None when
        there are none, or they surround the vehicle as a narrow corridor's walls do).
        """
        offsets, ranges_m = self.memory.near((pose.north_m, pose.east_m))
        if not offsets.size:
            return None
        return self._side_within(offsets, ranges_m, self.clearance_m + _DRIFT_BAND_M)

    def drift_back_m_s(self, pose: Pose) -> tuple[float, float]:
        """A velocity (north, east) that cancels the drift toward a near obstacle.

        The autopilot flies its own velocity estimate, which need not agree with how its
        position moves (:mod:`avoidd.planner.track`): told to fly along a wall and reporting
        that it does, the vehicle can close on it at 0.2-0.5 m/s for seconds. That
        disagreement (the track velocity less the reported one) carries over to whatever is
        commanded, so where remembered obstacles lie within the clearance plus
        :data:`_DRIFT_BAND_M`, all on one side, the part of it toward that side (less
        :data:`_DRIFT_SLACK_M_S` of noise, and at most :data:`_BACK_AWAY_MAX_M_S`) is asked
        the other way: the autopilot flies that much away in its own frame, which leaves the
        positions where the plan wants them. It is added to the back-away (the plan gives way
        to both within the maximum speed) and never points toward what is near. Holds with
        a known pose (dead end, stale, no path) send this with the back-away, an arrival
        this alone.

        Args:
            pose: The vehicle's state: its reported and track velocity.

        Returns:
            The velocity to add (zeros: none).
        """
        if pose.track_ne_m_s is None:
            return (0.0, 0.0)
        toward = self.near_side_rad(pose)
        if toward is None:
            return (0.0, 0.0)
        side_n, side_e = math.cos(toward), math.sin(toward)
        drift_n = pose.track_ne_m_s[0] - pose.north_m_s
        drift_e = pose.track_ne_m_s[1] - pose.east_m_s
        closing_m_s = drift_n * side_n + drift_e * side_e - _DRIFT_SLACK_M_S
        if closing_m_s <= 0.0:
            return (0.0, 0.0)
        closing_m_s = min(closing_m_s, _BACK_AWAY_MAX_M_S)
        return (-closing_m_s * side_n, -closing_m_s * side_e)

    def free_m(
        self, pose: Pose, headings_rad: np.ndarray, buffer_m: float | np.ndarray = 0.0
    ) -> np.ndarray:
        """Free distance along each heading from a pose (``buffer_m``: one, or one each).

        The nearer of :meth:`obstacle_free_m` and, with unknown directions blocked, where the
        vehicle's corridor reaches ground the cameras have not looked at within the memory
        time.
        """
        free = self.obstacle_free_m(pose, headings_rad, buffer_m)
        if self.config.unknown == "blocked":
            # The corridor must have been seen as wide as the vehicle keeps from obstacles (the
            # turning buffer is about following a path past known ones).
            since_ns = pose.t_ns - int(self.config.memory_s * 1e9)
            seen = self.visibility.seen_distance(
                (pose.north_m, pose.east_m), headings_rad, self.clearance_m, self._look_m, since_ns
            )
            free = np.minimum(free, seen)
        return free

    def decide(self, now_ns: int, pose: Pose, goal: Goal, fresh: bool) -> Decision:
        """The velocity and yaw rate to command now.

        Args:
            now_ns: The current time.
            pose: The vehicle's current state.
            goal: Where to go.
            fresh: Whether perception is fresh (else: hold).

        Returns:
            The decision.
        """
        config = self.config
        if self._last_decide_ns is not None and now_ns - self._last_decide_ns > _PAUSE_NS:
            # Not planning for a while (another mode, a stale hold): time spent so is not
            # time without progress, nor time spent looking for a way.
            self._best_since_ns = None
            self._dead_end_since_ns = None
            self._goal_bearing_rad = None
            self._back_since_ns = None
        self._last_decide_ns = now_ns
        self.memory.expire(now_ns)
        to_north, to_east = goal.north_m - pose.north_m, goal.east_m - pose.east_m
        goal_m = math.hypot(to_north, to_east)
        climb = _ALTITUDE_GAIN * (goal.altitude_m + pose.down_m)
        vertical = -max(-config.climb_rate_m_s, min(config.climb_rate_m_s, climb))
        if not fresh:
            return self.hold("stale", goal_m, pose)
        if goal_m <= config.acceptance_radius_m:
            self._best_since_ns = None
            self._dead_end_since_ns = None
            state = "arrived" if abs(climb) <= _ARRIVED_ALTITUDE_M else "moving"
            north, east = self._held_correction_m_s(pose, back_away=False)
            return Decision((north, east, vertical), 0.0, state, goal_distance_m=goal_m)
        if self._no_progress(now_ns, goal_m):
            return self.hold("no path", goal_m, pose)
        goal_rad = math.atan2(to_east, to_north)
        # Directions are chosen with room to spare for the turn the vehicle takes to follow
        # them (it lags its setpoint by a few tenths of a second): more at speed.
        buffer = _BUFFER_M + _BUFFER_S * math.hypot(pose.north_m_s, pose.east_m_s)
        # One pass over the memory and the seen grid for every heading this cycle looks at: the
        # 72 directions, the goal's, and the middles of gaps the 5-degree grid may step over.
        gaps = gap_headings(
            self.memory.offsets((pose.north_m, pose.east_m)),
            self.clearance_m + buffer,
            self._look_m,
        )
        candidates = np.concatenate([self._directions, [goal_rad], gaps])
        # Flying on the way it already flies, the vehicle does not turn: no turning room is
        # kept there, so a corridor that is wide enough at walking pace stays open at speed
        # (else the vehicle turns back until it has slowed down, and then turns again).
        along = math.atan2(pose.east_m_s, pose.north_m_s)
        straight = np.abs(wrap_rad(candidates - along)) <= _STRAIGHT_RAD
        looked = self.free_m(pose, candidates, np.where(straight, min(buffer, _BUFFER_M), buffer))
        grid_count = self._directions.size
        free, goal_free = looked[:grid_count], float(looked[grid_count])
        gaps_free = looked[grid_count + 1 :]
        enter = max(config.acceptance_radius_m, 1.0)
        leave = _LEAVE_M
        self._admissible = np.where(
            free >= enter, True, np.where(free < leave, False, self._admissible)
        )
        # The admissible grid directions, and the gaps' middles with room to go.
        headings = self._directions[self._admissible]
        headings_free = free[self._admissible]
        if gaps.size:
            headings = np.concatenate([headings, gaps[gaps_free >= enter]])
            headings_free = np.concatenate([headings_free, gaps_free[gaps_free >= enter]])
        keep = np.ones(headings.size, dtype=np.bool_)
        if self._dead_end_since_ns is not None:
            # While turning to look, only a way toward the goal side ends the search (none
            # within the scan time: no path; backing out is the pilot's call).
            keep &= np.abs(wrap_rad(headings - goal_rad)) < 1.6
        goal_open = goal_free >= min(goal_m, enter)
        # Going round while the line to the goal is never clear, the goal's bearing turns; a
        # whole turn means the vehicle has circled it: what blocks the way encloses the goal.
        if goal_free >= goal_m or self._goal_bearing_rad is None:
            self._circled_rad = 0.0
        else:
            self._circled_rad += float(wrap_rad(goal_rad - self._goal_bearing_rad))
        self._goal_bearing_rad = goal_rad
        if abs(self._circled_rad) >= 2.0 * math.pi:
            self._given_up = True
            return self.hold("no path", goal_m, pose)
        if goal_open:
            self._side = 0
            self._side_changes = 0
        elif self._side and self._side_changes >= MAX_SIDE_CHANGES:
            # Both sides were tried: only the side it is on now, or straight back out of the
            # pocket.
            delta_all = wrap_rad(headings - goal_rad)
            keep &= (np.sign(delta_all) != -self._side) | (np.abs(delta_all) >= _BACK_RAD)
        headings, headings_free = headings[keep], headings_free[keep]
        if headings.size == 0:
            return self._dead_end(now_ns, pose, goal_m, goal_rad)
        self._dead_end_since_ns = None
        goal_delta = wrap_rad(headings - goal_rad)
        cost = MU_GOAL * np.abs(goal_delta)
        cost += MU_HEADING * np.abs(wrap_rad(headings - pose.yaw_rad))
        if self._previous_rad is not None:
            cost += MU_PREVIOUS * np.abs(wrap_rad(headings - self._previous_rad))
        if self._side and not goal_open:
            cost += np.where(np.sign(goal_delta) == -self._side, COMMITMENT_COST, 0.0)
        # A way blocked farther on costs more than one that runs clear (to the goal or as far
        # as the sensors see): gaps and ends are aimed for before the vehicle is at the wall.
        horizon_m = min(goal_m, self.max_range_m)
        cost += MU_OBSTRUCTED * np.clip(1.0 - headings_free / horizon_m, 0.0, 1.0)
        best = int(np.argmin(cost))
        chosen = float(headings[best])
        chosen_free = float(headings_free[best])
        slow_for = self._better_way_when_slower(pose, goal_rad, goal_m, chosen, chosen_free, buffer)
        if goal_open and abs(float(wrap_rad(chosen - goal_rad))) <= math.radians(5.0):
            # Within a step of the goal direction: head straight for the goal.
            chosen, chosen_free = goal_rad, goal_free
        # The speed law counts the free distance without the turning buffer.
        chosen_free = float(self.free_m(pose, np.array([chosen]))[0])
        delta = float(wrap_rad(chosen - goal_rad))
        if not goal_open and math.radians(2.5) < abs(delta) <= _ONWARD_RAD:
            # Committed to the side of an onward way only: backing out for a moment (the way on
            # was blocked for a cycle, a pocket) leaves the commitment as it was, so the vehicle
            # goes on where it was going once that way opens again.
            side = 1 if delta > 0 else -1
            if self._side and side != self._side:
                self._side_changes += 1
            self._side = side
        drifting = self.drift_back_m_s(pose)
        backing = self.back_away_m_s(pose)
        away = away_m_s(backing, drifting)
        moving_m_s = math.hypot(pose.north_m_s, pose.east_m_s)
        if moving_m_s > _TURN_BACK_M_S and abs(float(wrap_rad(chosen - along))) > _TURN_BACK_RAD:
            # The way chosen turns the vehicle back on itself (every way on looks closed):
            # brake first, and turn back only if that stays so (one frame's closure would
            # otherwise send the vehicle back for a cycle, then on again).
            if self._back_since_ns is None:
                self._back_since_ns = now_ns
            if now_ns - self._back_since_ns < _BACK_OUT_AFTER_NS:
                # A vehicle that outruns the zero it is asked for is asked for the excess
                # back, as on any plan (PX4 braked from 1.6 m/s at about 1.2 m/s^2 on a zero).
                # The back-away and the drift correction stay, and no braking goes against
                # them: a vehicle backing away from a wall inside its clearance was braked
                # back toward it (PX4 SITL under load, edge 0.85 m).
                brake = brake_overspeed((0.0, 0.0), away, pose, config.max_speed_m_s)
                north, east = _with_back_away(brake, away, config.max_speed_m_s)
                return Decision((north, east, vertical), 0.0, "moving", goal_distance_m=goal_m)
        else:
            self._back_since_ns = None
        self._previous_rad = chosen
        speed = min(
            config.max_speed_m_s,
            stopping_speed_m_s(chosen_free, config.max_accel_m_s2, self._latency_s(now_ns)),
            math.sqrt(2.0 * config.max_accel_m_s2 * goal_m),
            slow_for,
            drift_speed_limit_m_s(math.hypot(*drifting), config.max_speed_m_s),
        )
        # The camera looks where the vehicle goes, or, when the way to the goal is only
        # blocked by what has not been seen, that way first.
        look = self._look_direction(pose, goal_rad, chosen, buffer)
        if abs(float(wrap_rad(look - chosen))) <= math.radians(SECTOR_WIDTH_DEG):
            # Going round something, the cameras turn toward the goal as far as they can while
            # the way flown stays in view: what opens toward the goal (a corridor's turn, a
            # wall's end) is seen before the vehicle is past it.
            look = chosen + self._view_offset_rad(float(wrap_rad(goal_rad - chosen)))
        # Beyond that the vehicle slows down while its heading differs from its way (the way
        # itself was seen: the speed law counts only the part of it the cameras looked at).
        turned_rad = float(wrap_rad(pose.yaw_rad - chosen))
        off_rad = abs(turned_rad - self._view_offset_rad(turned_rad))
        speed *= 0.5 + 0.5 * max(0.0, math.cos(off_rad))
        yaw_rate = self._yaw_rate(float(wrap_rad(look - pose.yaw_rad)))
        north, east = _with_back_away(
            (speed * math.cos(chosen), speed * math.sin(chosen)), away, config.max_speed_m_s
        )
        planned = (north, east)
        north, east = brake_overspeed(planned, away, pose, config.max_speed_m_s)
        near_side = self.near_side_rad(pose)
        if near_side is not None:
            north, east = brake_closing(
                (north, east), planned, pose, near_side, config.max_speed_m_s
            )
        velocity = (north, east, vertical)
        return Decision(
            velocity,
            yaw_rate,
            "moving",
            math.degrees(chosen) % 360.0,
            speed,
            chosen_free,
            goal_m,
        )

    def _better_way_when_slower(
        self,
        pose: Pose,
        goal_rad: float,
        goal_m: float,
        chosen_rad: float,
        chosen_free_m: float,
        buffer_m: float,
    ) -> float:
        """A speed limit that lets a way through open: ``inf`` when none is needed.

        The turning buffer grows with speed, so a gap that is wide enough at walking pace is
        closed to a vehicle flying at it. Slow to a walking pace (:data:`_SLOW_FOR_GAP_M_S`,
        the faster first) when, with that pace's buffer, on the side the vehicle is committed
        to, a way would open that

        - runs clear (to the goal, as far as the sensors see, or a stop from full speed past
          where the chosen way ends) while the chosen way ends within a stop from full speed,
          at most 30 degrees farther from the goal's direction than the chosen one (the way
          round the end of a wall, into a gap ahead); or
        - leads at least a stop from full speed toward the goal, at least
          :data:`_PASSING_RAD` nearer the goal's direction than the chosen way, while the
          vehicle goes round something (a gap in the wall it is flying along).
        """
        clear_m = min(goal_m, self.max_range_m)
        if buffer_m <= _BUFFER_M + _BUFFER_S * _SLOW_FOR_GAP_M_S[-1]:
            return math.inf
        chosen_off = abs(float(wrap_rad(chosen_rad - goal_rad)))
        # Within a stop from full speed of where the chosen way ends (farther off, the turn is
        # not near yet).
        ending = chosen_free_m < min(clear_m, self._look_m)
        if not ending and chosen_off < 2.0 * _PASSING_RAD:
            return math.inf
        offsets = self.memory.offsets((pose.north_m, pose.east_m))
        gaps = gap_headings(offsets, self.clearance_m + _BUFFER_M, self._look_m)
        headings = np.concatenate([self._directions, gaps])
        goal_delta = wrap_rad(headings - goal_rad)
        if ending:
            worth = np.abs(goal_delta) <= chosen_off + math.radians(30.0)
            needed_m = min(clear_m, chosen_free_m + self._look_m)
        else:
            worth = np.abs(goal_delta) <= chosen_off - _PASSING_RAD
            needed_m = min(clear_m, self._look_m)
        if self._side:
            worth &= np.sign(goal_delta) != -self._side
        if not worth.any():
            return math.inf
        # Now and every pace slower in one pass: the same ways, each pace's buffer. Only ways
        # that are closed now count (one open now was passed over for a cheaper one).
        paces = [v for v in _SLOW_FOR_GAP_M_S if buffer_m > _BUFFER_M + _BUFFER_S * v]
        ways = headings[worth]
        buffers = np.repeat([buffer_m] + [_BUFFER_M + _BUFFER_S * v for v in paces], ways.size)
        free = self.free_m(pose, np.tile(ways, len(paces) + 1), buffers)
        clear = (free >= needed_m).reshape(len(paces) + 1, ways.size)
        for pace, opens in zip(paces, clear[1:], strict=True):
            if (opens & ~clear[0]).any():
                return pace
        return math.inf

    def _look_direction(
        self, pose: Pose, goal_rad: float, chosen_rad: float, buffer_m: float
    ) -> float:
        """Where to point the cameras: the best way known obstacles leave open.

        That is the chosen way unless the way the planner would take, were unseen space free,
        differs: then the cameras turn there to look (a forward camera would otherwise only
        ever turn as far as it sees). When the chosen way turns more than
        :data:`_LOOK_ASIDE_RAD` from it (the vehicle is about to back out), they look at the
        first part of that way's corridor they have not seen instead: at a corridor's turn
        the near side of the way on lies beside the vehicle, outside a view pointed along it.
        """
        if self.config.unknown != "blocked":
            return chosen_rad
        enter = max(self.config.acceptance_radius_m, 1.0)
        free = self.obstacle_free_m(pose, self._directions, buffer_m)
        open_ways = np.flatnonzero(free >= enter)
        if open_ways.size == 0:
            return chosen_rad
        headings = self._directions[open_ways]
        cost = MU_GOAL * np.abs(wrap_rad(headings - goal_rad))
        cost += MU_HEADING * np.abs(wrap_rad(headings - pose.yaw_rad))
        pick = int(np.argmin(cost))
        best = float(headings[pick])
        if abs(float(wrap_rad(best - chosen_rad))) <= _LOOK_ASIDE_RAD:
            return best
        since_ns = pose.t_ns - int(self.config.memory_s * 1e9)
        reach_m = min(self._look_m, float(free[open_ways[pick]]))
        unseen = self.visibility.first_unseen(
            (pose.north_m, pose.east_m), best, self.clearance_m, reach_m, since_ns
        )
        if unseen is None:
            return best
        return math.atan2(unseen[1] - pose.east_m, unseen[0] - pose.north_m)

    def _view_offset_rad(self, wanted_rad: float) -> float:
        """How far the heading may turn from the way flown (``wanted_rad``, signed, clockwise).

        As far as keeps the way within the forward view (the bins the heads have measured,
        contiguous from straight ahead) less the view margin (the swept corridor's half-angle a
        stop away, and a bin); none for a view all round (nothing to gain) or before any scan.
        """
        view = self._in_view
        if not view[0] or view.all():
            return 0.0
        width = math.radians(SECTOR_WIDTH_DEG)
        right = int(np.argmin(view)) - 1  # bins right of ahead (clockwise) in view
        left = int(np.argmin(view[:0:-1]))  # and left of it
        # The way must stay in view: turning right by x puts it x left of ahead.
        room_left = max(0.0, (left + 0.5) * width - self._view_margin_rad)
        room_right = max(0.0, (right + 0.5) * width - self._view_margin_rad)
        return max(-room_right, min(room_left, wanted_rad))

    def _yaw_rate(self, error_rad: float) -> float:
        limit = math.radians(self.config.max_yaw_rate_deg_s)
        return max(-limit, min(limit, _YAW_GAIN * error_rad))

    def _latency_s(self, now_ns: int) -> float:
        """The speed law's delay now (see :func:`effective_latency_s`)."""
        config = self.config
        age_s = (now_ns - self._last_scan_ns) / 1e9 if self._last_scan_ns >= 0 else 0.0
        return effective_latency_s(config.latency_ms / 1000.0, age_s, config.setpoint_rate_hz)

    def _no_progress(self, now_ns: int, goal_m: float) -> bool:
        """Whether the goal has come no nearer (by 0.5 m) for ``no_progress_s``: give up."""
        if self._given_up:
            return True
        if self._best_since_ns is None or goal_m < self._best_goal_m - 0.5:
            self._best_goal_m = min(goal_m, self._best_goal_m)
            self._best_since_ns = now_ns
            return False
        if (now_ns - self._best_since_ns) / 1e9 >= self.config.no_progress_s:
            self._given_up = True
        return self._given_up

    def _dead_end(self, now_ns: int, pose: Pose, goal_m: float, goal_rad: float) -> Decision:
        """No admissible direction: hold, turn to look (goal side first), then give up."""
        if self._dead_end_since_ns is None:
            self._dead_end_since_ns = now_ns
            self._turned_rad = 0.0
            self._last_yaw_rad = pose.yaw_rad
            self._scan_side = 1.0 if float(wrap_rad(goal_rad - pose.yaw_rad)) >= 0 else -1.0
        self._turned_rad += float(wrap_rad(pose.yaw_rad - self._last_yaw_rad))
        self._last_yaw_rad = pose.yaw_rad
        elapsed_s = (now_ns - self._dead_end_since_ns) / 1e9
        if elapsed_s >= self.config.dead_end_scan_s:
            return self.hold("no path", goal_m, pose)
        # The first half turning toward the goal side up to 180 degrees, then the other way.
        first = elapsed_s < self.config.dead_end_scan_s / 2.0
        target = math.pi * self._scan_side * (1.0 if first else -1.0)
        rate = math.radians(self.config.max_yaw_rate_deg_s)
        yaw_rate = max(-rate, min(rate, _YAW_GAIN * (target - self._turned_rad)))
        north, east = self._held_correction_m_s(pose)
        return Decision((north, east, 0.0), yaw_rate, "dead end", goal_distance_m=goal_m)


def drift_speed_limit_m_s(drift_m_s: float, max_speed_m_s: float) -> float:
    """The speed a vehicle whose positions drift toward a near obstacle flies at, at most.

    An autopilot's velocity estimate can disagree with how its positions move (PX4 SITL under
    CPU load: 0.2-0.8 m/s toward a wall flown along at 1.6 m/s, while it reported flying
    away), and it follows a sideways setpoint slowly at speed. :meth:`Planner.drift_back_m_s`
    asks the drift back; flying slower along the obstacle meanwhile leaves the correction
    more time before the clearance is used up, and a disagreement that grows with speed
    shrinks with it. The limit falls by :data:`_DRIFT_SLOWING` of the maximum speed per
    :data:`_BACK_AWAY_MAX_M_S` of drift, to :data:`_DRIFT_SLOWEST` of it at most.

    Args:
        drift_m_s: The drift toward the obstacle being asked back (0: none).
        max_speed_m_s: The configured maximum speed.

    Returns:
        The speed limit (the maximum speed without drift).
    """
    share = 1.0 - _DRIFT_SLOWING * drift_m_s / _BACK_AWAY_MAX_M_S
    return max_speed_m_s * max(_DRIFT_SLOWEST, min(1.0, share))


def brake_overspeed(
    planned_m_s: tuple[float, float],
    away_m_s: tuple[float, float],
    pose: Pose,
    max_speed_m_s: float,
) -> tuple[float, float]:
    """The planned velocity with extra braking where the vehicle outruns it.

    The speed law and the turning buffer take it that the vehicle follows its setpoint within
    a few tenths of a second. An autopilot may not: PX4's velocity loop on a vehicle with
    drag holds about 80 % of a steady setpoint with its integrator, and when the setpoint
    drops (the speed law braking for a wall, or a turn along it) that wound-up integrator
    keeps the vehicle going: measured in SITL it flew on at 1.5 m/s for half a second after
    the setpoint had fallen to 1.2, and 0.6 m farther toward the wall than the plan after a
    turn. So where the vehicle moves faster along its own direction of travel than the plan
    wants that way (none: a plan the other way counts as zero), by more than a vehicle
    following its setpoint lags it anyway (the slack: the built-in simulator's vehicle mostly
    stays within it), the setpoint also asks for the excess back, against that direction; the
    correction fades as the vehicle slows to the plan.

    The correction only ever brakes: a part of it along the planned velocity (which would fly
    faster than the speed law allows that way) or against the speed away from what the vehicle
    is too near (which would undo the back-away) is not sent; when both cannot be kept out,
    none of it is. It shares the maximum speed with the plan, which is kept whole. The
    vehicle's velocity here is the autopilot's newest report (up to the position's freshness
    limit old): braking on an old one costs pace, never margin.

    Args:
        planned_m_s: The planned velocity (north, east), back-away included.
        away_m_s: The back-away part of it (zeros: none).
        pose: The vehicle's state (its measured velocity).
        max_speed_m_s: The setpoint's speed stays within this.

    Returns:
        The velocity to command (north, east).
    """
    unit = _unit((pose.north_m_s, pose.east_m_s))
    if unit is None:
        return planned_m_s
    moving_m_s = math.hypot(pose.north_m_s, pose.east_m_s)
    planned = np.array(planned_m_s, dtype=np.float64)
    wanted_m_s = max(0.0, float(planned @ unit))
    excess_m_s = moving_m_s - wanted_m_s - _OVERSPEED_SLACK_M_S
    if excess_m_s <= 0.0:
        return planned_m_s
    correction = -_OVERSPEED_GAIN * excess_m_s * unit
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
    north, east = _with_back_away(
        (float(correction[0]), float(correction[1])), planned_m_s, max_speed_m_s
    )
    return (north, east)


def brake_closing(
    command_m_s: tuple[float, float],
    planned_m_s: tuple[float, float],
    pose: Pose,
    side_rad: float,
    max_speed_m_s: float,
) -> tuple[float, float]:
    """The command with the vehicle's excess speed toward a near side asked back.

    :func:`brake_overspeed` looks along the vehicle's own direction of travel. Flying along a
    wall, PX4 SITL also kept closing on it sideways at 0.1-0.2 m/s for two seconds while the
    plan asked 0.1-0.3 m/s away (its velocity loop winding down from braking for the wall
    before the turn): its own velocity report showed it, so the drift check, which compares
    the positions with that report, did not, and the edge came 0.6 m nearer than the plan's.
    Here the part of the reported velocity toward the near side beyond what the plan wants
    that way (none when the plan points away), less a slack and whatever the command already
    asks back that way, is asked back, up to :data:`_BACK_AWAY_MAX_M_S`. The slack is
    :data:`_DRIFT_SLACK_M_S` of noise when the plan flies along or away from the side, and
    grows to the overspeed brake's :data:`_OVERSPEED_SLACK_M_S` over the first
    :data:`_CLOSING_RAMP_M_S` the plan wants toward it (braking head-on, a vehicle following
    its setpoint lags it that much). It only ever points away from the side: it costs pace,
    never margin.

    Args:
        command_m_s: The velocity to command so far (north, east).
        planned_m_s: The plan before any braking (back-away included).
        pose: The vehicle's state (its reported velocity).
        side_rad: Bearing of the near side (see :meth:`Planner.near_side_rad`).
        max_speed_m_s: The setpoint's speed stays within this.

    Returns:
        The velocity to command (north, east).
    """
    side = np.array((math.cos(side_rad), math.sin(side_rad)))
    closing_m_s = float(np.array((pose.north_m_s, pose.east_m_s)) @ side)
    wanted_m_s = max(0.0, float(np.array(planned_m_s) @ side))
    asked_back_m_s = max(0.0, float((np.array(planned_m_s) - np.array(command_m_s)) @ side))
    # Approaching as planned (the speed law braking for it), a vehicle that follows its
    # setpoint lags it by up to the overspeed brake's slack; flying along or away, by no
    # more than noise. In between, the slack grows with the speed wanted toward the side.
    share = min(1.0, wanted_m_s / _CLOSING_RAMP_M_S)
    slack_m_s = _DRIFT_SLACK_M_S + share * (_OVERSPEED_SLACK_M_S - _DRIFT_SLACK_M_S)
    excess_m_s = closing_m_s - wanted_m_s - slack_m_s - asked_back_m_s
    if excess_m_s <= 0.0:
        return command_m_s
    back = -min(excess_m_s, _BACK_AWAY_MAX_M_S) * side
    return _with_back_away(command_m_s, (float(back[0]), float(back[1])), max_speed_m_s)


def away_m_s(backing: tuple[float, float], drifting: tuple[float, float]) -> tuple[float, float]:
    """The back-away plus the drift correction, no part of the drift against the back-away.

    The back-away flees what the vehicle is inside the clearance of; the drift correction
    flees the side of what is near within the clearance plus :data:`_DRIFT_BAND_M`, which can
    be another obstacle on the other side (a pole inside the clearance to the north, a wall
    beyond it to the south the positions drift toward). The drift's part against the
    back-away would push the vehicle at what it is already too near, so it is dropped; its
    part across the back-away stays.

    Args:
        backing: :meth:`Planner.back_away_m_s`.
        drifting: :meth:`Planner.drift_back_m_s`.

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


def _unit(vector: tuple[float, float]) -> np.ndarray | None:
    """The direction of a horizontal vector (None for a zero one)."""
    size = math.hypot(*vector)
    return None if size == 0.0 else np.array(vector, dtype=np.float64) / size


def _with_back_away(
    way: tuple[float, float], away: tuple[float, float], max_speed_m_s: float
) -> tuple[float, float]:
    """The velocity along the way chosen plus the one away from what is too near.

    The speed away is kept whole (up to the maximum speed); the speed along the way gives
    way so that the sum stays within the maximum.
    """
    away_m_s = math.hypot(*away)
    if away_m_s == 0.0:
        return way
    if away_m_s > max_speed_m_s:
        away = (away[0] * max_speed_m_s / away_m_s, away[1] * max_speed_m_s / away_m_s)
        away_m_s = max_speed_m_s
    way_sq = way[0] ** 2 + way[1] ** 2
    north, east = way[0] + away[0], way[1] + away[1]
    if way_sq == 0.0 or math.hypot(north, east) <= max_speed_m_s:
        return (north, east)
    # The largest share s of the way with |s * way + away| = max speed.
    dot = way[0] * away[0] + way[1] * away[1]
    root = math.sqrt(max(0.0, dot * dot - way_sq * (away_m_s**2 - max_speed_m_s**2)))
    share = max(0.0, min(1.0, (root - dot) / way_sq))
    return (share * way[0] + away[0], share * way[1] + away[1])
