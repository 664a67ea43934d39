"""Through narrow gaps: finding them, lining up on their axis, and flying them closed-loop."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from avoidd.config.sim import ScenarioConfig
from avoidd.planner.gaps import GapFollower, find_gaps
from avoidd.planner.memory import ObstacleMemory, in_bin_rad
from avoidd.planner.surroundings import Surroundings
from avoidd.planner.tuning import DEFAULT
from avoidd.planner.types import Pose
from avoidd.planner.visibility import VisibilityGrid
from avoidd.sim.scenario import prepare
from avoidd.types import SECTOR_COUNT

S = 1_000_000_000
CLEARANCE_M = 1.5


def _wall_with_gap(north_m: float, middle_east_m: float, width_m: float) -> list[list[float]]:
    east = np.arange(-20.0, 20.0, 0.1)
    east = east[np.abs(east - middle_east_m) >= width_m / 2]
    return [[north_m, float(e)] for e in east]


def _around(points: list[list[float]], pose: Pose) -> Surroundings:
    memory = ObstacleMemory(10.0)
    memory.north_east = np.array(points, dtype=np.float64)
    memory.t_ns = np.full(len(points), pose.t_ns, dtype=np.int64)
    return Surroundings.around(pose, memory, None, CLEARANCE_M, 0.5, 4.5, 10.0, DEFAULT)


def _seen_all(pose: Pose) -> VisibilityGrid:
    grid = VisibilityGrid()
    grid.mark((pose.north_m, pose.east_m), 0.0, np.full(SECTOR_COUNT, np.inf), pose.t_ns, 20.0)
    return grid


def test_a_gap_in_a_wall_is_found_with_its_axis_and_width() -> None:
    pose = Pose(S, 0.0, 0.0, -2.0, 0.0)
    (gap,) = find_gaps(_around(_wall_with_gap(10.0, 3.0, 3.3), pose), 20.0)
    assert gap.middle == pytest.approx([10.0, 3.0], abs=0.06)
    assert gap.axis == pytest.approx([1.0, 0.0], abs=1e-6)
    assert 2 * gap.half_width_m == pytest.approx(3.3, abs=0.11)
    assert gap.distance_m == pytest.approx(10.0, abs=0.06)
    assert gap.lateral_m == pytest.approx(3.0, abs=0.06)


def test_the_space_between_two_poles_or_a_wall_never_looked_through_is_no_gap() -> None:
    pose = Pose(S, 0.0, 0.0, -2.0, 0.0)
    poles = [[8.0, -1.9], [8.1, -1.8], [8.0, 1.9], [8.1, 1.8]]  # 3.6 m apart, nothing beyond
    assert find_gaps(_around(poles, pose), 20.0) == []
    # A stretch of wall that two views' edges left out looks like a gap until it is checked
    # against what the cameras looked at.
    wall = _wall_with_gap(10.0, 0.0, 3.3)
    never_looked = VisibilityGrid()
    assert find_gaps(_around(wall, pose), 20.0, never_looked) == []
    assert len(find_gaps(_around(wall, pose), 20.0, _seen_all(pose))) == 1


def test_the_follower_lines_up_first_then_goes_through_and_gives_up_if_it_cannot() -> None:
    follower = GapFollower(9.0, give_up_s=10.0)
    wall = _wall_with_gap(10.0, 4.0, 3.3)
    goal = (30.0, 0.0)
    off_axis = Pose(S, 2.0, 0.0, -2.0, 0.0)
    sub = follower.subgoal(_around(wall, off_axis), (goal[0] - 2.0, goal[1]), True, 4.4)
    assert sub is not None
    # Toward a point on the axis short of the gap, and slow enough to stop there.
    assert 0.0 < math.degrees(sub.heading_rad) < 60.0
    assert math.isfinite(sub.stop_m)
    lined = Pose(2 * S, 5.0, 4.05, -2.0, 0.0)
    through = follower.subgoal(_around(wall, lined), (25.0, -4.05), True, 4.4)
    assert through is not None and abs(math.degrees(through.heading_rad)) < 2.0
    assert math.isinf(through.stop_m)
    # Nothing blocking the line to the goal: no gap needed; a wide gap: left to the grid.
    assert follower.subgoal(_around(wall, lined), (25.0, -4.05), False, 4.4) is None
    assert follower.subgoal(_around(wall, lined), (25.0, -4.05), True, 3.0) is None
    # The same gap followed for longer than the give-up time: given up.
    stuck = GapFollower(9.0, give_up_s=1.0)
    for t_s in (1.0, 1.5, 2.0):
        at = Pose(int(t_s * S), 2.0, 0.0, -2.0, 0.0)
        last = stuck.subgoal(_around(wall, at), (28.0, 0.0), True, 4.4)
    assert last is not None
    late = Pose(int(2.5 * S), 2.0, 0.0, -2.0, 0.0)
    assert stuck.subgoal(_around(wall, late), (28.0, 0.0), True, 4.4) is None


def test_a_gap_in_a_row_already_passed_is_not_flown_back_to() -> None:
    # Two short barriers on a slant behind and to the right of the vehicle, 3.7 m apart: the
    # goal lies beyond their line, but the line to the goal crosses it metres past the end of
    # the nearer one, where nothing stands (in a box field this turned the vehicle back).
    line = np.array([-0.79, 0.62]) / math.hypot(0.79, 0.62)
    near_edge, far_edge = np.array([-1.4, 2.7]), np.array([-1.4, 2.7]) + 3.7 * line
    steps = np.arange(0.0, 2.0, 0.1)[:, None]
    points = np.vstack([near_edge - steps * line, far_edge + steps * line])
    pose = Pose(S, 0.0, 0.0, -2.0, 0.0)
    around = _around(points.tolist(), pose)
    (gap,) = find_gaps(around, 20.0)
    assert gap.distance_m > 0.0  # ahead of the vehicle along its axis: the old rule took it
    assert GapFollower(9.0).subgoal(around, (7.3, 2.2), True, 4.4) is None
    # The same barrier with the line to the goal through the gap, or across the barrier
    # itself: followed.
    through = gap.middle + 8.0 * gap.axis
    assert GapFollower(9.0).subgoal(around, (float(through[0]), float(through[1])), True, 4.4)
    across = near_edge - 1.5 * line + 8.0 * gap.axis
    assert GapFollower(9.0).subgoal(around, (float(across[0]), float(across[1])), True, 4.4)


def test_a_reading_is_placed_at_its_measured_points_bearing() -> None:
    distance = np.full(SECTOR_COUNT, np.inf)
    distance[6] = 10.0  # bin 6: 27.5-32.5 degrees
    points = np.full((SECTOR_COUNT, 3), np.nan)
    bearing = math.radians(32.0)  # the wall's end at the bin's far edge
    points[6] = (10.0 * math.cos(bearing), 10.0 * math.sin(bearing), 0.0)
    assert in_bin_rad(distance, points)[6] == pytest.approx(math.radians(2.0))
    assert in_bin_rad(distance, None)[6] == 0.0  # without points: the middle (a lone bin)
    memory = ObstacleMemory(10.0)
    memory.add_scan(distance, S, (0.0, 0.0), 0.0, 20.0, points)
    assert memory.north_east[0] == pytest.approx(points[6, :2], abs=1e-6)


def test_a_forward_view_opens_the_way_ahead_at_take_off() -> None:
    # Only a forward view (+-37.5 degrees) seen: the corridor beside the vehicle lies outside
    # it, but right beside the vehicle it need only be as wide as the vehicle.
    grid = VisibilityGrid()
    scan = np.full(SECTOR_COUNT, np.nan)
    scan[list(range(0, 8)) + list(range(65, 72))] = np.inf
    grid.mark((0.0, 0.0), 0.0, scan, S, 20.0)
    ahead = np.array([0.0])
    assert grid.seen_distance((0.0, 0.0), ahead, 1.5, 6.0, 0) == pytest.approx(0.0)
    assert np.isinf(grid.seen_distance((0.0, 0.0), ahead, 1.5, 6.0, 0, near_half_m=0.5))
    sideways = np.array([math.pi / 2])
    assert grid.seen_distance((0.0, 0.0), sideways, 1.5, 6.0, 0, near_half_m=0.5)[0] < 1.0


def _gap_scenario(folder: Path, offset_m: float, wind_east_m_s: float = 0.0) -> ScenarioConfig:
    half = 3.3 / 2  # 2.2 x (radius + margin)
    world = folder / "world.yaml"
    world.write_text(
        yaml.safe_dump(
            {
                "version": 1,
                "seed": 5,
                "obstacles": [
                    {"shape": "wall", "start_ne_m": [15, -25], "end_ne_m": [15, offset_m - half]},
                    {"shape": "wall", "start_ne_m": [15, offset_m + half], "end_ne_m": [15, 25]},
                ],
            }
        )
    )
    return ScenarioConfig.model_validate(
        {
            "version": 1,
            "name": f"gap-{offset_m:g}",
            "world": str(world),
            "goal": {"north_m": 30.0, "east_m": 0.0, "altitude_m": 2.0},
            "perception": "oracle",
            "wind_m_s": [0.0, wind_east_m_s],
            "duration_s": 60.0,
            "pass": {"no_collision": True, "min_clearance_m": 0.9, "reach_goal_s": 60.0},
        }
    )


@pytest.mark.parametrize(
    ("offset_m", "wind_m_s"), [(0.0, 0.0), (3.0, 0.0), (-8.0, 0.0), (6.0, 3.0)]
)
def test_a_gap_of_2_2_clearances_is_flown_through_on_and_off_the_goal_line(
    tmp_path: Path, offset_m: float, wind_m_s: float
) -> None:
    summary = prepare(_gap_scenario(tmp_path, offset_m, wind_m_s)).run()
    assert summary.passed, summary.failures
    assert not summary.collided and summary.reached
