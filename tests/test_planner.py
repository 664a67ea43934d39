"""The local planner's parts: enlargement, speed law, memory, visibility, gating, decisions."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from avoidd.config import AvoidanceConfig, TemporalConfig
from avoidd.perception.temporal import SectorFilter
from avoidd.planner.core import (
    Goal,
    Planner,
    Pose,
    brake_overspeed,
    effective_latency_s,
    stopping_speed_m_s,
)
from avoidd.planner.gating import Facts, Gate, Handover, gate
from avoidd.planner.geometry import directions_rad, free_distance
from avoidd.planner.memory import ObstacleMemory, bearing_bins
from avoidd.planner.visibility import VisibilityGrid
from avoidd.types import SECTOR_COUNT, SectorScan

S = 1_000_000_000


def _scan(bins: dict[int, float], covered: range | None = None) -> np.ndarray:
    """A 72-bin body scan: unknown outside ``covered``, clear inside, ``bins`` as given."""
    scan = np.full(SECTOR_COUNT, np.nan, dtype=np.float32)
    for i in covered if covered is not None else range(SECTOR_COUNT):
        scan[i % SECTOR_COUNT] = np.inf
    for i, distance in bins.items():
        scan[i % SECTOR_COUNT] = distance
    return scan


# --- enlargement -------------------------------------------------------------------------


def test_a_point_ahead_blocks_the_headings_within_its_enlarged_angle() -> None:
    point = np.array([[5.0, 0.0]])  # 5 m north
    clearance = 1.5
    half_angle = math.asin(clearance / 5.0)
    headings = np.array([0.0, half_angle - 0.01, half_angle + 0.01, math.pi / 2, math.pi])
    free = free_distance(point, headings, clearance)
    assert free[0] == pytest.approx(5.0 - clearance)
    assert math.isfinite(free[1]) and free[1] > free[0]
    assert np.isinf(free[2:]).all()


def test_a_point_within_the_clearance_blocks_only_the_way_toward_it() -> None:
    point = np.array([[1.0, 0.0]])  # 1 m north, clearance 1.5: already too near
    free = free_distance(point, np.array([0.0, math.pi]), 1.5)
    assert free[0] == 0.0  # toward it
    assert np.isinf(free[1])  # away from it


# --- speed law ---------------------------------------------------------------------------


@pytest.mark.parametrize("free_m", [0.5, 2.0, 8.0, 30.0])
def test_the_stopping_speed_stops_within_the_free_distance_after_the_latency(
    free_m: float,
) -> None:
    accel, latency = 2.0, 0.4
    v = stopping_speed_m_s(free_m, accel, latency)
    assert v * latency + v * v / (2 * accel) == pytest.approx(free_m)


def test_no_speed_without_free_distance() -> None:
    assert stopping_speed_m_s(0.0, 2.0, 0.4) == 0.0
    assert stopping_speed_m_s(-1.0, 2.0, 0.4) == 0.0


# --- memory ------------------------------------------------------------------------------


def test_memory_places_readings_in_the_local_frame_with_the_pose_at_capture() -> None:
    memory = ObstacleMemory(memory_s=10.0)
    # Facing east from (10, 5): bin 0 at 4 m is the point (10, 9).
    memory.add_scan(_scan({0: 4.0}), 1 * S, (10.0, 5.0), math.pi / 2, 20.0)
    np.testing.assert_allclose(memory.north_east, [[10.0, 9.0]], atol=1e-9)
    # Seen from elsewhere it is where it was.
    np.testing.assert_allclose(memory.offsets((12.0, 9.0)), [[-2.0, 0.0]], atol=1e-9)


def test_memory_offsets_follow_every_change_of_points_and_position() -> None:
    # The offsets and ranges are kept between asks from one position: a new position, a new
    # scan, an expiry or a reset must each give fresh ones, and nobody may write into them.
    memory = ObstacleMemory(memory_s=2.0)
    memory.add_scan(_scan({0: 4.0}), 1 * S, (0.0, 0.0), 0.0, 20.0)
    offsets, ranges_m = memory.near((0.0, 0.0))
    np.testing.assert_allclose(ranges_m, [4.0], atol=1e-9)
    assert memory.near((0.0, 0.0))[0] is offsets  # asked again: the same arrays
    with pytest.raises(ValueError):
        offsets[0, 0] = 1.0
    np.testing.assert_allclose(memory.near((1.0, 0.0))[1], [3.0], atol=1e-9)
    memory.add_scan(_scan({18: 2.0}, range(14, 23)), 2 * S, (1.0, 0.0), 0.0, 20.0)  # east, 2 m
    np.testing.assert_allclose(sorted(memory.near((1.0, 0.0))[1]), [2.0, 3.0], atol=1e-9)
    memory.expire(int(3.5 * S))  # the first scan's point is gone
    np.testing.assert_allclose(memory.near((1.0, 0.0))[1], [2.0], atol=1e-9)
    memory.clear()
    assert memory.near((1.0, 0.0))[1].size == 0


def test_memory_keeps_what_leaves_the_view_and_forgets_it_after_the_memory_time() -> None:
    memory = ObstacleMemory(memory_s=2.0)
    memory.add_scan(_scan({0: 4.0}, range(-7, 8)), 1 * S, (0.0, 0.0), 0.0, 20.0)
    # Turned away: the point is unknown to the new scan (not covered), so it stays.
    memory.add_scan(_scan({}, range(29, 44)), 2 * S, (0.0, 0.0), 0.0, 20.0)
    assert len(memory.north_east) == 1
    memory.expire(int(2.9 * S))
    assert len(memory.north_east) == 1
    memory.expire(int(3.1 * S))
    assert len(memory.north_east) == 0


def test_a_reading_that_sees_past_a_remembered_point_removes_it() -> None:
    memory = ObstacleMemory(memory_s=10.0)
    memory.add_scan(_scan({0: 4.0}), 1 * S, (0.0, 0.0), 0.0, 20.0)
    memory.add_scan(_scan({}), 2 * S, (0.0, 0.0), 0.0, 20.0)  # clear now
    assert len(memory.north_east) == 0


def _nearest_per_bin(east_m: float, north_from_m: float, north_to_m: float) -> np.ndarray:
    """What a forward sensor at the origin (yaw 0, bins -7..7) reads of a wall along ``east_m``:
    each bin's nearest point of the wall, as the stereo sectors report it."""
    scan = _scan({}, range(-7, 8))
    for i in range(-7, 8):
        nearest = math.inf
        for bearing_deg in np.linspace(5.0 * i - 2.5, 5.0 * i + 2.5, 101):
            sin_b = math.sin(math.radians(bearing_deg))
            if sin_b * east_m <= 0.0:
                continue
            distance = east_m / sin_b
            if north_from_m <= distance * math.cos(math.radians(bearing_deg)) <= north_to_m:
                nearest = min(nearest, distance)
        scan[i % SECTOR_COUNT] = nearest if nearest < 20.0 else np.inf
    return scan


def test_a_slanted_wall_is_remembered_on_the_wall_not_in_front_of_it() -> None:
    # A corridor's side wall 2 m to the right: each bin reads the wall's nearest point, at the
    # bin's edge; placed in the bins' middles they would stand up to 0.3 m in front of it.
    memory = ObstacleMemory(memory_s=10.0)
    memory.add_scan(_nearest_per_bin(2.0, 0.5, 30.0), S, (0.0, 0.0), 0.0, 20.0)
    points = memory.north_east
    near = points[np.hypot(points[:, 0], points[:, 1]) < 12.0]
    assert len(near) >= 4
    np.testing.assert_allclose(near[:, 1], 2.0, atol=0.02)


def test_a_phantom_in_front_of_a_slanted_wall_is_cleared_though_the_next_bin_reads_nearer() -> None:
    # A noisy reading left a point 0.6 m in front of the wall (17.6 degrees, 4.5 m). The bins
    # within half a bin of it look past it; the next bin out reads the wall nearer than it.
    memory = ObstacleMemory(memory_s=10.0)
    phantom = (4.5 * math.cos(math.radians(17.6)), 4.5 * math.sin(math.radians(17.6)))
    memory.north_east = np.array([phantom])
    memory.t_ns = np.array([S], dtype=np.int64)
    wall = _nearest_per_bin(2.0, 0.5, 30.0)
    assert wall[5] < 4.5 + 0.3 < wall[4]
    memory.add_scan(wall, 2 * S, (0.0, 0.0), 0.0, 20.0)
    assert not np.any(np.all(np.isclose(memory.north_east, phantom), axis=1))


def test_the_end_of_a_wall_beside_a_gap_stays_when_the_gap_is_looked_through() -> None:
    # The wall's end was placed at 2 degrees, 5 m (half a bin off, as a bin's middle can be):
    # bin 0 now looks through the gap beside it, bin 1 still reads the wall there.
    memory = ObstacleMemory(memory_s=10.0)
    end = (5.0 * math.cos(math.radians(2.0)), 5.0 * math.sin(math.radians(2.0)))
    memory.north_east = np.array([end])
    memory.t_ns = np.array([S], dtype=np.int64)
    memory.add_scan(_scan({1: 5.0, 2: 5.2}, range(-7, 8)), 2 * S, (0.0, 0.0), 0.0, 20.0)
    assert np.any(np.all(np.isclose(memory.north_east, end), axis=1))


def test_bearing_bins_follow_the_yaw() -> None:
    bins = bearing_bins(np.array([math.pi / 2, math.pi]), math.pi / 2)
    assert bins.tolist() == [0, 18]


def test_a_held_reading_is_not_placed_again_at_the_turned_pose() -> None:
    # A wall's edge 5 m away at 10 degrees; the vehicle turns 6 degrees right between two
    # frames, so the edge moves from bin 2 to bin 1 and bin 2 reads clear. The sector filter
    # holds bin 2's reading for a moment: placed again at the new yaw it would stand 0.5 m
    # into the gap beside the edge (16 degrees).
    sectors = SectorFilter(TemporalConfig(confirm_frames=1, window_frames=1, hold_ms=200))
    t2 = S + 70_000_000
    first = sectors.update(SectorScan(S, _scan({2: 5.0}, range(-7, 8))))
    second = sectors.update(SectorScan(t2, _scan({1: 5.0}, range(-7, 8))))
    assert second.distance_m[2] == pytest.approx(5.0)  # held
    turned = _pose(1.07, yaw=math.radians(6.0))

    def nearest_m(planner: Planner, bearing_deg: float) -> float:
        where = 5.0 * np.array(
            [math.cos(math.radians(bearing_deg)), math.sin(math.radians(bearing_deg))]
        )
        return float(np.min(np.hypot(*(planner.memory.north_east - where).T)))

    planner = _planner()
    planner.observe_scan(first.distance_m, S, _pose(1.0), None, first.reading_t_ns)
    planner.observe_scan(second.distance_m, t2, turned, None, second.reading_t_ns)
    assert nearest_m(planner, 10.0) < 0.1
    assert nearest_m(planner, 16.0) > 0.4
    # Without the reading times the held reading is placed again where the turn carried it.
    unaware = _planner()
    unaware.observe_scan(first.distance_m, S, _pose(1.0))
    unaware.observe_scan(second.distance_m, t2, turned)
    assert nearest_m(unaware, 16.0) < 0.1


# --- visibility --------------------------------------------------------------------------


def test_only_what_a_scan_looked_through_counts_as_seen() -> None:
    grid = VisibilityGrid()
    # Everything within 20 m was seen at t = 0 (the vehicle turned once around); then a
    # camera of +-70 degrees saw clear ahead at 5 s.
    grid.mark((0.0, 0.0), 0.0, _scan({}), 0, 20.0)
    grid.mark((0.0, 0.0), 0.0, _scan({}, range(-14, 15)), 5 * S, 20.0)
    headings = np.array([0.0, math.pi / 2, math.pi])
    assert np.isinf(grid.seen_distance((0.0, 0.0), headings, 0.5, 6.0, 0)).all()
    # With the turn forgotten, only ahead is seen.
    recent = grid.seen_distance((0.0, 0.0), headings, 0.5, 6.0, 4 * S)
    assert np.isinf(recent[0])
    assert recent[1] < 1.0 and recent[2] < 1.0
    # A narrow camera cannot vouch for the vehicle's own flanks: it must turn to look.
    narrow = VisibilityGrid()
    narrow.mark((0.0, 0.0), 0.0, _scan({}, range(-6, 7)), 5 * S, 20.0)
    assert narrow.seen_distance((0.0, 0.0), headings[:1], 0.5, 6.0, 4 * S)[0] < 1.0


def test_a_surface_hides_what_is_behind_it() -> None:
    grid = VisibilityGrid()
    grid.mark((0.0, 0.0), 0.0, _scan({i: 3.0 for i in range(-8, 9)}), S, 20.0)
    seen = grid.seen_distance((0.0, 0.0), np.array([0.0, math.pi]), 0.5, 10.0, 0)
    assert 2.0 < seen[0] < 3.5
    assert np.isinf(seen[1])


# --- gating ------------------------------------------------------------------------------


def _facts(**changes: bool) -> Facts:
    base = {
        "enabled": True,
        "link_up": True,
        "armed": True,
        "setpoint_mode": True,
        "px4": False,
        "goal": True,
        "fresh": True,
        "prestream": True,
    }
    return Facts(**(base | changes))


def test_gate_plans_only_when_every_condition_holds() -> None:
    assert gate(_facts()) is Gate.PLAN
    for missing in ("enabled", "link_up", "armed", "goal"):
        assert gate(_facts(**{missing: False})) is Gate.SILENT, missing


def test_gate_never_fights_the_pilot_and_holds_on_stale_perception() -> None:
    assert gate(_facts(setpoint_mode=False)) is Gate.SILENT  # ArduPilot in LOITER
    assert gate(_facts(fresh=False)) is Gate.HOLD
    assert gate(_facts(setpoint_mode=False, px4=True)) is Gate.PRESTREAM
    assert gate(_facts(setpoint_mode=False, px4=True, prestream=False)) is Gate.SILENT
    # PX4 in a failsafe: a prestream would end it and return PX4 to OFFBOARD by itself.
    assert gate(_facts(setpoint_mode=False, px4=True, autopilot_failsafe=True)) is Gate.SILENT
    assert gate(_facts(autopilot_failsafe=True)) is Gate.PLAN  # in OFFBOARD: flies as before
    assert gate(_facts(setpoint_mode=False, fresh=False)) is Gate.SILENT


def test_handover_the_pilot_has_the_vehicle_after_leaving_the_setpoint_mode_until_a_new_goal() -> (
    None
):
    handover = Handover()
    handover.new_goal()
    assert not handover.update(True, armed=True, setpoint_mode=False, link_up=True)  # POSCTL
    assert not handover.update(True, armed=True, setpoint_mode=True, link_up=True)  # OFFBOARD
    # A heartbeat lost says nothing about the mode: not a takeover.
    assert not handover.update(True, armed=True, setpoint_mode=False, link_up=False)
    assert not handover.update(True, armed=True, setpoint_mode=True, link_up=True)
    assert handover.update(True, armed=True, setpoint_mode=False, link_up=True)  # switched away
    assert handover.update(True, armed=True, setpoint_mode=True, link_up=True)  # still the pilot's
    handover.new_goal()
    assert not handover.taken_over
    assert handover.update(True, armed=True, setpoint_mode=True, link_up=True) is False
    assert handover.update(True, armed=True, setpoint_mode=False, link_up=True)
    assert not handover.update(True, armed=False, setpoint_mode=False, link_up=True)  # disarmed
    assert not handover.update(False, armed=False, setpoint_mode=False, link_up=True)


def test_handover_armed_in_another_mode_at_first_sight_is_the_pilots_unless_a_goal_came_first() -> (
    None
):
    first = Handover()
    assert not first.update(False, armed=False, setpoint_mode=False, link_up=False)
    assert first.update(True, armed=True, setpoint_mode=False, link_up=True)
    assert not Handover().update(True, armed=True, setpoint_mode=True, link_up=True)
    assert not Handover().update(True, armed=False, setpoint_mode=False, link_up=True)
    with_goal = Handover()
    with_goal.new_goal()
    assert not with_goal.update(True, armed=True, setpoint_mode=False, link_up=True)


# --- decisions ---------------------------------------------------------------------------


def _planner(**changes: object) -> Planner:
    return Planner(AvoidanceConfig.model_validate({"enabled": True} | changes), 20.0)


def _pose(t_s: float, north: float = 0.0, east: float = 0.0, yaw: float = 0.0) -> Pose:
    return Pose(int(t_s * S), north, east, -2.0, yaw)


def test_open_ground_flies_straight_to_the_goal_at_full_speed() -> None:
    planner = _planner()
    planner.observe_scan(_scan({}), S, _pose(1.0))
    decision = planner.decide(S, _pose(1.0), Goal(30.0, 0.0, 2.0), fresh=True)
    assert decision.state == "moving"
    assert decision.direction_deg == pytest.approx(0.0)
    assert decision.velocity_ned[0] == pytest.approx(3.0)
    assert decision.velocity_ned[1] == pytest.approx(0.0, abs=1e-9)


def test_an_unseen_way_is_never_taken_when_unknown_is_blocked() -> None:
    planner = _planner()
    # Only the forward 60 degrees were looked at; the goal is behind.
    planner.observe_scan(_scan({}, range(-6, 7)), S, _pose(1.0))
    decision = planner.decide(S, _pose(1.0), Goal(-30.0, 0.0, 2.0), fresh=True)
    if decision.state == "moving":
        assert abs(math.remainder(decision.direction_deg or 0.0, 360.0)) <= 35.0
    else:
        assert decision.holding and decision.yaw_rate_rad_s != 0.0  # turning to look


def test_an_obstacle_ahead_is_passed_on_one_side_at_the_clearance() -> None:
    planner = _planner()
    # A post ahead, nearer than its enlargement plus the admissibility threshold.
    scan = _scan({0: 2.2, 1: 2.25, -1: 2.25})
    planner.observe_scan(scan, S, _pose(1.0))
    decision = planner.decide(S, _pose(1.0), Goal(30.0, 0.0, 2.0), fresh=True)
    assert decision.state == "moving"
    offset = abs(math.remainder(decision.direction_deg or 0.0, 360.0))
    # Out of the enlarged post: asin(1.75 / 2.2) = 53 deg (clearance plus turning buffer).
    assert 50.0 <= offset <= 90.0


def test_the_chosen_side_is_kept_while_the_obstacle_is_passed() -> None:
    planner = _planner()
    sides = []
    for step in range(20):
        t = 1.0 + 0.05 * step
        # A wide wall ahead whose readings jitter from frame to frame.
        jitter = 0.05 * math.sin(step * 2.3)
        scan = _scan({i: 5.0 / math.cos(math.radians(5 * i)) + jitter for i in range(-6, 7)})
        planner.observe_scan(scan, int(t * S), _pose(t))
        decision = planner.decide(int(t * S), _pose(t), Goal(30.0, 0.0, 2.0), fresh=True)
        if decision.direction_deg is not None:
            sides.append(math.copysign(1, math.remainder(decision.direction_deg, 360.0)))
    assert sides and len(set(sides)) == 1


def test_speed_follows_the_free_distance() -> None:
    near, far = _planner(), _planner()
    near.observe_scan(_scan({0: 4.0}), S, _pose(1.0))
    far.observe_scan(_scan({0: 12.0}), S, _pose(1.0))
    goal = Goal(30.0, 0.0, 2.0)
    slow = near.decide(S, _pose(1.0), goal, fresh=True)
    fast = far.decide(S, _pose(1.0), goal, fresh=True)
    assert slow.speed_limit_m_s < fast.speed_limit_m_s


def test_an_old_scan_slows_the_vehicle_as_a_longer_latency_would() -> None:
    """Perception running late (a loaded machine): the speed law counts the scan's age."""
    goal = Goal(30.0, 0.0, 2.0)
    speeds = []
    for age_s in (0.05, 0.3, 0.6):
        planner = _planner()
        # A wall 4 m away across the whole view: every way ahead is free for the same
        # distance, so the speed law decides.
        planner.observe_scan(_scan({i: 4.0 for i in range(-7, 8)}), S, _pose(1.0))
        t_ns = S + int(age_s * S)
        speeds.append(planner.decide(t_ns, _pose(t_ns / S), goal, fresh=True).speed_limit_m_s)
    # A fresh scan: the configured latency (0.4 s) governs, as 0.05 + 0.05 + 0.2 s is less;
    # older ones: their age counts, and the speed falls as it would for that latency.
    assert speeds[0] > speeds[1] > speeds[2] > 0.0
    free_m = 4.0 - 1.0  # about: the wall less radius and margin
    ratio = stopping_speed_m_s(free_m, 2.0, 0.85) / stopping_speed_m_s(free_m, 2.0, 0.4)
    assert speeds[2] / speeds[0] == pytest.approx(ratio, rel=0.1)
    assert effective_latency_s(0.4, 0.05, 20.0) == 0.4
    assert effective_latency_s(0.4, 0.6, 20.0) == pytest.approx(0.6 + 0.05 + 0.2)


def test_stale_perception_holds() -> None:
    planner = _planner()
    decision = planner.decide(S, _pose(1.0), Goal(30.0, 0.0, 2.0), fresh=False)
    assert decision.state == "stale"
    assert decision.holding


def test_arrival_holds_and_says_so() -> None:
    planner = _planner()
    planner.observe_scan(_scan({}), S, _pose(1.0))
    decision = planner.decide(S, _pose(1.0, 29.5, 0.2), Goal(30.0, 0.0, 2.0), fresh=True)
    assert decision.state == "arrived"
    assert decision.holding


def test_boxed_in_means_turn_to_look_then_no_path() -> None:
    planner = _planner(dead_end_scan_s=2.0)
    walls = _scan({i: 1.8 for i in range(SECTOR_COUNT)})
    goal = Goal(30.0, 0.0, 2.0)
    planner.observe_scan(walls, S, _pose(1.0))
    first = planner.decide(S, _pose(1.0), goal, fresh=True)
    assert first.state == "dead end"
    assert first.holding and first.yaw_rate_rad_s != 0.0
    for step in range(1, 51):  # 2.5 s of cycles at 20 Hz
        t = 1.0 + 0.05 * step
        planner.observe_scan(walls, int(t * S), _pose(t))
        last = planner.decide(int(t * S), _pose(t), goal, fresh=True)
    assert last.state == "no path"
    assert last.holding and last.yaw_rate_rad_s == 0.0


def test_the_72_directions_are_five_degrees_apart_from_north() -> None:
    d = np.degrees(directions_rad())
    assert d[0] == 0.0 and d[1] == 5.0 and len(d) == 72


def test_time_not_planning_is_not_time_without_progress() -> None:
    planner = _planner(no_progress_s=5.0)
    goal = Goal(30.0, 0.0, 2.0)
    wall = _scan({i: 2.0 for i in range(-3, 4)})
    planner.observe_scan(wall, S, _pose(1.0))
    planner.decide(S, _pose(1.0), goal, fresh=True)
    # Ten seconds in another mode (no decisions), then planning again: not given up.
    planner.observe_scan(_scan({}), 11 * S, _pose(11.0))
    decision = planner.decide(11 * S, _pose(11.0), goal, fresh=True)
    assert decision.state != "no path"


def _wall_scan(pose: Pose, north_m: float, gaps: list[tuple[float, float]]) -> np.ndarray:
    """What a 360-degree sensor at ``pose`` reads of a wall along ``north_m`` (east gaps open)."""
    scan = np.full(SECTOR_COUNT, np.inf, dtype=np.float32)
    for i in range(SECTOR_COUNT):
        bearing = pose.yaw_rad + math.radians(5.0 * i)
        cos_n = math.cos(bearing)
        if cos_n <= 1e-6:
            continue
        distance = (north_m - pose.north_m) / cos_n
        east = pose.east_m + distance * math.sin(bearing)
        if distance < 20.0 and not any(low < east < high for low, high in gaps):
            scan[i] = distance
    return scan


def test_a_gap_too_narrow_at_speed_makes_the_vehicle_slow_down_then_take_it() -> None:
    # Flying north at 3 m/s toward a wall with a 4 m gap whose middle is 2.3 m to the left of
    # the way: the gap is wider than the clearance (2 x 1.5 m) plus the turning buffer at
    # walking pace, not at 3 m/s; no 5-degree direction runs through its middle.
    goal = Goal(30.0, 0.0, 2.0)
    gaps = [(-3.5, 0.5)]
    planner = _planner(unknown="free")
    # 10 m off the wall the turn is not near yet: no slowing down (the speed law: 3 m/s).
    far = Pose(S, 5.0, 0.8, -2.0, 0.0, 3.0, 0.0)
    planner.observe_scan(_wall_scan(far, 15.0, gaps), S, far)
    assert planner.decide(S, far, goal, fresh=True).speed_limit_m_s > 2.0
    # 5 m off it, within a stop from full speed: walking pace, so that the gap opens.
    fast = Pose(2 * S, 10.0, 0.8, -2.0, 0.0, 3.0, 0.0)
    planner.observe_scan(_wall_scan(fast, 15.0, gaps), 2 * S, fast)
    approaching = planner.decide(2 * S, fast, goal, fresh=True)
    assert approaching.state == "moving" and approaching.speed_limit_m_s <= 1.0
    # Slowed down: the line through the middle of the gap.
    slow = Pose(3 * S, 10.0, 0.8, -2.0, 0.0, 0.8, 0.0)
    planner.observe_scan(_wall_scan(slow, 15.0, gaps), 3 * S, slow)
    through = planner.decide(3 * S, slow, goal, fresh=True)
    assert through.state == "moving"
    # It crosses the wall's line inside the gap, the clearance (1.5 m) from both ends.
    crossing_east = 0.8 + 5.0 * math.tan(math.radians(through.direction_deg or 90.0))
    assert -2.0 <= crossing_east <= -1.0, through
    # Without the gap, no reason to slow down at 5 m either (the speed law alone).
    plain = _planner(unknown="free")
    plain.observe_scan(_wall_scan(fast, 15.0, []), 2 * S, fast)
    assert plain.decide(2 * S, fast, goal, fresh=True).speed_limit_m_s > 1.0


def test_after_two_side_changes_round_one_obstacle_a_third_is_a_dead_end_then_no_path() -> None:
    # A pocket: whichever side the vehicle tries, the next scan shows that side closed and the
    # other open (a cul-de-sac seen bit by bit). Sides 1 and 2 are allowed, not a third.
    planner = _planner(unknown="free", memory_s=0.0, dead_end_scan_s=1.0)
    goal = Goal(30.0, 0.0, 2.0)
    states, sides = [], []
    for step in range(14):
        t_ns = S + step * S // 2
        pose = Pose(t_ns, 10.0, 0.0, -2.0, 0.0)
        closed = -1 if not sides or sides[-1] < 0 else 1  # the side it went last time
        bins = {i: 2.0 for i in range(-3, 4)}  # the back of the pocket
        if "dead end" in states:  # both sides closed, the way back out open
            bins |= {i: 2.0 for i in [*range(4, 13), *range(-12, -3)]}
        else:
            bins |= {closed * i: 1.7 for i in range(4, 36)}
        planner.observe_scan(_scan(bins), t_ns, pose)
        decision = planner.decide(t_ns, pose, goal, fresh=True)
        states.append(decision.state)
        if decision.direction_deg is not None:
            sides.append(1 if math.remainder(decision.direction_deg, 360.0) > 0 else -1)
    changes = sum(a != b for a, b in itertools.pairwise(sides))
    assert changes == 2, (sides, states)
    # The scan finds no way on toward the goal: no path, not backing out of the pocket (the
    # way out behind it is open; leaving is the pilot's call).
    stuck = states[states.index("dead end") :]
    assert set(stuck) == {"dead end", "no path"} and stuck[-1] == "no path", states


def test_a_way_on_closed_for_a_frame_brakes_and_backing_out_keeps_the_side() -> None:
    # Going north past a wall on the goal's side (the goal is 60 degrees right). Frames that
    # show everything ahead closed make the vehicle brake (no way back chosen on one frame's
    # word: the setpoint asks for the vehicle's speed back, less the overspeed slack, and
    # nothing beyond but the back-away); closed for 0.3 s, it backs out; when the way north
    # opens again it goes on north, not back (backing out left the commitment as it was).
    planner = _planner(unknown="free", memory_s=0.0)
    goal = Goal(15.0, 26.0, 2.0)
    right_wall = {i: 2.6 for i in range(9, 25)}  # closes the goal's way, not north
    closed = {i: 1.0 for i in range(-20, 21)}
    decisions = []
    for step, bins in enumerate([right_wall, closed, closed, closed, closed, right_wall]):
        t_ns = S + step * S // 10
        pose = Pose(t_ns, 5.0 + 0.01 * step, 0.0, -2.0, 0.0, 1.0, 0.0)
        planner.observe_scan(_scan(bins), t_ns, pose)
        decisions.append(planner.decide(t_ns, pose, goal, fresh=True))
    first, *braking, backing, last = decisions
    ways = [d.direction_deg for d in (first, backing, last)]
    assert None not in ways, decisions
    north, back, north_again = (abs(math.remainder(w or 0.0, 360.0)) for w in ways)
    assert north <= 15.0 and north_again <= 15.0 and back >= 100.0, ways
    for decision in braking:
        assert decision.direction_deg is None
        # The brake, and the back-away from what the closed frames put within the clearance
        # (1.0 m against 1.5: at most 0.75 m/s) on top: neither cancels the other.
        north_m_s, east_m_s = decision.velocity_ned[:2]
        assert -(1.0 - 0.25) - 0.75 - 1e-9 <= north_m_s <= -(1.0 - 0.25) - 0.5
        assert east_m_s == pytest.approx(0.0, abs=0.1)  # the back-away leans a little


def test_a_corridor_wide_enough_at_walking_pace_stays_open_along_it_at_full_speed() -> None:
    # Walls 1.85 m either side, from 1 m ahead: room for the clearance (1.5 m) and the turning
    # buffer at walking pace (0.25 m), not for the buffer at 3 m/s. Flying straight along it
    # the vehicle does not turn, so it goes on at speed instead of turning back.
    planner = _planner(unknown="free", memory_s=10.0)
    along = np.arange(1.0, 20.0, 0.1)
    planner.memory.north_east = np.concatenate(
        [np.stack([along, np.full_like(along, side)], axis=1) for side in (-1.85, 1.85)]
    )
    planner.memory.t_ns = np.full(len(planner.memory.north_east), S, dtype=np.int64)
    fast = Pose(S, 0.0, 0.0, -2.0, 0.0, 3.0, 0.0)
    decision = planner.decide(S, fast, Goal(30.0, 0.0, 2.0), fresh=True)
    assert decision.state == "moving" and decision.direction_deg == pytest.approx(0.0)
    assert decision.speed_limit_m_s >= 2.5
    # Turning into the same corridor from across it, the buffer at speed is kept.
    across = Pose(S, 0.0, 0.0, -2.0, 0.0, 0.0, 3.0)
    turned = _planner(unknown="free", memory_s=10.0)
    turned.memory.north_east, turned.memory.t_ns = planner.memory.north_east, planner.memory.t_ns
    assert turned.decide(S, across, Goal(30.0, 0.0, 2.0), fresh=True).direction_deg != 0.0


def test_within_the_clearance_of_a_wall_no_way_leads_nearer_to_it() -> None:
    # Stopped 1.3 m from a wall (inside the 1.5 m clearance: stereo's overshoot). Along it and
    # away stay open; 5 degrees toward it is closed (else the vehicle creeps in a few
    # centimetres a cycle, each cycle's nearest point the new limit).
    planner = _planner(unknown="free", memory_s=10.0)
    along = np.arange(-5.0, 20.0, 0.1)
    wall = np.stack([along, np.full_like(along, 1.3)], axis=1)
    planner.memory.north_east = wall
    planner.memory.t_ns = np.full(len(wall), S, dtype=np.int64)
    pose = _pose(1.0)
    free = planner.obstacle_free_m(pose, np.radians([0.0, 5.0, -5.0, -90.0, 180.0]))
    assert free[0] == np.inf and free[2] == np.inf and free[3] == np.inf and free[4] == np.inf
    assert free[1] == 0.0
    # Between two such walls (a corridor narrower than the clearance) the way along stays open.
    planner.memory.north_east = np.concatenate([wall, wall * [1.0, -1.0]])
    planner.memory.t_ns = np.full(2 * len(wall), S, dtype=np.int64)
    assert planner.obstacle_free_m(pose, np.radians([0.0]))[0] == np.inf


@pytest.mark.parametrize(
    ("wall_east_m", "away_min_m_s", "away_max_m_s"),
    [(1.6, 0.0, 0.0), (1.5, 0.0, 0.0), (1.3, 0.25, 0.35), (1.0, 0.75, 0.75), (0.8, 0.75, 0.75)],
)
def test_inside_the_clearance_of_a_wall_flown_along_the_setpoint_leads_away_from_it(
    wall_east_m: float, away_min_m_s: float, away_max_m_s: float
) -> None:
    # Flying north along a wall on the right, with the goal straight on. An autopilot that
    # drifts toward the wall (PX4 SITL under load: 0.2 m/s off its setpoint for seconds) is
    # brought back: within the 1.5 m clearance by more than 5 cm, a speed away from the wall
    # of 2 m/s per metre inside, at most 0.75 m/s; none outside the clearance.
    planner = _planner(unknown="free", memory_s=10.0)
    along = np.arange(-5.0, 40.0, 0.1)
    wall = np.stack([along, np.full_like(along, wall_east_m)], axis=1)
    planner.memory.north_east = wall
    planner.memory.t_ns = np.full(len(wall), S, dtype=np.int64)
    pose = Pose(S, 0.0, 0.0, -2.0, 0.0, 2.0, 0.0)
    decision = planner.decide(S, pose, Goal(30.0, 0.0, 2.0), fresh=True)
    assert decision.state == "moving"
    north_m_s, east_m_s, _ = decision.velocity_ned
    away_m_s = -east_m_s
    assert away_min_m_s - 1e-6 <= away_m_s <= away_max_m_s + 1e-6, decision
    assert north_m_s > 1.0  # it still flies on along the wall
    assert math.hypot(north_m_s, east_m_s) <= planner.config.max_speed_m_s + 1e-9
    # The same wall on the left: the same speed, the other way (a planner of its own: the
    # speed away grows while the vehicle stays inside).
    mirror = _planner(unknown="free", memory_s=10.0)
    mirror.memory.north_east = wall * [1.0, -1.0]
    mirror.memory.t_ns = planner.memory.t_ns
    mirrored = mirror.decide(S, pose, Goal(30.0, 0.0, 2.0), True)
    assert mirrored.velocity_ned[1] == pytest.approx(away_m_s, abs=1e-6)


def _moving(north_m_s: float, east_m_s: float) -> Pose:
    return Pose(S, 0.0, 0.0, -2.0, 0.0, north_m_s, east_m_s)


def test_a_vehicle_outrunning_its_plan_is_asked_for_the_excess_back() -> None:
    # Flying north at 1.5 m/s when the plan turns east along a wall ahead: the setpoint also
    # asks to brake the 1.5 m/s north (less the 0.25 m/s slack) at once, against the way the
    # vehicle came; the plan is kept whole within the maximum speed, the braking shares it.
    north, east = brake_overspeed((0.0, 1.0), (0.0, 0.0), _moving(1.5, 0.0), 2.0)
    assert north == pytest.approx(-1.25)
    assert east == pytest.approx(1.0)
    north, east = brake_overspeed((0.0, 2.0), (0.0, 0.0), _moving(1.5, 0.0), 2.0)
    assert (north, east) == pytest.approx((0.0, 2.0))
    north, east = brake_overspeed((0.0, 1.8), (0.0, 0.0), _moving(1.5, 0.0), 2.0)
    assert math.hypot(north, east) == pytest.approx(2.0)
    assert north == pytest.approx(-math.sqrt(2.0**2 - 1.8**2)) and east == pytest.approx(1.8)
    # The speed law slowing the way flown: 1.6 m/s measured, 1.1 planned: 0.25 m/s more brake.
    slowing = brake_overspeed((1.1, 0.0), (0.0, 0.0), _moving(1.6, 0.0), 2.0)
    assert slowing == pytest.approx((0.85, 0.0))


def test_a_vehicle_short_of_its_plan_gets_the_plan_unchanged() -> None:
    # Accelerating, short of the setpoint against drag, within the slack, hovering, or with a
    # little noise against the plan: as planned.
    for velocity, plan in [
        ((1.0, 0.0), (2.0, 0.0)),
        ((1.6, 0.0), (2.0, 0.0)),
        ((1.2, 0.0), (1.0, 0.2)),
        ((0.0, 0.0), (0.0, 1.0)),
        ((-0.01, 0.0), (1.0, 0.0)),
        ((-0.2, 0.1), (0.4, 0.0)),
    ]:
        assert brake_overspeed(plan, (0.0, 0.0), _moving(*velocity), 2.0) == plan


def test_braking_never_speeds_the_plan_up_nor_undoes_a_back_away() -> None:
    # Going back the way it came at 1.5 m/s while the plan says 0.4 m/s on (the speed law's
    # stopping speed toward a wall): nothing is added toward the wall.
    north, east = brake_overspeed((0.4, 0.0), (0.0, 0.0), _moving(-1.5, 0.0), 2.0)
    assert north <= 0.4 + 1e-9
    # Along a wall to the north with a back-away south in the plan, the vehicle already leaving
    # south faster than that: its speed away is not braked (nothing toward the wall).
    plan, away = (-0.3, 1.0), (-0.3, 0.0)
    north, east = brake_overspeed(plan, away, _moving(-1.5, 0.3), 2.0)
    assert north <= plan[0] + 1e-9
    # Backing away west from a wall to the east while drifting west-southwest: the speed
    # away is kept whole.
    plan, away = (0.8, -0.3), (0.0, -0.3)
    north, east = brake_overspeed(plan, away, _moving(-0.2, -0.6), 2.0)
    assert east <= plan[1] + 1e-9
    assert north <= plan[0] + 1e-9


def test_an_overshooting_vehicle_is_braked_in_the_setpoint_the_planner_sends() -> None:
    # At 1.8 m/s north toward a wall 2 m ahead that closes the way on, the plan turns along
    # it (east): the setpoint sent says south as well, as hard as the vehicle outruns the plan.
    planner = _planner(unknown="free", memory_s=10.0, max_speed_m_s=2.0)
    across = np.arange(-8.0, 30.0, 0.1)
    planner.memory.north_east = np.stack([np.full_like(across, 2.0), across], axis=1)
    planner.memory.t_ns = np.full(len(across), S, dtype=np.int64)
    pose = Pose(S, 0.0, 0.0, -2.0, 0.0, 1.8, 0.0)
    decision = planner.decide(S, pose, Goal(20.0, 0.0, 2.0), fresh=True)
    assert decision.state == "moving"
    north_m_s, east_m_s, _ = decision.velocity_ned
    assert north_m_s < -0.5, decision
    assert abs(east_m_s) > 0.5, decision
    assert math.hypot(north_m_s, east_m_s) <= 2.0 + 1e-9


def test_between_two_walls_nearer_than_the_clearance_nothing_pushes_either_way() -> None:
    # A corridor narrower than the clearance: the pushes cancel, the vehicle flies its middle.
    planner = _planner(unknown="free", memory_s=10.0)
    along = np.arange(-5.0, 40.0, 0.1)
    wall = np.stack([along, np.full_like(along, 1.2)], axis=1)
    planner.memory.north_east = np.concatenate([wall, wall * [1.0, -1.0]])
    planner.memory.t_ns = np.full(2 * len(wall), S, dtype=np.int64)
    assert planner.back_away_m_s(Pose(S, 0.0, 0.0, -2.0, 0.0, 1.0, 0.0)) == (0.0, 0.0)


def test_a_gap_that_opens_only_below_walking_pace_slows_the_vehicle_further() -> None:
    # As the 4 m gap above, 3.78 m wide, 4 m ahead (3.72 m across the line through its middle,
    # 10 degrees off): with the buffer at 1 m/s (0.4 m) the clearance (1.9 m each side) does
    # not fit; at 0.5 m/s (0.325 m) it does.
    goal = Goal(30.0, 0.0, 2.0)
    east = np.concatenate([np.arange(-10.0, -3.38, 0.02), np.arange(0.4, 10.0, 0.02)])
    planner = _planner(unknown="free", memory_s=10.0)
    planner.memory.north_east = np.stack([np.full_like(east, 15.0), east], axis=1)
    planner.memory.t_ns = np.full(len(east), S, dtype=np.int64)
    fast = Pose(S, 11.0, -0.8, -2.0, 0.0, 3.0, 0.0)  # the gap's middle 10 degrees left
    decision = planner.decide(S, fast, goal, fresh=True)
    assert decision.state == "moving"
    assert decision.speed_limit_m_s == pytest.approx(0.5, abs=0.01), decision


def test_a_whole_turn_round_a_goal_whose_way_stays_blocked_is_no_path() -> None:
    # The goal inside a closed room (6 m square): the vehicle goes round it 5 m out, the way to
    # the goal blocked all along. Not given up within the first turn; given up after it.
    planner = _planner(unknown="free", memory_s=60.0, no_progress_s=600.0)
    side = np.arange(-3.0, 3.0, 0.05)
    walls = [np.stack([side, np.full_like(side, e)], axis=1) for e in (-3.0, 3.0)]
    walls += [np.stack([np.full_like(side, n), side], axis=1) for n in (-3.0, 3.0)]
    planner.memory.north_east = np.concatenate(walls)
    planner.memory.t_ns = np.full(len(planner.memory.north_east), S, dtype=np.int64)
    goal = Goal(0.0, 0.0, 2.0)
    states = []
    for step in range(80):  # 5 degrees a step
        angle = math.radians(180.0 + 5.0 * step)
        t_ns = S + step * S // 10
        pose = Pose(t_ns, 5.0 * math.cos(angle), 5.0 * math.sin(angle), -2.0, angle + math.pi)
        states.append(planner.decide(t_ns, pose, goal, fresh=True).state)
    assert "no path" not in states[:70], states
    assert states[-1] == "no path", states


def _post_scans(planner: Planner, view_half_bins: int) -> None:
    """Scans from the origin all round (a head seeing +-5 degrees per bin given) of a post
    2.2 m away at 60 degrees, the last one facing north."""
    for step, yaw_deg in enumerate([*range(-180, 180, 30), 0]):
        scan = _scan({}, range(-view_half_bins, view_half_bins + 1))
        post_bin = round((60 - yaw_deg) / 5)
        for i, distance in ((post_bin, 2.2), (post_bin - 1, 2.25), (post_bin + 1, 2.25)):
            if abs(i) <= view_half_bins:
                scan[i % SECTOR_COUNT] = distance
        t = 0.5 + 0.02 * step
        planner.observe_scan(scan, int(t * S), _pose(t, yaw=math.radians(yaw_deg)))


def test_going_round_an_obstacle_a_forward_camera_turns_toward_the_goal_with_the_way_in_view() -> (
    None
):
    planner = _planner()
    _post_scans(planner, 7)  # a forward head of 75 degrees
    goal = Goal(10.0 * math.cos(math.radians(60)), 10.0 * math.sin(math.radians(60)), 2.0)
    decision = planner.decide(int(1.05 * S), _pose(1.05), goal, fresh=True)
    way_rad = math.radians(decision.direction_deg or 0.0)
    assert decision.state == "moving" and abs(math.remainder(way_rad, math.tau)) < math.radians(
        30.0
    )
    # Heading along its way, it turns toward the goal (the post's side) ...
    decision = planner.decide(int(1.10 * S), _pose(1.10, yaw=way_rad), goal, fresh=True)
    assert decision.yaw_rate_rad_s > 0.0
    # ... but never so far that the way leaves the view (37.5 degrees each side, less the
    # corridor the vehicle sweeps, seen from a stop away: 1.5 m at 4.45 m, and a bin).
    turned = _pose(1.15, yaw=way_rad + math.radians(30.0))
    decision = planner.decide(int(1.15 * S), turned, goal, fresh=True)
    assert decision.yaw_rate_rad_s < 0.0
    # The way was seen: little slowing down for the heading (half speed at 90 degrees off).
    assert math.hypot(*decision.velocity_ned[:2]) > 0.95 * planner.config.max_speed_m_s


def test_a_view_all_round_keeps_the_heading_on_the_way() -> None:
    planner = _planner()
    _post_scans(planner, 36)
    goal = Goal(10.0 * math.cos(math.radians(60)), 10.0 * math.sin(math.radians(60)), 2.0)
    decision = planner.decide(int(1.05 * S), _pose(1.05), goal, fresh=True)
    way_rad = math.radians(decision.direction_deg or 0.0)
    decision = planner.decide(int(1.10 * S), _pose(1.10, yaw=way_rad), goal, fresh=True)
    assert decision.yaw_rate_rad_s == pytest.approx(0.0)


def test_flying_along_a_wall_past_a_gap_too_narrow_at_speed_slows_down_and_takes_it() -> None:
    # West at 3 m/s, 2.3 m south of a wall with a 6 m gap (east -5.5 to 0.5) ahead-right; the
    # goal is north, beyond the wall. Slanted as the vehicle sees it, the gap is too narrow
    # for the turning buffer at 3 m/s, not at walking pace: slow down, then turn through it.
    goal = Goal(30.0, 0.0, 2.0)
    gaps = [(-5.5, 0.5)]
    fast = Pose(S, 12.7, 0.0, -2.0, -math.pi / 2, 0.0, -3.0)
    planner = _planner(unknown="free")
    planner.observe_scan(_wall_scan(fast, 15.0, gaps), S, fast)
    passing = planner.decide(S, fast, goal, fresh=True)
    assert passing.state == "moving" and passing.speed_limit_m_s <= 1.0, passing
    slow = Pose(2 * S, 12.7, 0.0, -2.0, -math.pi / 2, 0.0, -1.0)
    planner.observe_scan(_wall_scan(slow, 15.0, gaps), 2 * S, slow)
    through = planner.decide(2 * S, slow, goal, fresh=True)
    crossing_east = 2.3 * math.tan(math.radians(through.direction_deg or 90.0))
    assert -4.0 <= crossing_east <= -1.0, through  # the clearance (1.5 m) from both ends


def test_first_unseen_is_the_near_flank_a_forward_camera_missed() -> None:
    grid = VisibilityGrid()
    # All round seen but the south-west quarter; then a camera of +-37.5 degrees looked west.
    everywhere_but = np.full(SECTOR_COUNT, np.inf, dtype=np.float32)
    everywhere_but[36:48] = np.nan  # bearings 180-235 degrees
    grid.mark((0.0, 0.0), 0.0, everywhere_but, S, 20.0)
    grid.mark((0.0, 0.0), -math.pi / 2, _scan({}, range(-7, 8)), S, 20.0)
    assert grid.first_unseen((0.0, 0.0), 0.0, 1.5, 10.0, 0) is None
    north, east = grid.first_unseen((0.0, 0.0), -math.pi / 2, 1.5, 10.0, 0) or (9.0, 9.0)
    # Beside the vehicle, on the corridor's south flank.
    assert north == pytest.approx(-1.5, abs=0.3) and -2.5 < east < 0.0
    assert math.isfinite(grid.seen_distance((0.0, 0.0), np.array([-math.pi / 2]), 1.5, 10.0, 0)[0])


def _wall_north_2m(scan: np.ndarray, yaw_deg: float) -> np.ndarray:
    """``scan`` (taken at ``yaw_deg``) with the readings of a wall along north = 2 m."""
    for i in range(SECTOR_COUNT):
        cos = math.cos(math.radians(yaw_deg + i * 5.0))
        if not np.isnan(scan[i]) and cos > 0.1:
            scan[i] = min(float(scan[i]), 2.0 / cos)
    return scan


def test_at_a_corridors_turn_the_camera_looks_at_the_near_side_of_the_way_on() -> None:
    planner = _planner()
    # At a corridor's turn, a wall 2 m ahead (north): the vehicle looked all round but at its
    # south-west, and its forward camera (+-20 degrees) looks down the way on to the west (the
    # goal's way), whose south flank lies beside the vehicle, outside that view: that way is
    # open only as far as its corridor was seen (a 30-degree wedge each side right beside the
    # vehicle, the clearance 2.6 m on: that part lies at 240-250 degrees).
    everywhere_but = np.full(SECTOR_COUNT, np.nan, dtype=np.float32)
    everywhere_but[:36] = np.inf
    everywhere_but[50:] = np.inf  # all but bearings 180-247.5 degrees
    planner.observe_scan(_wall_north_2m(everywhere_but, 0.0), int(0.5 * S), _pose(0.5))
    west = -math.pi / 2
    ahead = _wall_north_2m(_scan({}, range(-4, 5)), -90.0)
    planner.observe_scan(ahead, S, _pose(1.0, yaw=west))
    goal = Goal(0.0, -20.0, 2.0)
    decision = planner.decide(int(1.05 * S), _pose(1.05, yaw=west), goal, fresh=True)
    assert decision.free_m is not None and decision.free_m < 2.0, decision
    stop = stopping_speed_m_s(decision.free_m, 2.0, planner.latency_s(int(1.05 * S)))
    assert decision.speed_limit_m_s <= stop + 1e-9
    # The camera turns to that flank (left, toward the south-west), not down the way on.
    assert decision.yaw_rate_rad_s < -0.5
    # Once it has looked there, the way on opens.
    south_west = math.radians(-150.0)
    looked = _wall_north_2m(_scan({}, range(-7, 8)), -150.0)
    planner.observe_scan(looked, int(1.1 * S), _pose(1.1, yaw=south_west))
    decision = planner.decide(int(1.15 * S), _pose(1.15, yaw=south_west), goal, fresh=True)
    assert decision.state == "moving" and decision.direction_deg == pytest.approx(270.0)


def test_a_heads_older_frame_merged_in_after_anothers_newer_one_is_remembered() -> None:
    # Two heads: the front one's frame at 1.00 s is taken in first; the right one's frame,
    # captured at 0.95 s, reaches the merge after it. Its bins are new: they are remembered.
    planner = _planner()
    front = _scan({0: 6.0}, range(-6, 7))
    planner.observe_scan(front, S, _pose(1.0), None, np.full(72, S, dtype=np.int64))
    merged = front.copy()
    merged[18] = 4.0  # the right head's reading, 90 degrees right
    times = np.full(72, S, dtype=np.int64)
    times[15:22] = S - 50_000_000
    planner.observe_scan(merged, S, _pose(1.0), None, times)
    right = np.hypot(*(planner.memory.north_east - [0.0, 4.0]).T)
    assert float(np.min(right)) < 0.1
    # The same merge again adds nothing.
    count = planner.memory.north_east.shape[0]
    planner.observe_scan(merged, S, _pose(1.0), None, times)
    assert planner.memory.north_east.shape[0] == count
