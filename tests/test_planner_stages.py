"""The planner's stages, each on its own: surroundings, direction, search, view, speed, tuning."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from avoidd.config import AvoidanceConfig
from avoidd.planner.direction import Direction
from avoidd.planner.memory import ObstacleMemory
from avoidd.planner.search import Search
from avoidd.planner.speed import drift_speed_limit_m_s, stopping_speed_m_s
from avoidd.planner.surroundings import Surroundings
from avoidd.planner.tuning import DEFAULT, Tuning
from avoidd.planner.types import Pose
from avoidd.planner.view import View
from avoidd.types import SECTOR_COUNT

S = 1_000_000_000
CONFIG = AvoidanceConfig(enabled=True, unknown="free")


def _around(points: list[tuple[float, float]], pose: Pose | None = None) -> Surroundings:
    memory = ObstacleMemory(10.0)
    memory.north_east = np.array(points, dtype=np.float64).reshape(-1, 2)
    memory.t_ns = np.full(len(points), S, dtype=np.int64)
    pose = pose or Pose(S, 0.0, 0.0, -2.0, 0.0)
    return Surroundings.around(pose, memory, None, 1.5, 0.5, 6.0, 10.0, DEFAULT)


def _wall(north_m: float, half_m: float = 3.0) -> list[tuple[float, float]]:
    return [(north_m, float(e)) for e in np.arange(-half_m, half_m + 0.01, 0.1)]


# --- surroundings ------------------------------------------------------------------------------


def test_the_side_of_what_is_near_and_the_ways_toward_it_close_inside_the_clearance() -> None:
    around = _around(_wall(1.2))  # inside the 1.5 m clearance of a wall to the north
    side = around.side_within(around.clearance_m)
    assert side == pytest.approx(0.0, abs=1e-6)
    assert around.depth_inside_m == pytest.approx(0.3)
    headings = np.radians([0.0, 60.0, 95.0, 180.0])
    free = around.obstacle_free_m(headings)
    assert free[0] == 0.0 and free[1] == 0.0  # toward the wall's side: closed
    assert free[2] > 0.0 and np.isinf(free[3])  # along and away: open
    # Walls on both sides (a corridor narrower than the clearance): no one side.
    corridor = _around(_wall(1.2) + _wall(-1.2))
    assert corridor.side_within(corridor.clearance_m) is None
    assert corridor.near_side_rad() is None
    assert _around([]).near_side_rad() is None and _around([]).depth_inside_m == 0.0


# --- direction ---------------------------------------------------------------------------------


def test_a_way_enters_at_enter_m_and_leaves_only_below_leave_m() -> None:
    direction = Direction(DEFAULT, 1.0)
    # The goal north; clearance 1.5 m and a hover's turning buffer of 0.25 m: a wall 2.5 m
    # ahead leaves the way north free 0.75 m.

    def north_open(wall_m: float) -> bool:
        ways = direction.ways(_around(_wall(wall_m, 10.0)), 0.0, 20.0, searching=False)
        return bool(np.any(np.abs(ways.headings) < 1e-9))

    assert not north_open(2.5)  # never admissible: below enter_m
    assert north_open(3.0)  # free 1.25 m: admissible
    assert north_open(2.5)  # 0.75 m: still admissible (above leave_m)
    assert not north_open(2.1)  # 0.35 m: below leave_m
    assert not north_open(2.5)


def test_the_side_committed_to_costs_the_other_side_extra() -> None:
    direction = Direction(DEFAULT, 1.0)
    around = _around(_wall(2.5, 1.5))  # a short wall across the goal line
    ways = direction.ways(around, 0.0, 20.0, searching=False)
    assert not ways.goal_open
    right = direction.choose(ways, 0.0, 20.0)[0]
    direction.commit(right, ways)
    side = direction.side
    assert side in (1, -1)
    # Even facing the other side, the committed side wins.
    facing_other = direction.choose(ways, -side * math.radians(40.0), 20.0)[0]
    assert np.sign(math.remainder(facing_other, 2 * math.pi)) == side
    # Without the commitment the heading would take it to the other side.
    fresh = Direction(DEFAULT, 1.0)
    uncommitted = fresh.choose(
        fresh.ways(around, 0.0, 20.0, False), -side * math.radians(40.0), 20.0
    )
    assert np.sign(math.remainder(uncommitted[0], 2 * math.pi)) == -side


# --- search ------------------------------------------------------------------------------------


def test_no_progress_for_its_time_is_no_path_and_half_a_metre_nearer_restarts_it() -> None:
    search = Search(AvoidanceConfig(enabled=True, no_progress_s=10.0), DEFAULT)
    assert not search.no_progress(0, 20.0)
    assert not search.no_progress(9 * S, 19.6)  # 0.4 m nearer: no progress
    assert not search.no_progress(9 * S + 1, 19.4)  # 0.6 m: the timer restarts
    assert not search.no_progress(18 * S, 19.3)
    assert search.no_progress(20 * S, 19.3) and search.given_up
    search.reset()
    assert not search.given_up and not search.no_progress(21 * S, 19.0)


def test_a_whole_turn_round_the_goal_with_its_line_blocked_is_no_path() -> None:
    search = Search(CONFIG, DEFAULT)
    steps = np.linspace(0.0, 2.0 * math.pi + 0.1, 50)
    results = [search.circled(float(math.remainder(a, 2 * math.pi)), False) for a in steps]
    assert results[-1] and not any(results[:-3])
    again = Search(CONFIG, DEFAULT)
    # A clear line to the goal on the way round starts the count again.
    seen = [
        again.circled(float(math.remainder(a, 2 * math.pi)), k == 25) for k, a in enumerate(steps)
    ]
    assert not any(seen)


def test_the_look_around_turns_goal_side_first_then_back_and_ends() -> None:
    config = AvoidanceConfig(enabled=True, dead_end_scan_s=4.0, max_yaw_rate_deg_s=90.0)
    search = Search(config, DEFAULT)
    pose = Pose(S, 0.0, 0.0, -2.0, 0.0)
    first = search.look(S, pose, math.radians(30.0))  # the goal to the right
    assert first is not None and first > 0.0
    late = search.look(S + 3 * S, pose, math.radians(30.0))  # second half: the other way
    assert late is not None and late < 0.0
    assert search.look(S + 4 * S, pose, math.radians(30.0)) is None


# --- view and speed ----------------------------------------------------------------------------


def test_the_heading_turns_toward_the_goal_only_as_far_as_keeps_the_way_in_view() -> None:
    view = View(DEFAULT, math.radians(10.0))
    assert view.offset_rad(1.0) == 0.0  # no scan yet
    scan = np.full(SECTOR_COUNT, np.nan, dtype=np.float32)
    scan[list(range(0, 8)) + list(range(65, 72))] = np.inf  # -35..+35 degrees
    view.observe(scan)
    assert view.offset_rad(math.radians(80.0)) == pytest.approx(math.radians(37.5 - 10.0))
    assert view.offset_rad(math.radians(5.0)) == pytest.approx(math.radians(5.0))
    assert view.speed_share(0.0, 0.0) == 1.0
    assert view.speed_share(math.radians(90.0), 0.0) < 1.0
    view.observe(np.full(SECTOR_COUNT, np.inf, dtype=np.float32))  # all round: nothing to gain
    assert view.offset_rad(1.0) == 0.0


def test_the_speed_law_and_the_drift_limit() -> None:
    # v = sqrt(2 a (d - v t)): 2 m/s^2, 0.4 s, 6 m free.
    v = stopping_speed_m_s(6.0, 2.0, 0.4)
    assert v == pytest.approx(math.sqrt(2 * 2.0 * (6.0 - v * 0.4)))
    assert stopping_speed_m_s(0.0, 2.0, 0.4) == 0.0
    assert drift_speed_limit_m_s(0.0, 4.0) == 4.0
    assert drift_speed_limit_m_s(0.375, 4.0) == pytest.approx(3.0)
    assert drift_speed_limit_m_s(5.0, 4.0) == pytest.approx(2.0)  # never below half


def test_tuning_is_one_frozen_record_that_changes_the_rules() -> None:
    with pytest.raises(dataclasses.FrozenInstanceError):
        DEFAULT.mu_goal = 1.0  # type: ignore[misc]
    assert drift_speed_limit_m_s(0.375, 4.0, Tuning(drift_slowing=1.0)) == pytest.approx(2.0)
    assert Tuning(buffer_m=0.5).buffer_at_m(2.0) == pytest.approx(0.8)
