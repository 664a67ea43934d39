"""Searching for a way, and giving up: the look-around at a dead end, and "no path to goal".

No admissible way: hold, then turn up to 180 degrees each way looking for one toward the
goal's side; none within ``dead_end_scan_s``: "no path". Also "no path" once the goal has come
no nearer (by 0.5 m) for ``no_progress_s``, or once the vehicle has gone a whole turn round
the goal without once seeing the line to it clear (what blocks it encloses the goal).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from avoidd.config import AvoidanceConfig
from avoidd.planner.geometry import wrap_rad
from avoidd.planner.tuning import Tuning
from avoidd.planner.types import Pose

_PROGRESS_M = 0.5
"""The goal must come this much nearer to count as progress."""


@dataclass
class Search:
    """The search's state between cycles.

    Args:
        config: The ``avoidance`` section (its search and progress times).
        tuning: The planner's constants.
    """

    config: AvoidanceConfig
    tuning: Tuning
    dead_end_since_ns: int | None = None
    given_up: bool = False
    _turned_rad: float = 0.0
    _last_yaw_rad: float = 0.0
    _scan_side: float = 1.0
    _best_goal_m: float = math.inf
    _best_since_ns: int | None = None
    _goal_bearing_rad: float | None = None
    _circled_rad: float = 0.0

    def reset(self) -> None:
        """Start over for a new goal."""
        self.dead_end_since_ns = None
        self.given_up = False
        self._best_goal_m = math.inf
        self._best_since_ns = None
        self._goal_bearing_rad = None
        self._circled_rad = 0.0

    def paused(self) -> None:
        """Planning was paused: time spent so is no time without progress, nor looking."""
        self._best_since_ns = None
        self.dead_end_since_ns = None
        self._goal_bearing_rad = None

    def arrived(self) -> None:
        """The goal is reached: no progress is owed, no search is on."""
        self._best_since_ns = None
        self.dead_end_since_ns = None

    def no_progress(self, now_ns: int, goal_m: float) -> bool:
        """Whether the goal has come no nearer for ``no_progress_s`` (then: give up)."""
        if self.given_up:
            return True
        if self._best_since_ns is None or goal_m < self._best_goal_m - _PROGRESS_M:
            self._best_goal_m = min(goal_m, self._best_goal_m)
            self._best_since_ns = now_ns
            return False
        if (now_ns - self._best_since_ns) / 1e9 >= self.config.no_progress_s:
            self.given_up = True
        return self.given_up

    def circled(self, goal_rad: float, goal_line_clear: bool) -> bool:
        """Whether the vehicle has gone a whole turn round the goal, its line never clear."""
        if goal_line_clear or self._goal_bearing_rad is None:
            self._circled_rad = 0.0
        else:
            self._circled_rad += float(wrap_rad(goal_rad - self._goal_bearing_rad))
        self._goal_bearing_rad = goal_rad
        if abs(self._circled_rad) >= 2.0 * math.pi:
            self.given_up = True
        return self.given_up

    def found(self) -> None:
        """A way was found: the look-around is over."""
        self.dead_end_since_ns = None

    def look(self, now_ns: int, pose: Pose, goal_rad: float) -> float | None:
        """The yaw rate of the look-around this cycle; None once its time is up (no path).

        The first half turns toward the goal's side up to 180 degrees, then the other way.
        """
        if self.dead_end_since_ns is None:
            self.dead_end_since_ns = now_ns
            self._turned_rad = 0.0
            self._last_yaw_rad = pose.yaw_rad
            self._scan_side = 1.0 if float(wrap_rad(goal_rad - pose.yaw_rad)) >= 0 else -1.0
        self._turned_rad += float(wrap_rad(pose.yaw_rad - self._last_yaw_rad))
        self._last_yaw_rad = pose.yaw_rad
        elapsed_s = (now_ns - self.dead_end_since_ns) / 1e9
        if elapsed_s >= self.config.dead_end_scan_s:
            return None
        first = elapsed_s < self.config.dead_end_scan_s / 2.0
        target = math.pi * self._scan_side * (1.0 if first else -1.0)
        rate = math.radians(self.config.max_yaw_rate_deg_s)
        return max(-rate, min(rate, self.tuning.yaw_gain_per_s * (target - self._turned_rad)))
