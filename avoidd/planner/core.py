"""The local planner's step: from the vehicle's state, the obstacles and a goal to a velocity.

Each decision is a few stages over one snapshot of the surroundings
(:class:`~avoidd.planner.surroundings.Surroundings`, one query of the obstacle memory):

- the search's checks (:mod:`~avoidd.planner.search`): no progress for ``no_progress_s``, a
  whole turn round the goal with its line never clear: "no path";
- the direction (:mod:`~avoidd.planner.direction`): the admissible ways (obstacles enlarged
  by the radius, the margin and a turning buffer; unseen ground blocked unless unknown is
  free) and the cheapest of them; none: the look-around, then "no path";
- the speed law (:mod:`~avoidd.planner.speed`): ``v <= min(v_max, sqrt(2 a (d - v t)))``
  along the chosen way, no faster than stopping at the goal, slower for a gap that opens at a
  walking pace, slower while the positions drift toward a near obstacle;
- the view (:mod:`~avoidd.planner.view`): yaw toward the way, turned toward the goal as far
  as keeps the way in view;
- the corrections (:mod:`~avoidd.planner.corrections`): back away from what the vehicle is
  inside the clearance of, cancel a drift toward what is near, brake an overrun.

Never crawl forward. The constants are one :class:`~avoidd.planner.tuning.Tuning`.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from avoidd.config import AvoidanceConfig
from avoidd.planner.corrections import (
    BackAway,
    away_m_s,
    brake_closing,
    brake_overspeed,
    drift_back_m_s,
    held_correction_m_s,
    with_back_away,
)
from avoidd.planner.direction import Direction, Ways
from avoidd.planner.gaps import GapFollower
from avoidd.planner.geometry import wrap_rad
from avoidd.planner.memory import ObstacleMemory
from avoidd.planner.search import Search
from avoidd.planner.speed import (
    AUTOPILOT_RESPONSE_S,
    drift_speed_limit_m_s,
    effective_latency_s,
    stopping_speed_m_s,
)
from avoidd.planner.surroundings import Surroundings
from avoidd.planner.tuning import DEFAULT, Tuning
from avoidd.planner.types import Decision, Goal, Pose
from avoidd.planner.view import View
from avoidd.planner.visibility import VisibilityGrid
from avoidd.types import SECTOR_COUNT, SECTOR_WIDTH_DEG

__all__ = [
    "AUTOPILOT_RESPONSE_S",
    "Decision",
    "Goal",
    "Planner",
    "Pose",
    "away_m_s",
    "brake_closing",
    "brake_overspeed",
    "drift_speed_limit_m_s",
    "effective_latency_s",
    "stopping_speed_m_s",
]

Array = npt.NDArray[np.float64]
Vector = tuple[float, float]


class Planner:
    """The planner of one vehicle: its memory and what its stages keep between steps.

    Args:
        config: The ``avoidance`` section.
        max_range_m: The sensors' maximum range (a clear bin sees this far).
        tuning: The planner's constants.
    """

    def __init__(
        self, config: AvoidanceConfig, max_range_m: float, tuning: Tuning = DEFAULT
    ) -> None:
        self.max_range_m = max_range_m
        self.tuning = tuning
        self.memory = ObstacleMemory(config.memory_s)
        self.visibility = VisibilityGrid()
        self.back_away = BackAway(tuning)
        self._last_scan_ns = -1
        self._taken_ns = np.full(SECTOR_COUNT, -1, dtype=np.int64)
        """Per body bin, the capture time of the newest reading taken into the memory."""
        self._last_decide_ns: int | None = None
        self._back_since_ns: int | None = None
        self.gaps = GapFollower(0.0)
        self._configure(config)

    def _configure(self, config: AvoidanceConfig) -> None:
        """The stages that follow from the settings (the memory and what was seen are kept)."""
        t = self.tuning
        self.config = config
        latency_s = config.latency_ms / 1000.0
        # Beyond the stopping distance at full speed nothing unseen matters yet.
        self.look_m = (
            config.max_speed_m_s**2 / (2 * config.max_accel_m_s2)
            + config.max_speed_m_s * latency_s
            + t.look_margin_m
        )
        self.enter_m = max(config.acceptance_radius_m, t.enter_m)
        # The way flown stays this far inside the view when the cameras turn toward the goal:
        # the corridor the vehicle sweeps, seen from a stop away, and one bin of jitter.
        margin = math.atan2(self.clearance_m, self.look_m) + math.radians(SECTOR_WIDTH_DEG)
        if not hasattr(self, "direction"):
            self.direction = Direction(t, self.enter_m)
            self.search = Search(config, t)
            self.view = View(t, margin)
        # New settings in flight: the stages keep what they know (a new admissible set).
        self.direction.enter_m = self.enter_m
        self.gaps.within_m = 2.0 * self.look_m
        self.direction.clear_admissible()
        self.search.config = config
        self.view.margin_rad = margin

    def reconfigure(self, config: AvoidanceConfig) -> None:
        """Take new settings (parameters set in flight); the memory is kept."""
        self._configure(config)
        self.memory.memory_s = config.memory_s

    @property
    def clearance_m(self) -> float:
        """Vehicle radius plus margin: how far every obstacle is kept."""
        return self.config.vehicle_radius_m + self.config.margin_m

    def reset(self) -> None:
        """Start over for a new goal (the memory and the back-away's growth are kept)."""
        self.direction.reset()
        self.search.reset()
        self.gaps.reset()
        self._back_since_ns = None

    def observe_scan(
        self,
        distance_m: npt.NDArray[np.float32],
        t_capture_ns: int,
        pose_at_capture: Pose,
        points_frd_m: npt.NDArray[np.float32] | None = None,
        reading_t_ns: npt.NDArray[np.int64] | None = None,
    ) -> None:
        """Take a fresh merged scan (body bins) with the vehicle's pose at its capture.

        Args:
            distance_m: The scan's 72 distances (NaN unknown, ``inf`` clear).
            t_capture_ns: Its (newest) capture time.
            pose_at_capture: The vehicle's pose then.
            points_frd_m: The body point each finite bin measured, when the scan has them
                (the memory places the readings at their bearings).
            reading_t_ns: The capture time of each bin's reading, when it has them. A bin
                whose reading was already taken in (a reading the sector filter holds for a
                moment, another head's scan merged in again) is not placed again: at this
                pose it would land where the vehicle's turn since then carried it (4 degrees
                of yaw put a gap's edge 0.2 m into a 3.5 m gap at 3 m, and the gap closed).
        """
        times = (
            np.full(distance_m.shape, t_capture_ns, dtype=np.int64)
            if reading_t_ns is None
            else np.asarray(reading_t_ns, dtype=np.int64)
        )
        # Per bin: a head whose frame was captured before another's newest still brings new
        # readings for its own bins when its scan is merged in after.
        # An unknown bin takes nothing in: it leaves the bin open to another head's reading.
        new = (times > self._taken_ns) & ~np.isnan(distance_m)
        if t_capture_ns > self._last_scan_ns:
            self.view.observe(distance_m)
            self._last_scan_ns = t_capture_ns
        if not new.any():
            return
        self._taken_ns = np.where(new, times, self._taken_ns)
        distance_m = np.where(new, distance_m, np.nan).astype(np.float32)
        if points_frd_m is not None:
            points_frd_m = np.where(new[:, None], points_frd_m, np.nan).astype(np.float32)
        where = (pose_at_capture.north_m, pose_at_capture.east_m)
        self.memory.add_scan(
            distance_m,
            t_capture_ns,
            where,
            pose_at_capture.yaw_rad,
            self.max_range_m,
            points_frd_m,
        )
        self.visibility.mark(
            where, pose_at_capture.yaw_rad, distance_m, t_capture_ns, self.max_range_m
        )

    # --- the snapshot and the questions asked of it ------------------------------------------

    def surroundings(self, pose: Pose) -> Surroundings:
        """What surrounds ``pose`` (obstacles remembered, ground seen)."""
        blocked = self.config.unknown == "blocked"
        return Surroundings.around(
            pose,
            self.memory,
            self.visibility if blocked else None,
            self.clearance_m,
            self.config.vehicle_radius_m,
            self.look_m,
            self.config.memory_s,
            self.tuning,
        )

    def free_m(self, pose: Pose, headings_rad: Array, buffer_m: float | Array = 0.0) -> Array:
        """Free distance along each heading (see :meth:`Surroundings.free_m`)."""
        return self.surroundings(pose).free_m(headings_rad, buffer_m)

    def obstacle_free_m(
        self, pose: Pose, headings_rad: Array, buffer_m: float | Array = 0.0
    ) -> Array:
        """Free distance among remembered obstacles (:meth:`Surroundings.obstacle_free_m`)."""
        return self.surroundings(pose).obstacle_free_m(headings_rad, buffer_m)

    def back_away_m_s(self, pose: Pose) -> Vector:
        """The back-away now (:class:`~avoidd.planner.corrections.BackAway`)."""
        return self.back_away.velocity(self.surroundings(pose))

    def drift_back_m_s(self, pose: Pose) -> Vector:
        """The drift correction now (:func:`~avoidd.planner.corrections.drift_back_m_s`)."""
        return drift_back_m_s(self.surroundings(pose))

    def near_side_rad(self, pose: Pose) -> float | None:
        """The side what is near lies on (:meth:`Surroundings.near_side_rad`)."""
        return self.surroundings(pose).near_side_rad()

    def latency_s(self, now_ns: int) -> float:
        """The speed law's delay now (see :func:`~avoidd.planner.speed.effective_latency_s`)."""
        config = self.config
        age_s = (now_ns - self._last_scan_ns) / 1e9 if self._last_scan_ns >= 0 else 0.0
        return effective_latency_s(
            config.latency_ms / 1000.0, age_s, config.setpoint_rate_hz, self.tuning
        )

    # --- holding and deciding --------------------------------------------------------------

    def hold(
        self, state: str, goal_distance_m: float | None = None, pose: Pose | None = None
    ) -> Decision:
        """Stay here: no turning, no planned motion (not a decision: planning is paused).

        With the vehicle's ``pose``, "here" is where its positions are and outside the
        clearance of what it remembers: inside it, the hold backs away, and a drift of the
        positions toward a near remembered obstacle that the reported velocity does not show
        is asked back, as on the move (:func:`~avoidd.planner.corrections.held_correction_m_s`).
        Told to hold zero, PX4 SITL under CPU load let its positions close on a wall at
        0.3-0.4 m/s for five seconds, reporting about zero, and ran into it.
        """
        north, east = (0.0, 0.0) if pose is None else self._held(pose)
        return Decision((north, east, 0.0), 0.0, state, goal_distance_m=goal_distance_m)

    def _held(self, pose: Pose, back_away: bool = True) -> Vector:
        self.memory.expire(pose.t_ns)
        around = self.surroundings(pose)
        backing = self.back_away.velocity(around) if back_away else (0.0, 0.0)
        config = self.config
        return held_correction_m_s(
            around, backing, config.max_speed_m_s, config.max_accel_m_s2, self.latency_s(pose.t_ns)
        )

    def decide(self, now_ns: int, pose: Pose, goal: Goal, fresh: bool) -> Decision:
        """The velocity and yaw rate to command now.

        Args:
            now_ns: The current time.
            pose: The vehicle's current state.
            goal: Where to go.
            fresh: Whether perception is fresh (else: hold).
        """
        config, t = self.config, self.tuning
        if self._last_decide_ns is not None and now_ns - self._last_decide_ns > t.pause_ns:
            # Not planning for a while (another mode, a stale hold): its timers restart.
            self.search.paused()
            self._back_since_ns = None
        self._last_decide_ns = now_ns
        self.memory.expire(now_ns)
        to_north, to_east = goal.north_m - pose.north_m, goal.east_m - pose.east_m
        goal_m = math.hypot(to_north, to_east)
        climb = t.altitude_gain_per_s * (goal.altitude_m + pose.down_m)
        vertical = -max(-config.climb_rate_m_s, min(config.climb_rate_m_s, climb))
        if not fresh:
            return self.hold("stale", goal_m, pose)
        if goal_m <= config.acceptance_radius_m:
            self.search.arrived()
            state = "arrived" if abs(climb) <= t.arrived_altitude_m else "moving"
            north, east = self._held(pose, back_away=False)
            return Decision((north, east, vertical), 0.0, state, goal_distance_m=goal_m)
        if self.search.no_progress(now_ns, goal_m):
            return self.hold("no path", goal_m, pose)
        around = self.surroundings(pose)
        searching = self.search.dead_end_since_ns is not None
        goal_rad = math.atan2(to_east, to_north)
        blocked = float(around.obstacle_free_m(np.array([goal_rad]))[0]) < goal_m
        wide_m = 2.0 * (self.clearance_m + t.buffer_at_m(config.max_speed_m_s))
        sub = self.gaps.subgoal(around, (to_north, to_east), blocked, wide_m, self.visibility)
        if sub is None:
            ways = self.direction.ways(around, goal_rad, goal_m, searching)
        else:
            ways = self.direction.ways(around, sub.heading_rad, sub.distance_m, searching, 0.0)
        line_m = ways.goal_free_m if sub is None else float(around.free_m(np.array([goal_rad]))[0])
        if self.search.circled(goal_rad, line_m >= goal_m):
            return self.hold("no path", goal_m, pose)
        if ways.headings.size == 0:
            return self._look_around(now_ns, pose, goal_m, goal_rad)
        self.search.found()
        stop_m = math.inf if sub is None else sub.stop_m
        return self._fly(now_ns, around, ways, goal_m, vertical, stop_m)

    def _fly(
        self,
        now_ns: int,
        around: Surroundings,
        ways: Ways,
        goal_m: float,
        vertical: float,
        stop_m: float = math.inf,
    ) -> Decision:
        """Fly the cheapest way: speed law, view, corrections.

        ``stop_m``: the vehicle must also be able to stop within this (lining up on a gap).
        """
        config, t, pose = self.config, self.tuning, around.pose
        clear_m = min(goal_m, self.max_range_m)
        chosen = self.direction.choose(ways, pose.yaw_rad, clear_m)
        slow_for = self.direction.slower_opens(around, ways, clear_m, chosen)
        way = self.direction.snapped(chosen[0], ways)
        # The speed law counts the free distance without the turning buffer.
        way_free = float(around.free_m(np.array([way]))[0])
        self.direction.commit(way, ways)
        drifting = drift_back_m_s(around)
        away = away_m_s(self.back_away.velocity(around), drifting)
        turning_back = self._turning_back(now_ns, pose, way, ways.along_rad, away, vertical, goal_m)
        if turning_back is not None:
            return turning_back
        self.direction.previous_rad = way
        speed = min(
            config.max_speed_m_s,
            stopping_speed_m_s(
                min(way_free, stop_m), config.max_accel_m_s2, self.latency_s(now_ns)
            ),
            math.sqrt(2.0 * config.max_accel_m_s2 * goal_m),
            slow_for,
            drift_speed_limit_m_s(math.hypot(*drifting), config.max_speed_m_s, t),
        )
        look = self.view.look_rad(
            around, self.direction.directions, ways.goal_rad, way, ways.buffer_m, self.enter_m
        )
        speed *= self.view.speed_share(pose.yaw_rad, way)
        yaw_rate = self.view.yaw_rate(
            float(wrap_rad(look - pose.yaw_rad)), config.max_yaw_rate_deg_s
        )
        planned = with_back_away(
            (speed * math.cos(way), speed * math.sin(way)), away, config.max_speed_m_s
        )
        north, east = brake_overspeed(planned, away, pose, config.max_speed_m_s, t)
        near_side = around.near_side_rad()
        if near_side is not None:
            north, east = brake_closing(
                (north, east), planned, pose, near_side, config.max_speed_m_s, t
            )
        return Decision(
            (north, east, vertical),
            yaw_rate,
            "moving",
            math.degrees(way) % 360.0,
            speed,
            way_free,
            goal_m,
        )

    def _turning_back(
        self,
        now_ns: int,
        pose: Pose,
        way_rad: float,
        along_rad: float,
        away: Vector,
        vertical: float,
        goal_m: float,
    ) -> Decision | None:
        """Brake first when the way chosen turns the vehicle back on itself (None: go on).

        One frame's closure would otherwise send the vehicle back for a cycle, then on again:
        it turns back only if that stays the choice for ``back_out_after_ns``. A vehicle that
        outruns the zero it is asked for is asked for the excess back; the back-away and the
        drift correction stay, and no braking goes against them.
        """
        t = self.tuning
        moving_m_s = math.hypot(pose.north_m_s, pose.east_m_s)
        turn_back = math.radians(t.turn_back_deg)
        if moving_m_s <= t.turn_back_m_s or abs(float(wrap_rad(way_rad - along_rad))) <= turn_back:
            self._back_since_ns = None
            return None
        if self._back_since_ns is None:
            self._back_since_ns = now_ns
        if now_ns - self._back_since_ns >= t.back_out_after_ns:
            return None
        max_speed = self.config.max_speed_m_s
        brake = brake_overspeed((0.0, 0.0), away, pose, max_speed, t)
        north, east = with_back_away(brake, away, max_speed)
        return Decision((north, east, vertical), 0.0, "moving", goal_distance_m=goal_m)

    def _look_around(self, now_ns: int, pose: Pose, goal_m: float, goal_rad: float) -> Decision:
        """No admissible way: hold, turn to look (goal side first), then give up."""
        yaw_rate = self.search.look(now_ns, pose, goal_rad)
        if yaw_rate is None:
            return self.hold("no path", goal_m, pose)
        north, east = self._held(pose)
        return Decision((north, east, 0.0), yaw_rate, "dead end", goal_distance_m=goal_m)
