"""The track velocity (fitted to positions) and the planner's drift check against it."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from avoidd.config import AvoidanceConfig, MavlinkConfig
from avoidd.mavlink import codec as mav
from avoidd.mavlink.link import MavLink
from avoidd.mavlink.vehicle import Vehicle
from avoidd.planner.core import (
    Goal,
    Planner,
    Pose,
    away_m_s,
    brake_closing,
    drift_speed_limit_m_s,
    stopping_speed_m_s,
)
from avoidd.planner.track import track_velocity_ne
from avoidd.planner.tuning import DEFAULT, Tuning
from avoidd.types import TrackPoint

S = 1_000_000_000


def _positions(
    rate_hz: float,
    seconds: float,
    velocity: tuple[float, float],
    noise_m: float = 0.0,
    reported: tuple[float, float] | None = None,
) -> list[TrackPoint]:
    """Steady motion; the velocity reported is ``reported`` (default: the true one)."""
    rng = np.random.default_rng(5)
    vn, ve = reported or velocity
    out = []
    for i in range(int(rate_hz * seconds)):
        t_s = i / rate_hz
        n, e = rng.normal(0.0, noise_m, 2) if noise_m else (0.0, 0.0)
        out.append((int(t_s * S), velocity[0] * t_s + n, velocity[1] * t_s + e, vn, ve))
    return out


def test_the_track_velocity_is_how_the_positions_move() -> None:
    assert track_velocity_ne(_positions(50, 2.0, (0.45, 1.44))) == pytest.approx((0.45, 1.44))
    assert track_velocity_ne(_positions(10, 2.0, (-1.0, 0.3))) == pytest.approx((-1.0, 0.3))
    # Centimetre noise on the positions (PX4's estimate) stays within a few cm/s.
    noisy = track_velocity_ne(_positions(50, 2.0, (0.0, 1.5), noise_m=0.01))
    assert noisy is not None and noisy == pytest.approx((0.0, 1.5), abs=0.06)


def test_the_track_is_the_positions_velocity_when_the_reported_one_disagrees() -> None:
    # The estimate says east at 1.5 m/s; the positions move 17 degrees north of it, faster.
    track = track_velocity_ne(_positions(50, 2.0, (0.45, 1.44), reported=(0.0, 1.5)))
    assert track == pytest.approx((0.45, 1.44), abs=1e-6)


def test_the_track_does_not_lag_a_braking_vehicle() -> None:
    # Braking at 3 m/s^2 from 2 m/s, positions and velocities agreeing: the track is the
    # newest velocity, not the window's average (which lags by a quarter of a second).
    reports: list[TrackPoint] = []
    for i in range(30):
        t_s = i / 50
        reports.append((int(t_s * S), 2.0 * t_s - 1.5 * t_s**2, 0.0, 2.0 - 3.0 * t_s, 0.0))
    track = track_velocity_ne(reports)
    assert track is not None and track[0] == pytest.approx(2.0 - 3.0 * 29 / 50, abs=1e-6)


def test_the_track_is_right_through_a_step_in_velocity() -> None:
    # 1.5 m/s east, then a hard turn to 1.5 m/s north between two reports (positions moving
    # as the reports say, trapezoids): the track is the newest reported velocity throughout.
    reports: list[TrackPoint] = []
    north = east = 0.0
    previous = (0.0, 1.5)
    for i in range(40):
        velocity = (0.0, 1.5) if i < 20 else (1.5, 0.0)
        north += (previous[0] + velocity[0]) / 2 / 50
        east += (previous[1] + velocity[1]) / 2 / 50
        previous = velocity
        reports.append((i * S // 50, north, east, *velocity))
        track = track_velocity_ne(reports)
        if track is not None:
            assert track == pytest.approx(velocity, abs=0.03), i


def test_too_few_positions_or_too_short_a_span_give_no_track() -> None:
    assert track_velocity_ne([]) is None
    assert track_velocity_ne(_positions(10, 0.2, (1.0, 0.0))) is None  # 2 positions
    assert track_velocity_ne(_positions(50, 0.2, (1.0, 0.0))) is None  # 0.2 s span
    # A position stream that paused: only the newest one is within the window.
    gap = [*_positions(10, 1.0, (1.0, 0.0)), (3 * S, 3.0, 0.0, 1.0, 0.0)]
    assert track_velocity_ne(gap) is None


def _planner_by_a_wall(
    wall_north_m: float, *, both_sides: bool = False, tuning: Tuning = DEFAULT
) -> Planner:
    """A planner at the origin remembering a wall ``wall_north_m`` to the north."""
    config = {"enabled": True, "max_speed_m_s": 2.0, "unknown": "free"}
    planner = Planner(AvoidanceConfig.model_validate(config), 20.0, tuning)
    east = np.arange(-3.0, 3.01, 0.1)
    points = [np.stack([np.full(east.size, wall_north_m), east], axis=1)]
    if both_sides:
        points.append(np.stack([np.full(east.size, -wall_north_m), east], axis=1))
    planner.memory.north_east = np.concatenate(points)
    planner.memory.t_ns = np.full(planner.memory.north_east.shape[0], S, dtype=np.int64)
    return planner


def _pose(track: tuple[float, float] | None, reported: tuple[float, float] = (0.0, 1.5)) -> Pose:
    # By default the autopilot reports flying east along the wall at 1.5 m/s.
    return Pose(S, 0.0, 0.0, -2.0, math.pi / 2, *reported, track)


def test_drifting_toward_a_wall_flown_along_is_asked_back() -> None:
    planner = _planner_by_a_wall(2.0)
    assert planner.clearance_m + 1.0 > 2.0  # the wall is within the checked band
    # The autopilot reports east at 1.5 m/s, its positions close on the wall at 0.45 m/s:
    # 0.45 less 0.1 of noise is asked away from it, south.
    assert planner.drift_back_m_s(_pose((0.45, 1.44))) == pytest.approx((-0.35, 0.0), abs=1e-6)
    assert planner.drift_back_m_s(_pose((0.75, 1.0))) == pytest.approx((-0.65, 0.0), abs=1e-6)
    # A position that jumps (an estimator reset) asks no more than a back-away at most does.
    assert planner.drift_back_m_s(_pose((5.0, 1.5))) == pytest.approx((-0.75, 0.0), abs=1e-6)


def test_the_drift_is_asked_back_from_a_wall_at_any_angle() -> None:
    # The wall north-east of the vehicle (45 degrees): the correction points south-west.
    planner = _planner_by_a_wall(2.0)
    turn = np.array([[1.0, -1.0], [1.0, 1.0]]) / math.sqrt(2.0)  # 45 degrees clockwise
    planner.memory.north_east = planner.memory.north_east @ turn.T
    back = planner.drift_back_m_s(_pose((0.5, 1.8), reported=(0.0, 1.5)))
    # Closing along the north-east diagonal at (0.5 + 0.3) / sqrt(2), less the noise.
    closing = (0.5 + 0.3) / math.sqrt(2.0) - 0.1
    assert back == pytest.approx((-closing / math.sqrt(2.0), -closing / math.sqrt(2.0)), abs=0.02)


def test_no_drift_correction_without_a_near_one_sided_obstacle_or_a_disagreement() -> None:
    near = _planner_by_a_wall(2.0)
    assert near.drift_back_m_s(_pose(None)) == (0.0, 0.0)  # no track known
    assert near.drift_back_m_s(_pose((-0.3, 1.5))) == (0.0, 0.0)  # drifting away
    assert near.drift_back_m_s(_pose((0.08, 1.5))) == (0.0, 0.0)  # within the noise
    # Closing on the wall as reported (the estimates agree): the speed law and the overspeed
    # brake see that; nothing here.
    assert near.drift_back_m_s(_pose((0.6, 1.5), reported=(0.6, 1.5))) == (0.0, 0.0)
    far = _planner_by_a_wall(near.clearance_m + 1.5)
    assert far.drift_back_m_s(_pose((0.8, 1.5))) == (0.0, 0.0)
    corridor = _planner_by_a_wall(2.0, both_sides=True)
    assert corridor.drift_back_m_s(_pose((0.8, 1.5))) == (0.0, 0.0)


def test_the_drift_correction_only_ever_points_away_from_the_wall() -> None:
    planner = _planner_by_a_wall(2.0)
    rng = np.random.default_rng(11)
    for _ in range(300):
        track = (float(rng.uniform(-2, 2)), float(rng.uniform(-2, 2)))
        reported = (float(rng.uniform(-2, 2)), float(rng.uniform(-2, 2)))
        north, east = planner.drift_back_m_s(_pose(track, reported))
        assert north <= 0.0 and math.hypot(north, east) <= 0.75 + 1e-9


def test_a_planner_drifting_along_a_wall_commands_away_from_it() -> None:
    # The whole decision: flying east to a goal along a wall 2 m north, the positions closing
    # on it at 0.5 m/s that the reports do not show: the setpoint leans south by the drift.
    goal = Goal(0.0, 30.0, 2.0)
    agreeing = _planner_by_a_wall(2.0).decide(S, _pose((0.0, 1.5)), goal, fresh=True)
    drifting = _planner_by_a_wall(2.0).decide(S, _pose((0.5, 1.5)), goal, fresh=True)
    assert agreeing.state == drifting.state == "moving"
    lean = drifting.velocity_ned[0] - agreeing.velocity_ned[0]
    assert lean == pytest.approx(-0.4, abs=0.05)
    assert math.hypot(*drifting.velocity_ned[:2]) <= 2.0 + 1e-9


def test_drifting_toward_a_wall_slows_the_vehicle_along_it() -> None:
    goal = Goal(0.0, 30.0, 2.0)
    agreeing = _planner_by_a_wall(2.0).decide(S, _pose((0.0, 1.5)), goal, fresh=True)
    drifting = _planner_by_a_wall(2.0).decide(S, _pose((0.5, 1.5)), goal, fresh=True)
    # Along the wall (east): the full 2 m/s without drift; with 0.4 m/s of drift asked back,
    # 2 * (1 - 0.5 * 0.4 / 0.75).
    assert agreeing.velocity_ned[1] == pytest.approx(2.0, abs=1e-6)
    assert drifting.velocity_ned[1] == pytest.approx(2.0 * (1.0 - 0.5 * 0.4 / 0.75), abs=0.01)
    # The same drift with no wall near: nothing to drift into, no slowing.
    open_planner = _planner_by_a_wall(20.0)
    free = open_planner.decide(S, _pose((0.5, 1.5)), goal, fresh=True)
    assert free.velocity_ned[1] == pytest.approx(2.0, abs=1e-6)


def test_closing_on_a_wall_flown_along_faster_than_the_plan_is_asked_back() -> None:
    # The autopilot's own report says it closes on the wall 2 m north at 0.4 m/s (its
    # positions agree, so this is no drift) while the plan flies east along it: 0.4 less 0.1
    # of noise is asked back, south.
    goal = Goal(0.0, 30.0, 2.0)
    following = _planner_by_a_wall(2.0).decide(S, _pose((0.0, 1.5)), goal, fresh=True)
    closing = _planner_by_a_wall(2.0).decide(
        S, _pose((0.4, 1.5), reported=(0.4, 1.5)), goal, fresh=True
    )
    assert following.state == closing.state == "moving"
    lean = closing.velocity_ned[0] - following.velocity_ned[0]
    assert lean == pytest.approx(-0.3, abs=0.02)
    assert math.hypot(*closing.velocity_ned[:2]) <= 2.0 + 1e-9
    # No wall near: the same sideways speed is the autopilot's business.
    free = _planner_by_a_wall(20.0).decide(
        S, _pose((0.4, 1.5), reported=(0.4, 1.5)), goal, fresh=True
    )
    assert free.velocity_ned[0] == pytest.approx(following.velocity_ned[0], abs=1e-6)


def test_the_closing_brake_asks_only_the_excess_and_only_away() -> None:
    north = 0.0  # the near side's bearing: the wall is north
    pose = Pose(S, 0.0, 0.0, -2.0, 0.0, 0.5, 1.0)  # closing at 0.5 m/s
    # The plan wants 0.5 m/s that way (approaching, slowed by the speed law): no excess; at
    # 0.3 the 0.2 is the lag of braking (within the overspeed brake's 0.25 slack).
    assert brake_closing((0.5, 1.0), (0.5, 1.0), pose, north, 2.0) == (0.5, 1.0)
    assert brake_closing((0.3, 1.0), (0.3, 1.0), pose, north, 2.0) == (0.3, 1.0)
    # Along the wall: 0.5 too fast that way, less 0.1 of noise.
    assert brake_closing((0.0, 1.0), (0.0, 1.0), pose, north, 2.0) == pytest.approx((-0.4, 1.0))
    # In between the slack grows with the speed wanted: 0.2 wanted, slack 0.1 + 0.8 * 0.15.
    assert brake_closing((0.2, 1.0), (0.2, 1.0), pose, north, 2.0) == pytest.approx((0.12, 1.0))
    # What an earlier brake already asks back that way counts.
    assert brake_closing((-0.4, 1.0), (0.0, 1.0), pose, north, 2.0) == (-0.4, 1.0)
    # Moving away, or within the noise: nothing.
    away = Pose(S, 0.0, 0.0, -2.0, 0.0, -0.5, 1.0)
    assert brake_closing((0.0, 1.0), (0.0, 1.0), away, north, 2.0) == (0.0, 1.0)
    slow = Pose(S, 0.0, 0.0, -2.0, 0.0, 0.08, 1.0)
    assert brake_closing((0.0, 1.0), (0.0, 1.0), slow, north, 2.0) == (0.0, 1.0)
    rng = np.random.default_rng(3)
    for _ in range(300):
        side = float(rng.uniform(-math.pi, math.pi))
        unit = np.array((math.cos(side), math.sin(side)))
        plan = (float(rng.uniform(-1.5, 1.5)), float(rng.uniform(-1.5, 1.5)))
        vehicle = Pose(S, 0.0, 0.0, -2.0, 0.0, float(rng.uniform(-2, 2)), float(rng.uniform(-2, 2)))
        command = brake_closing(plan, plan, vehicle, side, 2.0)
        # Never more toward the side than the plan, never beyond the maximum speed.
        assert float(np.array(command) @ unit) <= float(np.array(plan) @ unit) + 1e-9
        assert math.hypot(*command) <= max(2.0, math.hypot(*plan)) + 1e-9


def test_the_drift_speed_limit_falls_with_the_drift_to_a_floor() -> None:
    assert drift_speed_limit_m_s(0.0, 2.0) == 2.0
    limits = [drift_speed_limit_m_s(d, 2.0) for d in np.linspace(0.0, 3.0, 61)]
    assert bool(np.all(np.diff(limits) <= 0.0))
    assert min(limits) == pytest.approx(1.0)  # half the maximum speed at most
    assert drift_speed_limit_m_s(0.75, 1.2) == pytest.approx(0.6)


def test_holds_ask_a_drift_toward_a_near_wall_back() -> None:
    # Held on stale frames, dead-ended or stuck, the positions closing on the wall at 0.5
    # m/s while the autopilot reports standing still: 0.4 m/s asked south, nothing east.
    still = _pose((0.5, 0.0), reported=(0.0, 0.0))
    goal = Goal(0.0, 30.0, 2.0)
    stale = _planner_by_a_wall(2.0).decide(S, still, goal, fresh=False)
    assert stale.state == "stale"
    assert stale.velocity_ned[:2] == pytest.approx((-0.4, 0.0), abs=1e-6)
    assert _planner_by_a_wall(2.0).hold("stale", 30.0, still).velocity_ned[:2] == (
        pytest.approx((-0.4, 0.0), abs=1e-6)
    )
    # No pose (no position heard) or no disagreement: a plain zero.
    assert _planner_by_a_wall(2.0).hold("no position").velocity_ned == (0.0, 0.0, 0.0)
    agreeing = _pose((0.0, 0.0), reported=(0.0, 0.0))
    assert _planner_by_a_wall(2.0).hold("stale", 30.0, agreeing).holding
    # At the goal, beside the wall: the same correction.
    arrived = _planner_by_a_wall(2.0).decide(S, still, Goal(0.0, 0.5, 2.0), fresh=True)
    assert arrived.state == "arrived"
    assert arrived.velocity_ned[:2] == pytest.approx((-0.4, 0.0), abs=1e-6)


def test_a_hold_asks_no_drift_back_for_a_jump_nor_beyond_a_stop_or_the_maximum_speed() -> None:
    planner = _planner_by_a_wall(2.0)
    # 5 m/s of disagreement is a position reset fitted as a speed: nothing is sent for it.
    assert planner.hold("stale", 30.0, _pose((5.0, 0.0), reported=(0.0, 0.0))).holding
    # A maximum speed below the correction bounds it.
    slow = Planner(
        AvoidanceConfig.model_validate({"enabled": True, "max_speed_m_s": 0.3, "unknown": "free"}),
        20.0,
    )
    slow.memory.north_east = planner.memory.north_east.copy()
    slow.memory.t_ns = planner.memory.t_ns.copy()
    held = slow.hold("stale", 30.0, _pose((0.5, 0.0), reported=(0.0, 0.0)))
    assert held.velocity_ned[:2] == pytest.approx((-0.3, 0.0), abs=1e-6)
    # Something behind (beyond the drift band: the wall ahead stays one-sided) and frames
    # 3 s old: no faster than a stop short of it within the speed law's longer delay.
    behind = _planner_by_a_wall(2.0)
    east = np.arange(-3.0, 3.01, 0.1)
    wall_south = np.stack([np.full(east.size, -(behind.clearance_m + 1.2)), east], axis=1)
    behind.memory.north_east = np.concatenate([behind.memory.north_east, wall_south])
    behind.memory.t_ns = np.full(behind.memory.north_east.shape[0], 3 * S, dtype=np.int64)
    behind._last_scan_ns = 1 * S  # the newest scan was taken 3 s before the hold
    pose = Pose(4 * S, 0.0, 0.0, -2.0, math.pi / 2, 0.0, 0.0, (0.5, 0.0))
    assert behind.drift_back_m_s(pose) == pytest.approx((-0.4, 0.0), abs=1e-6)  # one-sided
    free_m = float(behind.free_m(pose, np.array([math.pi]))[0])
    stop = stopping_speed_m_s(free_m, behind.config.max_accel_m_s2, behind.latency_s(4 * S))
    assert 0.0 < stop < 0.4
    held = behind.hold("stale", 30.0, pose)
    assert held.velocity_ned[:2] == pytest.approx((-stop, 0.0), abs=1e-3)


def test_the_vehicle_keeps_the_reported_positions_for_the_track() -> None:
    config = MavlinkConfig(connection="udpout:127.0.0.1:9")
    link = MavLink(config.link, mav.Codec(1, 196))
    vehicle = Vehicle(link, config, lambda severity, text, key=None: None)
    sender = mav.Codec(1, 1)

    base_ns = time.monotonic_ns()

    def feed(message: mav.Message, t_ms: int = 0) -> None:
        # Received as it was sent: the autopilot's clock runs with avoidd's.
        for decoded in link.codec.decode(sender.pack(message)):
            vehicle.handle(decoded, base_ns + t_ms * 1_000_000)

    feed(sender.build("HEARTBEAT", 2, mav.MAV_AUTOPILOT_PX4, 1, 0, 4))
    # 20 Hz for 1 s: the estimate reports east at 1.5 m/s, the positions also move north.
    for i in range(20):
        t_ms = 5000 + 50 * i
        north, east = 0.45 * i / 20, 1.44 * i / 20
        feed(sender.build("LOCAL_POSITION_NED", t_ms, north, east, -2.0, 0.0, 1.5, 0.0), t_ms)
    assert len(vehicle.positions) == 20
    assert track_velocity_ne(vehicle.positions.reports) == pytest.approx((0.45, 1.44), abs=1e-3)
    # A repeat of the newest report adds nothing; a clock far back (a reboot) starts over.
    feed(sender.build("LOCAL_POSITION_NED", 5950, 0.0, 0.0, -2.0, 0.0, 1.5, 0.0), 5960)
    assert len(vehicle.positions) == 20
    feed(sender.build("LOCAL_POSITION_NED", 100, 0.0, 0.0, -2.0, 0.0, 1.5, 0.0), 6000)
    assert len(vehicle.positions) == 1 and track_velocity_ne(vehicle.positions.reports) is None


def test_braking_to_turn_back_never_pushes_toward_a_wall_it_backs_away_from() -> None:
    # Backing away south-west at 0.85 m/s from a wall 1.4 m north (inside the clearance),
    # the vehicle is told to go east (the goal's way): that turns it back on itself, so it
    # brakes first. The brake may not point north, toward the wall, and the back-away stays.
    planner = _planner_by_a_wall(1.4)
    inside = planner.clearance_m - 1.4
    assert inside > 0.1
    pose = Pose(S, 0.0, 0.0, -2.0, 0.0, -0.6, -0.6, (-0.6, -0.6))
    backing = planner.back_away_m_s(pose)
    assert backing[0] < 0.0
    decision = planner.decide(S, pose, Goal(-0.5, 30.0, 2.0), fresh=True)
    assert decision.state == "moving"
    assert decision.velocity_ned[0] <= backing[0] + 1e-9, decision


def test_braking_to_turn_back_head_on_inside_the_clearance_keeps_the_whole_brake() -> None:
    # Flying north at 1.5 m/s at a wall 1.4 m ahead (inside the clearance), told to go back
    # south-east (the goal's way): it brakes first. The brake asks the speed back less the
    # 0.25 m/s slack, and the back-away comes on top; neither cancels the other.
    planner = _planner_by_a_wall(1.4)
    pose = Pose(S, 0.0, 0.0, -2.0, 0.0, 1.5, 0.0, (1.5, 0.0))
    backing = planner.back_away_m_s(pose)
    assert backing[0] < 0.0
    decision = planner.decide(S, pose, Goal(-30.0, 5.0, 2.0), fresh=True)
    assert decision.state == "moving" and decision.direction_deg is None
    assert decision.velocity_ned[0] <= -(1.5 - 0.25) + backing[0] + 1e-9, decision
    assert decision.velocity_ned[1] == pytest.approx(0.0, abs=1e-9)


def test_holds_inside_the_clearance_back_away_and_add_the_drift_correction() -> None:
    # PX4 SITL under load: holds on frames just over max_age_ms flickered with moves, and
    # holds that sent only the drift correction halved the back-away PX4 saw (edge 1.1 m ->
    # 0.35 m). Inside the clearance a hold backs away as a move does.
    probe = _planner_by_a_wall(2.0)
    wall_m = probe.clearance_m - 0.3  # 0.25 m inside, beyond the 5 cm slack
    expected_back = min(0.75, 2.0 * 0.25)
    for state in ("stale", "no path", "dead end"):
        planner = _planner_by_a_wall(wall_m)
        # No track known: the back-away alone.
        held = planner.hold(state, 30.0, _pose(None, reported=(0.0, 0.0)))
        assert held.velocity_ned[:2] == pytest.approx((-expected_back, 0.0), abs=1e-6)
        assert held.yaw_rate_rad_s == 0.0
        # Positions closing at 0.5 m/s, reported still: both, added.
        drifting = planner.hold(state, 30.0, _pose((0.5, 0.0), reported=(0.0, 0.0)))
        assert drifting.velocity_ned[:2] == pytest.approx((-expected_back - 0.4, 0.0), abs=1e-6)
    # A stale decision holds the same way.
    stale = _planner_by_a_wall(wall_m).decide(
        S, _pose(None, reported=(0.0, 0.0)), Goal(0.0, 30.0, 2.0), fresh=False
    )
    assert stale.state == "stale"
    assert stale.velocity_ned[:2] == pytest.approx((-expected_back, 0.0), abs=1e-6)
    # Walls on both sides nearer than the clearance (a corridor): no side to back away
    # from, and nothing is sent either way.
    corridor = _planner_by_a_wall(wall_m, both_sides=True)
    assert corridor.hold("stale", 30.0, _pose(None, reported=(0.0, 0.0))).velocity_ned == (
        0.0,
        0.0,
        0.0,
    )
    # Outside the clearance (the wall 2 m away) and no drift: a plain zero, as before.
    assert _planner_by_a_wall(2.0).hold("stale", 30.0, _pose(None, reported=(0.0, 0.0))).holding


def test_a_dead_end_backs_away_and_an_arrival_beside_a_wall_stays() -> None:
    probe = _planner_by_a_wall(2.0)
    wall_m = probe.clearance_m - 0.3  # 0.25 m inside
    still = _pose(None, reported=(0.0, 0.0))
    # Dead-ended inside the clearance: it turns to look and backs away meanwhile.
    planner = _planner_by_a_wall(wall_m)
    looking = planner._look_around(S, still, 30.0, 0.0)
    assert looking.state == "dead end"
    assert looking.velocity_ned[:2] == pytest.approx((-0.5, 0.0), abs=1e-6)
    # Arrived at a goal within the clearance of the wall: it stays (backing out of the
    # acceptance radius would start the flight again), and only a drift is asked back.
    goal = Goal(wall_m - 0.4, 0.0, 2.0)
    arrived = _planner_by_a_wall(wall_m).decide(S, still, goal, fresh=True)
    assert arrived.state == "arrived" and arrived.holding
    drifting = _pose((0.5, 0.0), reported=(0.0, 0.0))
    arrived = _planner_by_a_wall(wall_m).decide(S, drifting, goal, fresh=True)
    assert arrived.state == "arrived"
    assert arrived.velocity_ned[:2] == pytest.approx((-0.4, 0.0), abs=1e-6)


def test_no_part_of_the_drift_correction_goes_against_the_back_away() -> None:
    # Against it: dropped. Across it: kept. With it, or with no back-away: added whole.
    assert away_m_s((-0.1, 0.0), (0.5, 0.0)) == pytest.approx((-0.1, 0.0))
    assert away_m_s((-0.5, 0.0), (0.2, 0.3)) == pytest.approx((-0.5, 0.3))
    assert away_m_s((-0.5, 0.0), (-0.2, 0.3)) == pytest.approx((-0.7, 0.3))
    assert away_m_s((0.0, 0.0), (0.3, -0.1)) == pytest.approx((0.3, -0.1))
    rng = np.random.default_rng(11)
    for _ in range(300):
        back = tuple(rng.uniform(-0.75, 0.75, 2))
        drift = tuple(rng.uniform(-0.75, 0.75, 2))
        north, east = away_m_s(back, drift)
        # Never less away from what is too near than the back-away alone.
        assert north * back[0] + east * back[1] >= back[0] ** 2 + back[1] ** 2 - 1e-9


def test_a_hold_between_a_pole_inside_the_clearance_and_a_wall_it_drifts_toward() -> None:
    # A pole just inside the clearance to the north, a long wall within the drift band to
    # the south, the positions drifting south at 0.6 m/s: the drift correction points north,
    # at the pole. The hold backs away from the pole and asks nothing toward it.
    planner = _planner_by_a_wall(2.0)
    clearance = planner.clearance_m
    pole = np.array([[clearance - 0.1, 0.0]])  # a thin pole: one point
    east = np.arange(-6.0, 6.01, 0.1)
    wall = np.stack([np.full(east.size, -(clearance + 0.5)), east], axis=1)
    planner.memory.north_east = np.concatenate([pole, wall])
    planner.memory.t_ns = np.full(planner.memory.north_east.shape[0], S, dtype=np.int64)
    pose = _pose((-0.6, 0.0), reported=(0.0, 0.0))
    backing = planner.back_away_m_s(pose)
    drifting = planner.drift_back_m_s(pose)
    assert backing[0] < 0.0 < drifting[0]  # away from the pole; the drift's toward it
    held = planner.hold("stale", 30.0, pose)
    assert held.velocity_ned[:2] == pytest.approx(backing, abs=1e-6)


def test_a_hold_backs_away_into_ground_the_cameras_have_not_seen() -> None:
    # `unknown: blocked` (the default) closes planned moves toward ground not looked at. The
    # way out of a wall's clearance is behind the cameras, seldom seen: a hold that checked
    # it against that sent zero (PX4 SITL under load: a dead-end hold for three seconds while
    # the positions closed on the wall at 0.4-0.5 m/s, into it).
    config = AvoidanceConfig.model_validate({"enabled": True, "max_speed_m_s": 2.0})
    assert config.unknown == "blocked"
    planner = Planner(config, 20.0)
    wall_m = planner.clearance_m - 0.3  # 0.25 m inside
    east = np.arange(-3.0, 3.01, 0.1)
    planner.memory.north_east = np.stack([np.full(east.size, wall_m), east], axis=1)
    planner.memory.t_ns = np.full(east.size, S, dtype=np.int64)
    still = Pose(S, 0.0, 0.0, -2.0, 0.0, 0.0, 0.0, None)
    # Nothing has been seen behind: a planned move that way would be blocked...
    assert planner.free_m(still, np.array([math.pi]))[0] == 0.0
    # ... but the holds back away (0.25 m inside: 0.5 m/s).
    for state in ("stale", "no path"):
        assert planner.hold(state, 30.0, still).velocity_ned[:2] == pytest.approx(
            (-0.5, 0.0), abs=1e-6
        )
    looking = planner._look_around(S, still, 30.0, 0.0)
    assert looking.velocity_ned[:2] == pytest.approx((-0.5, 0.0), abs=1e-6)
    # With a drift toward the wall the 0.4 m/s asked back adds to it, but into unseen ground
    # no faster than a back-away at most: 0.9 asked, 0.75 sent.
    drifting = Pose(S, 0.0, 0.0, -2.0, 0.0, 0.0, 0.0, (0.5, 0.0))
    assert planner.hold("stale", 30.0, drifting).velocity_ned[:2] == pytest.approx(
        (-0.75, 0.0), abs=1e-6
    )
    # A remembered wall behind, 0.3 m beyond the clearance (0.65 m of room), still limits it:
    # with the newest scan 2 s old, no faster than a stop before that wall allows.
    behind = np.stack([np.full(east.size, -(planner.clearance_m + 0.3)), east], axis=1)
    planner.memory.north_east = np.concatenate([planner.memory.north_east, behind])
    planner.memory.t_ns = np.full(planner.memory.north_east.shape[0], S, dtype=np.int64)
    planner._last_scan_ns = S
    later = Pose(3 * S, 0.0, 0.0, -2.0, 0.0, 0.0, 0.0, None)
    room_m = float(planner.obstacle_free_m(later, np.array([math.pi]))[0])
    assert room_m == pytest.approx(0.65, abs=1e-6)
    stop_m_s = stopping_speed_m_s(room_m, config.max_accel_m_s2, planner.latency_s(3 * S))
    assert stop_m_s < 0.5
    limited = planner.hold("stale", 30.0, later).velocity_ned[:2]
    assert limited == pytest.approx((-stop_m_s, 0.0), abs=1e-6)


def test_the_back_away_grows_while_the_vehicle_stays_inside_and_fades_outside() -> None:
    wall_m = _planner_by_a_wall(2.0).clearance_m - 0.15  # 0.10 m inside, beyond the 5 cm slack
    planner = _planner_by_a_wall(wall_m)

    def back(t_s: float, north_m: float = 0.0) -> float:
        pose = Pose(int(t_s * S), north_m, 0.0, -2.0, 0.0, 0.0, 0.0, None)
        north, east = planner.back_away_m_s(pose)
        assert east == pytest.approx(0.0, abs=1e-9)
        return -north

    assert back(1.0) == pytest.approx(0.2, abs=1e-6)  # the depth's part alone at first
    for i in range(1, 11):
        back(1.0 + 0.1 * i)
    # A second 0.10 m inside: 2 m/s per metre-second more.
    grown = 2.0 * 0.10 * 1.0
    assert back(2.0) == pytest.approx(0.2 + grown, abs=1e-6)
    # One position time grows it once, and an older one changes nothing.
    assert back(2.0) == pytest.approx(0.2 + grown, abs=1e-6)
    assert back(1.95) == pytest.approx(0.2 + grown, abs=1e-6)
    assert back(2.0) == pytest.approx(0.2 + grown, abs=1e-6)
    # A gap of 0.6 s between positions counts 0.25 s at most.
    grown += 2.0 * 0.10 * 0.25
    assert back(2.6) == pytest.approx(0.2 + grown, abs=1e-6)
    # Within the 5 cm slack (0.03 m inside) the depth's part is gone, the growth stays whole.
    assert back(2.7, north_m=-0.12) == pytest.approx(grown, abs=1e-6)
    for i in range(1, 101):
        back(2.7 + 0.1 * i)
    assert back(12.7) == pytest.approx(0.75)  # never beyond the back-away's most
    # Outside the clearance nothing is sent and the growth fades (1 s time constant), over
    # the whole time that passed ...
    assert back(13.0, north_m=-0.5) == 0.0
    assert back(13.9, north_m=-0.5) == 0.0
    # ... so that back just inside it (within the slack: no depth part) is what is left.
    assert back(14.0, north_m=-0.12) == pytest.approx(0.75 * math.exp(-1.2), abs=1e-6)
    # A pause in positions (over a second) starts it from nothing.
    assert back(20.0) == pytest.approx(0.2, abs=1e-6)


def test_the_back_away_grown_against_one_side_never_pushes_toward_another() -> None:
    wall_m = _planner_by_a_wall(2.0).clearance_m - 0.15  # 0.10 m inside
    planner = _planner_by_a_wall(wall_m)
    north_wall = planner.memory.north_east.copy()

    def back(t_s: float) -> tuple[float, float]:
        return planner.back_away_m_s(Pose(int(t_s * S), 0.0, 0.0, -2.0, 0.0, 0.0, 0.0, None))

    for i in range(21):
        back(1.0 + 0.1 * i)
    assert back(3.0)[0] == pytest.approx(-(0.2 + 2.0 * 0.10 * 2.0), abs=1e-6)
    # The same depth inside the clearance of a wall to the south instead: the speed north
    # away from it is the depth's alone (the growth pointed south, at it).
    planner.memory.north_east = north_wall * [-1.0, 1.0]
    assert back(3.1) == pytest.approx((0.2, 0.0), abs=1e-6)
    # Inside a corridor narrower than the clearance there is no one side: nothing is sent and
    # the growth is dropped, so back at the north wall only the depth counts.
    planner.memory.north_east = np.concatenate([north_wall, north_wall * [-1.0, 1.0]])
    planner.memory.t_ns = np.full(planner.memory.north_east.shape[0], S, dtype=np.int64)
    assert back(3.2) == (0.0, 0.0)
    planner.memory.north_east = north_wall
    planner.memory.t_ns = planner.memory.t_ns[: north_wall.shape[0]]
    assert back(3.2) == pytest.approx((-0.2, 0.0), abs=1e-6)


def _slide_along_the_wall(planner: Planner, wall_m: float) -> tuple[list[float], list[float]]:
    """Depths inside the clearance and speeds asked away of a vehicle sliding along a wall.

    For 8 s the autopilot follows the correction sideways at 65 % after a 0.3 s lag, and its
    positions drift 0.5 m/s toward the wall beyond what it reports (PX4 SITL along the
    wall's end).
    """
    north_m, reported_n = 0.0, 0.0
    depths, away = [], []
    for i in range(80):
        t_ns = S + i * S // 10
        pose = Pose(t_ns, north_m, 0.0, -2.0, math.pi / 2, reported_n, 1.5, (reported_n + 0.5, 1.5))
        north, _ = away_m_s(planner.back_away_m_s(pose), planner.drift_back_m_s(pose))
        away.append(-north)
        reported_n += (0.65 * north - reported_n) * 0.1 / 0.3
        north_m += (reported_n + 0.5) * 0.1
        depths.append(planner.clearance_m - (wall_m - north_m))
    return depths, away


def test_the_growing_back_away_settles_a_partly_following_vehicle_at_the_clearance() -> None:
    wall_m = _planner_by_a_wall(2.0).clearance_m - 0.1
    settled, away = _slide_along_the_wall(_planner_by_a_wall(wall_m), wall_m)
    # The depth alone balances the drift about 0.2 m inside (as PX4 SITL did, edge 0.83 m);
    # with the growth the vehicle comes back to within a few cm of the clearance ...
    assert max(settled[-20:]) < 0.08, settled[-20:]
    assert max(settled) < 0.25
    # ... and stays there asking a steady speed away, not one that drops out and back.
    assert max(away[-30:]) - min(away[-30:]) < 0.05, away[-30:]
    no_growth = Tuning(back_away_growth_per_s2=0.0)
    depth_only, _ = _slide_along_the_wall(_planner_by_a_wall(wall_m, tuning=no_growth), wall_m)
    assert min(depth_only[-20:]) > 0.15, depth_only[-20:]
