"""What a lockstep run scores: its summary, the tally that fills it step by step, the verdict.

The tally watches the run from outside (it never changes what is flown): the vehicle's edge
clearance and speed every step, the planner's state and chosen side every cycle, when
perception went stale and when a hold followed. Speeds and times are the ones a pilot reads:
the speed while moving (hovering before the start and after arrival left out), the delay
from the goal to the vehicle moving, the time to the goal and to "no path".
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from avoidd.config.sim import PassConfig

MOVING_M_S = 0.3
"""Faster than this (horizontally) the vehicle counts as moving."""


@dataclass
class Summary:
    """The outcome of one run (JSON-ready; rounded so that repeated runs compare equal).

    Attributes:
        name: The scenario's name.
        seed: The run's seed.
        perception: ``stereo`` or ``oracle``.
        world_kind: The generator's kind, or ``file`` for a world file.
        speed_limit_m_s: The planner's maximum speed in this run.
        collided: The vehicle's edge touched an obstacle.
        collision_t_s: When it first did.
        min_clearance_m: The smallest edge clearance of the run.
        clearance_p01_m: The edge clearance the run kept in 99 % of its steps.
        reached: The planner arrived at the goal.
        time_to_goal_s: When (from the start).
        end_state: The planner's state at the end.
        mean_speed_m_s: The mean speed over the whole run, hovering included.
        max_speed_m_s: The highest speed.
        moving_speed_m_s: Distance flown while moving over the time moving (None: never moved).
        moving_s: The time spent moving.
        start_delay_s: From the first goal to the vehicle moving (None: it never moved).
        no_path_s: From the goal in force to the first "no path" (None: none).
        search_s: From the start of the search that ended in "no path" (the first cycle since
            the chosen way last led straight for the goal: a look-around, or a detour round
            what closes it) to "no path" (None: none).
        side_changes: Changes of the side the chosen way passes the goal line on.
        detour_side_changes: The most side changes within one detour.
        reachable: The goal can be reached (the criteria do not ask for "no path").
        clearance_target_m: The edge clearance the targets ask in 99 % of the steps.
        stale_to_hold_ms: The longest time from perception going stale to a hold setpoint.
        stale_holds: Planning cycles that held for stale perception.
        passed: Every criterion held.
        failures: The criteria that did not, in words.
        sim_time_s: Simulated time run.
        wall_time_s: Wall-clock time it took (left out of the JSON).
    """

    name: str
    seed: int
    perception: str
    world_kind: str = "file"
    speed_limit_m_s: float = 0.0
    collided: bool = False
    collision_t_s: float | None = None
    min_clearance_m: float = math.inf
    clearance_p01_m: float = math.inf
    reached: bool = False
    time_to_goal_s: float | None = None
    end_state: str = ""
    mean_speed_m_s: float = 0.0
    max_speed_m_s: float = 0.0
    moving_speed_m_s: float | None = None
    moving_s: float = 0.0
    start_delay_s: float | None = None
    no_path_s: float | None = None
    search_s: float | None = None
    side_changes: int = 0
    detour_side_changes: int = 0
    reachable: bool = True
    clearance_target_m: float = 0.0
    stale_to_hold_ms: float | None = None
    stale_holds: int = 0
    passed: bool = False
    failures: list[str] = field(default_factory=list)
    sim_time_s: float = 0.0
    wall_time_s: float = 0.0

    def as_json(self) -> dict[str, Any]:
        """The summary with floats rounded (the wall time is left out: it never repeats)."""
        out: dict[str, Any] = {}
        for key, value in self.__dict__.items():
            if key == "wall_time_s":
                continue
            if isinstance(value, float):
                out[key] = None if not math.isfinite(value) else round(value, 4)
            else:
                out[key] = value
        return out


class Tally:
    """Fills a summary from what the run shows, step by step and cycle by cycle.

    Args:
        summary: The summary to fill.
        step_s: The run's time step.
    """

    def __init__(self, summary: Summary, step_s: float) -> None:
        self.summary = summary
        self._step_s = step_s
        self._clearances: list[float] = []
        self._speeds: list[float] = []
        self._moving_m = 0.0
        self._moving_steps = 0
        self._last_side = 0
        self._detour_changes = 0
        self._stale_since_ns: int | None = None
        self._was_fresh = False
        self._goal_t_s = 0.0
        self._search_t_s: float | None = None
        self.no_path_t_s: float | None = None
        """When the planner first said "no path" (from the start)."""

    def goal_given(self, t_s: float) -> None:
        """A new goal: the time to "no path" counts from here."""
        self._goal_t_s = t_s
        self._search_t_s = None

    def perception(self, fresh: bool, now_ns: int) -> None:
        """Whether avoidd has a fresh scan this step (marks when it went stale)."""
        if not fresh and self._was_fresh:
            self._stale_since_ns = now_ns
        self._was_fresh = fresh

    def cycle(self, t_s: float, now_ns: int, state: str, holds: bool, side: int | None) -> None:
        """One planning cycle's outcome.

        Args:
            t_s: The time.
            now_ns: The time in ns.
            state: The planner's state.
            holds: The gate held (stale perception or no position).
            side: The side of the goal line the chosen way passes (-1 left, 0 on it, 1
                right), None without a chosen way.
        """
        summary = self.summary
        if side is not None:
            if side and self._last_side and side != self._last_side:
                summary.side_changes += 1
                self._detour_changes += 1
                summary.detour_side_changes = max(summary.detour_side_changes, self._detour_changes)
            if not side:
                self._detour_changes = 0  # heading for the goal again: that detour is over
            self._last_side = side
        if holds:
            summary.stale_holds += 1
            if self._stale_since_ns is not None and state == "stale":
                # Stale perception to a hold setpoint (the worst of the run).
                waited_ms = (now_ns - self._stale_since_ns) / 1e6
                summary.stale_to_hold_ms = max(summary.stale_to_hold_ms or 0.0, waited_ms)
                self._stale_since_ns = None
        self._search(t_s, state, side)

    def _search(self, t_s: float, state: str, side: int | None) -> None:
        """Where the search began, and the first "no path".

        The search begins at the first cycle since the chosen way last led straight for the
        goal: a look-around, or a detour round what closes the way.
        """
        summary = self.summary
        if state == "moving" and side == 0:
            self._search_t_s = None
        elif state == "no path" and summary.no_path_s is None:
            self.no_path_t_s = t_s
            summary.no_path_s = t_s - self._goal_t_s
            if self._search_t_s is not None:
                summary.search_s = t_s - self._search_t_s
        elif self._search_t_s is None:
            self._search_t_s = t_s

    def step(self, t_s: float, clearance_m: float, speed_m_s: float, state: str) -> None:
        """The vehicle after one step: its edge clearance, its horizontal speed."""
        summary = self.summary
        self._clearances.append(clearance_m)
        self._speeds.append(speed_m_s)
        if speed_m_s > MOVING_M_S:
            self._moving_steps += 1
            self._moving_m += speed_m_s * self._step_s
            if summary.start_delay_s is None:
                summary.start_delay_s = t_s
        if clearance_m < 0.0 and not summary.collided:
            summary.collided = True
            summary.collision_t_s = t_s
        if state == "arrived" and not summary.reached:
            summary.reached = True
            summary.time_to_goal_s = t_s

    def finish(self, end_state: str) -> Summary:
        """The summary at the end of the run."""
        summary = self.summary
        summary.end_state = end_state
        clearances = self._clearances
        summary.min_clearance_m = float(min(clearances))
        finite = [c for c in clearances if math.isfinite(c)]
        summary.clearance_p01_m = float(np.percentile(finite, 1)) if finite else math.inf
        summary.mean_speed_m_s = float(np.mean(self._speeds))
        summary.max_speed_m_s = float(max(self._speeds))
        summary.moving_s = self._moving_steps * self._step_s
        if self._moving_steps:
            summary.moving_speed_m_s = self._moving_m / summary.moving_s
        summary.sim_time_s = len(clearances) * self._step_s
        return summary


def judge(summary: Summary, passing: PassConfig) -> None:
    """Check the run against its pass criteria; the failures in words, and the verdict."""
    summary.reachable = passing.end_state != "no path"
    failures = summary.failures
    if passing.no_collision and summary.collided:
        failures.append(f"collision at {summary.collision_t_s:.2f} s")
    needed = passing.min_clearance_m
    if needed is not None and summary.clearance_p01_m < needed:
        failures.append(
            f"clearance {summary.clearance_p01_m:.2f} m in 1% of steps, below {needed} m"
        )
    if passing.reach_goal_s is not None and (
        not summary.reached or (summary.time_to_goal_s or math.inf) > passing.reach_goal_s
    ):
        failures.append(f"goal not reached within {passing.reach_goal_s} s")
    if passing.end_state is not None and summary.end_state != passing.end_state:
        failures.append(f"ended '{summary.end_state}', not '{passing.end_state}'")
    if passing.closest_approach_m is not None:
        low, high = passing.closest_approach_m
        if not low <= summary.min_clearance_m <= high:
            failures.append(
                f"closest approach {summary.min_clearance_m:.2f} m, not {low}..{high} m"
            )
    failures += _bounds(summary, passing)
    summary.passed = not failures


def _bounds(summary: Summary, passing: PassConfig) -> list[str]:
    """The failures of the bounds on side changes, the start delay and the time to no path."""
    failures = []
    most = passing.max_side_changes
    if most is not None and summary.detour_side_changes > most:
        failures.append(f"{summary.detour_side_changes} side changes in one detour, over {most}")
    delay = passing.start_delay_s
    if delay is not None and (summary.start_delay_s is None or summary.start_delay_s > delay):
        failures.append(f"start delay {_seconds(summary.start_delay_s)}, over {delay} s")
    no_path = passing.no_path_within_s
    if no_path is not None and (summary.no_path_s is None or summary.no_path_s > no_path):
        failures.append(f"no path after {_seconds(summary.no_path_s)}, not within {no_path} s")
    return failures


def _seconds(value: float | None) -> str:
    return "never" if value is None else f"{value:.1f} s"
