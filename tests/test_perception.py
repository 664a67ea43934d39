"""Frames, ground model, the paper's geometry, the temporal filter and pose resolution."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from avoidd.config import (
    BandConfig,
    GroundConfig,
    HistogramConfig,
    PerceptionConfig,
    SectorsConfig,
    TemporalConfig,
)
from avoidd.mavlink.attitude import Attitude
from avoidd.mavlink.vehicle import LocalPosition, Rangefinder
from avoidd.perception.frames import (
    body_to_level,
    camera_to_body,
    camera_to_level,
    depth_to_frame,
    mount_quaternion,
    rotation_zyx,
)
from avoidd.perception.geometry import (
    ground_range,
    tilt_from_ground_point,
    tilt_from_horizon,
)
from avoidd.perception.ground import fit_plane, height_from_rangefinder, obstacle_points
from avoidd.perception.obstacles import cluster_obstacles
from avoidd.perception.pose import resolve_pose
from avoidd.perception.temporal import SectorFilter
from avoidd.sources.scene import Scene, render_pair
from avoidd.types import FramePose, Mount, RectifiedRig, SectorScan

RIG = RectifiedRig(640, 480, 400.0, 400.0, 319.5, 239.5, 0.12)
CONFIG = PerceptionConfig()


# --- frames -----------------------------------------------------------------------------------


def test_mount_rotations_follow_frd_conventions() -> None:
    # The optical axis of a head yawed 90 degrees points along body right.
    assert camera_to_body(Mount(yaw_deg=90.0)).apply([0.0, 0.0, 1.0]) == pytest.approx(
        [0.0, 1.0, 0.0], abs=1e-12
    )
    # Pitched up 30 degrees, it points forward and up (negative down).
    axis = camera_to_body(Mount(pitch_deg=30.0)).apply([0.0, 0.0, 1.0])
    assert axis == pytest.approx([math.cos(math.radians(30)), 0.0, -0.5], abs=1e-12)
    # Rolled right side down, the camera's right (x) axis points down a little.
    right = camera_to_body(Mount(roll_deg=10.0)).apply([1.0, 0.0, 0.0])
    assert right[2] == pytest.approx(math.sin(math.radians(10.0)))
    # A nose-up vehicle sees a point ahead in its body frame above the level forward axis.
    ahead = body_to_level(0.0, 15.0).apply([10.0, 0.0, 0.0])
    assert ahead[2] == pytest.approx(-10.0 * math.sin(math.radians(15.0)))
    # Position is added in the body frame, then turned with the attitude.
    pose = camera_to_level(Mount(position_m=(0.2, 0.0, 0.1)), 0.0, 0.0)
    assert pose.translation == pytest.approx([0.2, 0.0, 0.1])


@settings(max_examples=50, deadline=None)
@given(
    st.floats(-180, 180),
    st.floats(-80, 80),
    st.floats(-80, 80),
    st.floats(-30, 30),
    st.floats(-30, 30),
)
def test_depth_to_frame_equals_the_matrix_product(
    yaw: float, pitch: float, roll: float, v_roll: float, v_pitch: float
) -> None:
    rig = RectifiedRig(16, 12, 20.0, 21.0, 7.5, 5.5, 0.1)
    depth = np.random.default_rng(0).uniform(0.5, 30.0, (12, 16)).astype(np.float32)
    depth[3, 4] = np.nan
    pose = camera_to_level(Mount(yaw, pitch, roll, (0.1, -0.2, 0.3)), v_roll, v_pitch)
    fast = depth_to_frame(depth, rig, pose)
    v, u = np.mgrid[0:12, 0:16]
    optical = np.stack([(u - 7.5) / 20.0 * depth, (v - 5.5) / 21.0 * depth, depth], axis=-1)
    exact = pose.apply(optical.reshape(-1, 3)).reshape(12, 16, 3)
    for index, component in enumerate(fast):
        assert np.allclose(component, exact[..., index], atol=1e-3, equal_nan=True)
    assert np.isnan(fast.down_m[3, 4])


@pytest.mark.parametrize("yaw", [0.0, 45.0, 90.0, -135.0, 180.0])
@pytest.mark.parametrize("pitch", [0.0, -30.0])
def test_mount_quaternion_turns_the_x_axis_onto_the_camera_axis(yaw: float, pitch: float) -> None:
    w, x, y, z = mount_quaternion(Mount(yaw_deg=yaw, pitch_deg=pitch))
    assert w * w + x * x + y * y + z * z == pytest.approx(1.0)
    # Rotate (1, 0, 0) by the quaternion.
    rotated = np.array(
        [1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)], dtype=np.float64
    )
    assert rotated == pytest.approx(rotation_zyx(yaw, pitch, 0.0)[:, 0], abs=1e-6)


# --- the paper's geometry ---------------------------------------------------------------------


@settings(max_examples=200, deadline=None)
@given(
    st.floats(0.3, 50.0),
    st.floats(0.5, 60.0),
    st.floats(-300.0, 300.0),
    st.floats(-200.0, 200.0),
)
def test_ground_range_matches_a_ray_plane_intersection(
    height: float, tilt_deg: float, dx: float, dy: float
) -> None:
    f = 400.0
    tilt = math.radians(tilt_deg)
    result = ground_range(height, tilt, dx, dy, f)
    # Ray of the pixel in the optical frame (y down), turned down by the tilt.
    ray = np.array([dx / f, -dy / f, 1.0])
    c, s = math.cos(tilt), math.sin(tilt)
    forward = ray[2] * c - ray[1] * s
    down = ray[2] * s + ray[1] * c
    if down <= 1e-9:
        assert result is None
        return
    assert result is not None
    t = height / down  # ray parameter = optical depth
    assert result.depth_m == pytest.approx(t, rel=1e-9)
    assert result.forward_m == pytest.approx(t * forward, rel=1e-9)
    assert result.lateral_m == pytest.approx(t * ray[0], rel=1e-9, abs=1e-12)
    assert result.range_m == pytest.approx(math.hypot(t * forward, t * ray[0]), rel=1e-9)


def test_tilt_from_h_over_op_and_from_the_horizon() -> None:
    tilt = tilt_from_ground_point(1.5, 6.0)
    assert tilt == pytest.approx(math.atan(0.25))
    # The optical axis then meets the ground exactly at OP.
    axis = ground_range(1.5, tilt, 0.0, 0.0, 400.0)
    assert axis is not None and axis.forward_m == pytest.approx(6.0)
    # The horizon lies f * tan(delta) above the principal point; its ray never lands.
    dy_horizon = 400.0 * math.tan(tilt)
    assert tilt_from_horizon(dy_horizon, 400.0) == pytest.approx(tilt)
    assert ground_range(1.5, tilt, 0.0, dy_horizon, 400.0) is None
    with pytest.raises(ValueError, match="positive"):
        tilt_from_ground_point(0.0, 6.0)


def test_target_of_known_height_by_substituting_the_height_difference() -> None:
    # A point 0.5 m above the ground seen by a camera 1.5 m up is ranged with h = 1.0.
    f, tilt = 400.0, math.radians(10.0)
    depth, height_above = 7.0, 0.5
    # Where does that point appear? Its ray descends by (1.5 - 0.5) over its horizontal run.
    descent = math.atan2(1.0, depth)  # for a point straight ahead at 7 m forward
    alpha = tilt - descent
    dy = f * math.tan(alpha)
    result = ground_range(1.5 - height_above, tilt, 0.0, dy, f)
    assert result is not None and result.forward_m == pytest.approx(7.0)


def test_geometry_agrees_with_rendered_truth_on_ground_pixels() -> None:
    scene = Scene(1.5, -12.0, (), None, 3)
    truth = render_pair(scene, RIG).truth
    tilt = math.radians(12.0)
    for v, u in [(300, 100), (400, 320), (479, 600), (260, 500)]:
        assert truth.object_id[v, u] == 1
        result = ground_range(1.5, tilt, u - RIG.cx, RIG.cy - v, RIG.fx)
        assert result is not None
        assert result.depth_m == pytest.approx(float(truth.depth_m[v, u]), rel=1e-4)
        assert result.lateral_m == pytest.approx(float(truth.points_m[v, u, 1]), rel=1e-4)


# --- ground model -----------------------------------------------------------------------------


def _kept(
    depth: np.ndarray, height_m: float, ground: GroundConfig, band: BandConfig, max_range_m: float
) -> np.ndarray:
    """The obstacle mask of a level camera at the body origin."""
    points = obstacle_points(
        depth, RIG, camera_to_level(Mount(), 0.0, 0.0), height_m, ground, band, max_range_m
    )
    return points.mask


def test_ground_is_rejected_and_obstacles_kept_even_with_a_pixel_of_disparity_error() -> None:
    scene = Scene(1.5, 0.0, (), None, 1)
    depth = render_pair(scene, RIG).truth.depth_m.copy()
    ground = np.isfinite(depth)
    fb = RIG.fx * RIG.baseline_m
    # Every ground pixel measured one pixel of disparity too near: at 16 m that is 4 m.
    depth_near = np.where(ground, fb / (fb / depth + 1.0), np.nan).astype(np.float32)
    assert not _kept(depth_near, 1.5, CONFIG.ground, CONFIG.band, 20.0).any()
    # The same pixel error without the tolerance makes far ground stand up.
    strict = CONFIG.ground.model_copy(update={"disparity_tolerance_px": 0.0})
    assert _kept(depth_near, 1.5, strict, CONFIG.band, 20.0).any()
    # A wall 5 m ahead stands: its rows between the margin and the band are kept.
    wall = np.full((RIG.height, RIG.width), 5.0, dtype=np.float32)
    keep = _kept(wall, 1.5, CONFIG.ground, CONFIG.band, 20.0)
    rows = np.flatnonzero(keep.any(axis=1))
    heights = 1.5 - 5.0 * (rows - RIG.cy) / RIG.fy
    assert heights.min() >= 0.3 and heights.max() <= 1.5 + 2.0
    assert heights.min() < 0.9  # the tolerance costs little at 5 m
    # Unmeasured and measured-far pixels are never obstacles.
    wall[:, :10] = np.nan
    wall[:, 10:20] = np.inf
    assert not _kept(wall, 1.5, CONFIG.ground, CONFIG.band, 20.0)[:, :20].any()


@settings(max_examples=40, deadline=None)
@given(
    st.floats(-60, 60),
    st.floats(-40, 20),
    st.floats(-20, 20),
    st.floats(-20, 20),
    st.floats(0.3, 4.0),
    st.floats(0.0, 2.0),
)
def test_obstacle_points_equal_the_per_point_rule(
    yaw: float, pitch: float, roll: float, v_pitch: float, height: float, tolerance: float
) -> None:
    """The product form of the ground and band tests agrees with moving each point back."""
    rng = np.random.default_rng(1)
    depth = rng.uniform(0.3, 40.0, (RIG.height, RIG.width)).astype(np.float32)
    depth[rng.random(depth.shape) < 0.1] = np.nan
    pose = camera_to_level(Mount(yaw, pitch, roll, (0.2, 0.1, -0.1)), 5.0, v_pitch)
    ground = CONFIG.ground.model_copy(update={"disparity_tolerance_px": tolerance})
    points = obstacle_points(depth, RIG, pose, height, ground, CONFIG.band, 15.0)
    level = depth_to_frame(depth, RIG, pose)
    fb = RIG.fx * RIG.baseline_m
    camera = pose.translation[2]
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = 1.0 - tolerance / fb * depth.astype(np.float64)
        far_down = (level.down_m - camera) / scale + camera
        expected = (
            (level.down_m >= -CONFIG.band.above_m)
            & (level.down_m <= CONFIG.band.below_m)
            & (np.hypot(level.forward_m, level.right_m) < 15.0)
            & (scale > 0)
            & (far_down <= height - ground.margin_m)
        )
    disagree = points.mask != expected
    # Only points on the very edge of a test (float32 against float64) may differ.
    assert np.count_nonzero(disagree) <= max(2, expected.size // 5000)
    assert np.allclose(points.level.down_m, level.down_m[points.mask], atol=1e-4)
    assert np.allclose(points.level.right_m, level.right_m[points.mask], atol=1e-4)
    assert np.allclose(points.level.forward_m, level.forward_m[points.mask], atol=1e-4)


def test_height_band_limits() -> None:
    wall = np.full((RIG.height, RIG.width), 4.0, dtype=np.float32)
    level = depth_to_frame(wall, RIG, camera_to_level(Mount(), 0.0, 0.0))
    band = CONFIG.band.model_copy(update={"above_m": 0.2, "below_m": 0.4})
    keep = _kept(wall, 10.0, CONFIG.ground, band, 20.0)
    down = level.down_m[keep]
    assert down.min() >= -0.2 and down.max() <= 0.4
    # Beyond the maximum range nothing is kept.
    assert not _kept(wall, 10.0, CONFIG.ground, band, 3.9).any()


def test_height_from_a_tilted_rangefinder() -> None:
    assert height_from_rangefinder(2.0, 0.0, 0.0) == pytest.approx(2.0)
    assert height_from_rangefinder(2.0, 20.0, 10.0) == pytest.approx(
        2.0 * math.cos(math.radians(20)) * math.cos(math.radians(10))
    )


def test_plane_fit_ignores_outliers() -> None:
    rng = np.random.default_rng(4)
    normal = np.array([0.1, 0.98, -0.17])
    normal /= np.linalg.norm(normal)
    basis = np.linalg.svd(normal[None, :])[2][1:]
    on_plane = rng.uniform(-5, 5, (700, 2)) @ basis + normal * 1.4
    on_plane += rng.normal(0, 0.01, on_plane.shape)
    outliers = rng.uniform(-5, 5, (300, 3))
    plane = fit_plane(np.vstack([on_plane, outliers]), threshold_m=0.03)
    assert plane.normal == pytest.approx(normal, abs=0.005)
    assert plane.offset_m == pytest.approx(1.4, abs=0.01)
    assert 0.6 <= plane.inlier_fraction <= 0.75  # 70% on the plane, a few outliers near it
    with pytest.raises(ValueError, match="at least 3"):
        fit_plane(np.zeros((2, 3)), 0.1)


# --- pose -------------------------------------------------------------------------------------


def test_pose_comes_from_the_best_source() -> None:
    recorded = FramePose(1.0, 2.0, 3.0, "recording", "recording")
    attitude = Attitude(1_000, math.radians(5.0), math.radians(-4.0), 0.0)
    fresh = Rangefinder(1_000, 2.0)
    stale = Rangefinder(1_000 - 10**9, 2.0)
    position = LocalPosition(1_000, 0, 0, -7.0, 0, 0, 0)
    # A live frame: the autopilot's attitude and rangefinder.
    pose = resolve_pose(1_000, None, attitude, fresh, position, CONFIG)
    assert (pose.roll_deg, pose.pitch_deg) == pytest.approx((5.0, -4.0))
    assert pose.source == "mavlink" and pose.height_source == "rangefinder"
    assert pose.height_m == pytest.approx(height_from_rangefinder(2.0, 5.0, -4.0))
    # A frame that carries its pose was taken in it, whatever the autopilot says now.
    assert resolve_pose(1_000, recorded, attitude, fresh, position, CONFIG) == recorded
    assert resolve_pose(1_000, recorded, None, stale, position, CONFIG) == recorded
    # Without a recorded height, the live chain gives the height.
    no_height = FramePose(1.0, 2.0, math.nan, "recording", "none")
    pose = resolve_pose(1_000, no_height, attitude, fresh, position, CONFIG)
    assert (pose.roll_deg, pose.source, pose.height_source) == (1.0, "recording", "rangefinder")
    altitude = CONFIG.model_copy(
        update={"ground": CONFIG.ground.model_copy(update={"use_altitude": True})}
    )
    pose = resolve_pose(1_000, None, None, stale, position, altitude)
    assert pose.height_m == 7.0 and pose.height_source == "altitude"
    pose = resolve_pose(1_000, None, None, None, None, CONFIG)
    assert pose == FramePose(0.0, 0.0, 1.5, "config", "config")


# --- obstacles --------------------------------------------------------------------------------


def test_clustering_separates_two_obstacles_and_measures_them() -> None:
    rng = np.random.default_rng(0)
    # A 0.6 m wide, 1.2 m tall post at 4 m straight ahead and a pole at 7 m, 30 deg right.
    lateral = rng.uniform(-0.3, 0.3, 2000)
    post = np.stack([np.full(2000, 4.0), lateral, rng.uniform(0.3, 1.5, 2000)], axis=1)
    angle = math.radians(30.0)
    pole = np.stack(
        [
            np.full(500, 7.0 * math.cos(angle)),
            np.full(500, 7.0 * math.sin(angle)) + rng.uniform(-0.05, 0.05, 500),
            rng.uniform(0.3, 2.0, 500),
        ],
        axis=1,
    )
    speckle = np.array([[2.0, -1.0, 1.0]] * 5)
    points = np.vstack([post, pole, speckle]).astype(np.float32)
    obstacles = cluster_obstacles(
        points[:, 0],
        points[:, 1],
        points[:, 2],
        48.0,
        0.12,
        CONFIG.obstacles,
        SectorsConfig(),
        HistogramConfig(),
    )
    assert len(obstacles) == 2
    near, far = obstacles
    assert near.distance_m == pytest.approx(4.0, rel=0.01) and abs(near.bearing_deg) < 5
    assert near.width_m == pytest.approx(0.6, abs=0.05)
    assert near.height_m == pytest.approx(1.2, abs=0.1) and near.top_m == pytest.approx(1.5, 0.05)
    assert sum(near.histogram_counts) == 2000
    assert far.distance_m == pytest.approx(7.0, rel=0.01)
    assert far.bearing_deg == pytest.approx(30.0, abs=1.0)
    assert far.lateral_m == pytest.approx(3.5, abs=0.05)


# --- temporal filter --------------------------------------------------------------------------


def _scan(t_ms: int, readings: dict[int, float]) -> SectorScan:
    distance = np.full(72, np.inf, dtype=np.float32)
    for index, value in readings.items():
        distance[index] = value
    return SectorScan(t_ms * 1_000_000, distance)


def test_new_obstacle_needs_k_of_n_frames_and_is_unknown_until_then() -> None:
    f = SectorFilter(TemporalConfig(confirm_frames=2, window_frames=3, hold_ms=150))
    # The first frame can confirm no obstacle, so it vouches for nothing: clear bins beside
    # an unconfirmed one would tell the autopilot the way is free.
    first = f.update(_scan(0, {5: 4.0}))
    assert f.warming_up and np.isnan(first.distance_m).all()
    second = f.update(_scan(100, {5: 3.9}))
    assert not f.warming_up
    assert second.distance_m[5] == pytest.approx(3.9) and second.distance_m[6] == np.inf
    # A single-frame speckle elsewhere never gets out.
    assert np.isnan(f.update(_scan(200, {5: 3.8, 40: 1.0})).distance_m[40])
    assert f.update(_scan(300, {5: 3.7})).distance_m[40] == np.inf
    # A reset (the recording starts over) begins the warm-up again.
    f.reset()
    assert np.isnan(f.update(_scan(400, {5: 3.6})).distance_m).all()
    assert f.update(_scan(500, {5: 3.5})).distance_m[5] == pytest.approx(3.5)


def test_confirmed_obstacle_attacks_at_once_and_holds_for_a_bounded_time() -> None:
    f = SectorFilter(TemporalConfig(confirm_frames=3, window_frames=3, hold_ms=150))
    for t in (0, 50, 100):
        out = f.update(_scan(t, {10: 5.0}))
    assert out.distance_m[10] == pytest.approx(5.0)
    # Approaching: the nearer reading goes out in the very frame that measured it.
    assert f.update(_scan(150, {10: 2.0})).distance_m[10] == pytest.approx(2.0)
    # Vanishing: held with its own capture time, then dropped after hold_ms.
    held = f.update(_scan(200, {}))
    assert held.distance_m[10] == pytest.approx(2.0)
    assert held.reading_t_ns is not None and held.reading_t_ns[10] == 150_000_000
    assert f.update(_scan(300, {})).distance_m[10] == pytest.approx(2.0)
    assert f.update(_scan(350, {})).distance_m[10] == np.inf
    # The sender's age limit applies to a held reading as to any: 120 ms old is unknown.
    assert np.isnan(held.expired(now_ns=270_000_000, max_age_ns=100_000_000).distance_m[10])
    assert held.expired(now_ns=270_000_000, max_age_ns=100_000_000).distance_m[11] == np.inf


def test_filter_with_k_1_passes_readings_straight_through() -> None:
    f = SectorFilter(TemporalConfig(confirm_frames=1, window_frames=1, hold_ms=0))
    out = f.update(_scan(0, {3: 1.5}))
    assert out.distance_m[3] == pytest.approx(1.5)
    assert f.update(_scan(10, {})).distance_m[3] == np.inf


def test_reported_points_are_in_body_frd_under_attitude() -> None:
    from avoidd.perception.perceive import perceive

    wall = np.full((RIG.height, RIG.width), 4.0, dtype=np.float32)
    seen = perceive(
        wall,
        RIG,
        Mount(),
        FramePose(8.0, -12.0, 1.5),
        CONFIG,
        SectorsConfig(),
        HistogramConfig(),
        20.0,
        0,
    )
    scan = seen.scan
    assert scan.points_frd_m is not None
    finite = np.flatnonzero(np.isfinite(scan.distance_m))
    assert finite.size >= 5
    level = body_to_level(8.0, -12.0)
    for index in finite:
        point = level.apply(scan.points_frd_m[index])
        assert math.hypot(point[0], point[1]) == pytest.approx(scan.distance_m[index], rel=1e-4)
        # In the body frame the point is off the horizontal plane by the attitude.
        assert abs(scan.points_frd_m[index][2] - point[2]) > 0.05
