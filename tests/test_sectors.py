from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from avoidd.config import HistogramConfig, PerceptionConfig, SectorsConfig
from avoidd.mavlink.messages import UNKNOWN_CM, sectors_to_cm
from avoidd.perception.frames import camera_to_level
from avoidd.perception.ground import unseen_surfaces
from avoidd.perception.perceive import perceive
from avoidd.perception.sectors import (
    _beyond_reach,
    _bins_of_points,
    _SizeRule,
    _sorted_search,
    bin_of_bearing,
    column_bearings_deg,
    covered_bins,
    merge_scans,
    nearest_cluster,
)
from avoidd.types import FramePose, Mount, RectifiedRig, SectorScan, bin_bearing_deg, wrap_deg

RIG = RectifiedRig(640, 480, 400.0, 400.0, 319.5, 239.5, 0.12, 0.0)
PARAMS = SectorsConfig()
MAX_RANGE_M = 20.0


def column_at(bearing_deg: float, rig: RectifiedRig = RIG) -> int:
    return round(rig.cx + rig.fx * math.tan(math.radians(bearing_deg)))


def far_scene(rig: RectifiedRig = RIG) -> np.ndarray:
    """Everything measured and far beyond the maximum range."""
    return np.full((rig.height, rig.width), 60.0, dtype=np.float32)


def put_obstacle(depth: np.ndarray, bearing_deg: float, range_m: float, width_px: int) -> None:
    column = column_at(bearing_deg)
    z = range_m * math.cos(math.radians(bearing_deg))
    depth[:, column - width_px // 2 : column + (width_px + 1) // 2] = z


def scan_of(depth: np.ndarray, mount: Mount | None = None) -> np.ndarray:
    """The scan of a depth map seen by a level vehicle whose body origin is 1.5 m up."""
    seen = perceive(
        depth,
        RIG,
        mount or Mount(),
        FramePose(0.0, 0.0, 1.5),
        PerceptionConfig(),
        PARAMS,
        HistogramConfig(),
        MAX_RANGE_M,
        123,
    )
    assert seen.scan.t_capture_ns == 123
    return seen.scan.distance_m


def test_bin_geometry() -> None:
    assert int(bin_of_bearing(0.0)) == 0
    assert int(bin_of_bearing(20.0)) == 4
    assert int(bin_of_bearing(2.4)) == 0 and int(bin_of_bearing(2.6)) == 1
    assert int(bin_of_bearing(-20.0)) == 68
    assert int(bin_of_bearing(357.6)) == 0
    assert (
        bin_bearing_deg(4) == 20.0 and bin_bearing_deg(68) == -20.0 and bin_bearing_deg(36) == 180
    )
    assert wrap_deg(270.0) == -90.0 and wrap_deg(-180.0) == 180.0


def test_points_get_the_bin_of_their_bearing_all_round() -> None:
    rng = np.random.default_rng(3)
    bearing = rng.uniform(-180.0, 180.0, 20000)
    bearing = np.concatenate([bearing, [-180.0, 0.0, 90.0, 180.0]])
    range_m = rng.uniform(0.1, 30.0, bearing.size)
    forward = (range_m * np.cos(np.radians(bearing))).astype(np.float32)
    right = (range_m * np.sin(np.radians(bearing))).astype(np.float32)
    got, turns = _bins_of_points(forward, right)
    # The bearing in bin widths comes along (for lateral extents): bin = its floor mod 72.
    assert np.array_equal(got, np.mod(np.floor(turns).astype(np.int64), 72))
    expected = bin_of_bearing(np.degrees(np.arctan2(right.astype(np.float64), forward)))
    # Float32 may round a bearing within a hair of a bin edge either way; nowhere else.
    offset = np.abs(np.mod(bearing + 2.5, 5.0) - 2.5)
    edge = np.abs(offset - 2.5) < 1e-3
    assert np.array_equal(got[~edge], expected[~edge])
    assert got.min() >= 0 and got.max() <= 71 and set(got[bearing.size - 4 :]) == {36, 0, 18}


def test_obstacle_at_plus_20_degrees_lands_in_bin_4() -> None:
    depth = far_scene()
    put_obstacle(depth, 20.0, 6.0, 30)
    distance = scan_of(depth)
    assert distance[4] == pytest.approx(6.0, rel=0.01)
    finite = np.flatnonzero(np.isfinite(distance))
    assert set(finite) <= {3, 4, 5}
    nearest = SectorScan(0, distance).nearest()
    assert nearest is not None and nearest.bearing_deg == 20.0


def test_clear_bins_and_field_of_view() -> None:
    distance = scan_of(far_scene())
    covered = covered_bins(RIG, Mount())
    half_fov = RIG.hfov_deg / 2
    for index in range(72):
        bearing = bin_bearing_deg(index)
        assert covered[index] == (abs(bearing) <= half_fov)
        if covered[index]:
            assert distance[index] == np.inf
        else:
            assert np.isnan(distance[index])
    cm = sectors_to_cm(SectorScan(0, distance), 20, 2000)
    assert cm[0] == 2001 and cm[36] == UNKNOWN_CM and cm[18] == UNKNOWN_CM


def test_mount_yaw_90_fills_bins_around_18() -> None:
    depth = far_scene()
    put_obstacle(depth, 0.0, 4.0, 40)
    distance = scan_of(depth, Mount(yaw_deg=90.0))
    assert distance[18] == pytest.approx(4.0, rel=0.01)
    covered = np.flatnonzero(~np.isnan(distance))
    # The obstacle (40 px) overhangs bin 18 (35 px) by 2 px each side: slivers 2 cm wide at
    # 4 m, narrower than the smallest obstacle (5 cm), which bins 17 and 19 cannot vouch
    # for either way: unknown, not a reading and not clear.
    assert set(covered) == set(range(11, 26)) - {17, 19}
    assert np.isnan(distance[0]) and np.isnan(distance[36])


def test_a_thin_pole_split_by_a_bin_boundary_is_read_in_both_bins() -> None:
    # A 5 cm pole at 5 m (4 px) across the boundary of bins 0 and 1 (2.5 deg, between
    # columns 336 and 337): one column in bin 0, three in bin 1. Each part alone is narrower
    # than the smallest obstacle, so each bin alone would call it a sliver of something the
    # other reports, and neither did: the pole read unknown in both.
    boundary = column_at(2.5)
    bearings = column_bearings_deg(RIG, Mount())[boundary - 1 : boundary + 1]
    assert bin_of_bearing(np.asarray(bearings)).tolist() == [0, 1]
    depth = far_scene()
    depth[:, boundary - 1 : boundary + 3] = 5.0
    distance = scan_of(depth)
    assert distance[0] == pytest.approx(5.0, rel=0.02)
    assert distance[1] == pytest.approx(5.0, rel=0.02)
    # A sliver beside a wide body stays unknown: the body's bin reports it.
    depth = far_scene()
    depth[:, boundary - 1 : boundary + 40] = 5.0
    distance = scan_of(depth)
    assert np.isnan(distance[0]) and distance[1] == pytest.approx(5.0, rel=0.02)
    # Two slivers that do not meet at the boundary are no object split by it.
    depth = far_scene()
    depth[:, boundary - 2 : boundary - 1] = 5.0
    depth[:, boundary + 4 : boundary + 7] = 5.0
    distance = scan_of(depth)
    assert np.isnan(distance[0]) and np.isnan(distance[1])


def test_mount_position_shifts_the_range() -> None:
    depth = far_scene()
    put_obstacle(depth, 0.0, 4.0, 40)
    distance = scan_of(depth, Mount(position_m=(0.3, 0.0, 0.0)))
    assert distance[0] == pytest.approx(4.3, rel=0.01)


def test_unmeasured_bins_are_unknown_not_clear() -> None:
    depth = far_scene()
    left, right = column_at(-12.5), column_at(-7.5)
    depth[:, left:right] = np.nan  # bin 70 (-10 deg) has no valid pixel
    distance = scan_of(depth)
    assert np.isnan(distance[70])
    assert distance[69] == np.inf and distance[71] == np.inf


def test_a_plain_surface_in_view_is_unknown_never_clear() -> None:
    # A surface too plain to match leaves its pixels unmeasured while the rest of the bin
    # shows free space: before, the free pixels around it made the bin clear. Here a plain
    # box 10 columns wide at the edge of bin 0 spans the level, so rays that would meet
    # anything standing in the band are unmeasured: unknown, never clear.
    depth = far_scene()
    left = column_at(-2.5) + 1  # the first column of bin 0
    bearings = column_bearings_deg(RIG, Mount())[left - 1 : left + 1]
    assert bin_of_bearing(bearings).tolist() == [71, 0]
    depth[RIG.height // 2 - 40 : RIG.height // 2 + 60, left : left + 10] = np.nan
    distance = scan_of(depth)
    assert np.isnan(distance[0])
    assert distance[71] == np.inf and distance[1] == np.inf
    # The patch is where the rays at or above the level meet it (the sky above the band at
    # the maximum range and the ground below the level are no part of it).
    level = camera_to_level(Mount(), 0.0, 0.0)
    band = PerceptionConfig().band
    patch = unseen_surfaces(depth, RIG, level, band, MAX_RANGE_M, (7, 7))
    rows, columns = np.nonzero(patch)
    assert set(columns.tolist()) == set(range(left, left + 10))
    horizon = RIG.cy
    assert rows.max() <= horizon and rows.min() >= horizon - RIG.fy * band.above_m / MAX_RANGE_M
    # Holes below the level only (ground the matcher missed) and holes smaller than the
    # patch (matcher noise) leave the bin clear.
    depth = far_scene()
    depth[RIG.height // 2 + 20 :, left : left + 10] = np.nan
    rng = np.random.default_rng(5)
    rows = rng.integers(0, RIG.height - 2, 200)
    columns = rng.integers(0, RIG.width - 2, 200)
    for row, column in zip(rows, columns, strict=True):
        depth[row : row + 2, column : column + 2] = np.nan
    distance = scan_of(depth)
    assert distance[0] == np.inf


def test_a_few_speckles_cannot_make_an_obstacle() -> None:
    depth = far_scene()
    rng = np.random.default_rng(1)
    band_rows = np.arange(150, 230)
    rows = rng.choice(band_rows, PARAMS.min_pixels - 1, replace=False)
    depth[rows, column_at(10.0)] = 1.5
    assert scan_of(depth)[2] == np.inf


def test_thin_pole_in_front_of_a_wall_is_kept() -> None:
    depth = np.full((RIG.height, RIG.width), 9.0, dtype=np.float32)  # a wall 9 m ahead
    put_obstacle(depth, 0.0, 5.0, 4)  # a 5 cm pole at 5 m is 4 px wide
    distance = scan_of(depth)
    assert distance[0] == pytest.approx(5.0, rel=0.01)
    assert distance[2] == pytest.approx(9.0 / math.cos(math.radians(10.0)), rel=0.02)


def test_nearest_cluster_reports_the_near_end_of_an_oblique_surface() -> None:
    # One bin seeing a wall whose range grows from 4 m to 8 m across the bin.
    ranges = np.linspace(4.0, 8.0, 400)
    focal_baseline = 48.0
    distance, _ = nearest_cluster(
        np.zeros(400, dtype=np.int64), (focal_baseline / ranges).astype(np.float32), 48.0, 20, 0.8
    )
    assert 4.0 <= distance[0] < 4.0 * 1.03
    assert np.isnan(distance[1:]).all()


@settings(max_examples=200, deadline=None)
@given(
    st.lists(
        st.tuples(st.integers(0, 71), st.floats(0.5, 60.0)),
        min_size=0,
        max_size=300,
    ),
    st.integers(1, 30),
    st.floats(0.1, 3.0),
)
def test_nearest_cluster_properties(
    points: list[tuple[int, float]], min_pixels: int, window_px: float
) -> None:
    bins = np.array([b for b, _ in points], dtype=np.int64)
    disparity = np.array([d for _, d in points], dtype=np.float32)
    distance, _ = nearest_cluster(bins, disparity, 48.0, min_pixels, window_px)
    counts = np.bincount(bins, minlength=72) if points else np.zeros(72, dtype=np.int64)
    for index in range(72):
        values = disparity[bins == index]
        if counts[index] < min_pixels:
            assert np.isnan(distance[index])
            continue
        ordered = np.sort(values)[::-1]
        dense = ordered[: ordered.size - min_pixels + 1] - ordered[min_pixels - 1 :] <= window_px
        if not dense.any():
            assert np.isnan(distance[index])
            continue
        seed = ordered[int(np.argmax(dense))]
        reported = 48.0 / distance[index]
        # The reported disparity lies in the seed's window and is one of the measured values.
        assert seed - window_px - 1e-4 <= reported <= seed + 1e-4
        assert np.isclose(values, reported, rtol=1e-5).any()


@settings(max_examples=60, deadline=None)
@given(
    st.integers(0, 2**32 - 1),
    st.integers(1, 40),
    st.floats(0.1, 3.0),
    st.sampled_from([0.0, 0.05 / 0.12, 1.0]),
    st.sampled_from([0.0, 0.05 / 48.0, 0.01]),
)
def test_dropping_points_out_of_reach_changes_no_cluster(
    seed: int, min_pixels: int, window_px: float, size_px_per_px: float, slab: float
) -> None:
    # Scattered points behind and in front of a few dense surfaces, as in a frame: the search
    # on the points left after the histogram cut must give what the search on all of them does.
    rng = np.random.default_rng(seed)
    count = int(rng.integers(2000, 12000))
    bins = [rng.integers(0, 72, count)]
    disparity = [rng.uniform(0.3, 60.0, count)]
    for _ in range(int(rng.integers(1, 10))):
        size = int(rng.integers(5, 800))
        bins.append(np.full(size, rng.integers(0, 72)))
        spread = rng.uniform(0.01, 1.5)
        disparity.append(np.clip(rng.normal(rng.uniform(1.0, 60.0), spread, size), 0.3, None))
    all_bins = np.concatenate(bins).astype(np.int64)
    all_disparity = np.concatenate(disparity).astype(np.float32)
    args = (min_pixels, window_px, size_px_per_px, slab)
    distance, index = nearest_cluster(all_bins, all_disparity, 48.0, *args)
    expected, expected_index = _sorted_search(all_bins, all_disparity, 48.0, _SizeRule(*args))
    np.testing.assert_array_equal(distance, expected)
    found = index >= 0
    np.testing.assert_array_equal(found, expected_index >= 0)
    # Ties may swap which point is reported, never its disparity.
    np.testing.assert_array_equal(all_disparity[index[found]], all_disparity[expected_index[found]])


def test_the_cut_drops_the_points_behind_a_dense_surface() -> None:
    # 3000 points of a wall at d = 10 px and 3000 points far behind it (d < 5 px) in one bin:
    # the far points cannot matter and are dropped, the wall and anything nearer kept.
    wall = np.full(3000, 10.0, dtype=np.float32)
    far = np.linspace(1.0, 5.0, 3000, dtype=np.float32)
    near = np.array([30.0, 40.0], dtype=np.float32)
    disparity = np.concatenate([wall, far, near])
    bins = np.zeros(disparity.size, dtype=np.int64)
    kept = _beyond_reach(bins, disparity, _SizeRule(20, 0.8, 0.0, 0.0))
    assert kept is not None
    assert set(kept.tolist()) == set(range(3000)) | {6000, 6001}


def test_merge_takes_nearest_and_keeps_unknown_where_nobody_sees() -> None:
    a = np.full(72, np.nan, dtype=np.float32)
    b = np.full(72, np.nan, dtype=np.float32)
    a[0], b[0] = 5.0, 3.0
    a[1], b[1] = np.inf, 4.0
    a[2] = np.inf
    points_a = np.full((72, 3), np.nan, dtype=np.float32)
    points_b = np.full((72, 3), np.nan, dtype=np.float32)
    points_a[0], points_b[0] = (5.0, 0.0, 0.0), (3.0, 0.0, 0.0)
    merged = merge_scans([SectorScan(10, a, points_a), SectorScan(20, b, points_b)])
    assert merged.t_capture_ns == 20
    assert merged.distance_m[0] == 3.0 and merged.distance_m[1] == 4.0
    assert merged.distance_m[2] == np.inf and np.isnan(merged.distance_m[3])
    # Each bin keeps the capture time and the point of the reading it took.
    assert merged.reading_t_ns is not None and merged.points_frd_m is not None
    assert list(merged.reading_t_ns[:3]) == [20, 20, 10]
    assert list(merged.points_frd_m[0]) == [3.0, 0.0, 0.0]
    assert np.isnan(merge_scans([]).distance_m).all()


def test_encoding_never_sends_zero_and_clamps() -> None:
    distance = np.full(72, np.nan, dtype=np.float32)
    distance[0] = 0.01  # closer than min: clamped up to min, never 0
    distance[1] = 25.0  # beyond max (cannot come from a scan, but must still clamp)
    distance[2] = np.inf
    distance[3] = 7.234
    cm = sectors_to_cm(SectorScan(0, distance), 20, 2000)
    assert cm[:4] == [20, 2000, 2001, 723]
    assert cm[4:] == [UNKNOWN_CM] * 68
    assert 0 not in cm


def test_column_bearings_follow_the_mount() -> None:
    bearings = column_bearings_deg(RIG, Mount(yaw_deg=-90.0))
    assert bearings[0] == pytest.approx(-90.0 - RIG.hfov_deg / 2, abs=0.1)
    assert bearings[-1] == pytest.approx(-90.0 + RIG.hfov_deg / 2, abs=0.1)


def test_near_clusters_must_be_as_large_as_a_small_object_there() -> None:
    # At 1.33 m (d = 36 px with f B = 48, B = 0.12) a 5 cm square covers (0.05 / 0.12 * 36)^2
    # = 225 pixels: 40 pixels smeared off an edge do not make an obstacle, 300 do.
    disparity = np.full(40, 36.0, dtype=np.float32)
    smear, _ = nearest_cluster(np.zeros(40, dtype=np.int64), disparity, 48.0, 20, 0.8, 0.05 / 0.12)
    assert np.isnan(smear[0])
    wall = np.concatenate([disparity, np.full(300, 35.9, dtype=np.float32)])
    found, index = nearest_cluster(np.zeros(340, dtype=np.int64), wall, 48.0, 20, 0.8, 0.05 / 0.12)
    assert found[0] == pytest.approx(48.0 / 35.9, rel=1e-3) or found[0] == pytest.approx(48 / 36)
    assert index[0] >= 0
    # Far away the fixed minimum rules: 20 points at d = 4 (12 m) still make an obstacle.
    far, _ = nearest_cluster(
        np.zeros(20, dtype=np.int64), np.full(20, 4.0, np.float32), 48.0, 20, 0.8, 0.05 / 0.12
    )
    assert far[0] == pytest.approx(12.0)


def test_many_points_that_make_no_cluster_leave_the_bin_unknown_not_clear() -> None:
    # The corner of a round pole 1 m away, or a slanted surface: hundreds of obstacle points
    # in one bin, spread over 1 to 3 m, so that no disparity slab holds a 5 cm square of them.
    # No reading can be vouched for, and the bin must not read clear either.
    depth = far_scene()
    rng = np.random.default_rng(7)
    column = column_at(10.0)
    rows = rng.integers(180, 300, 400)
    columns = column + rng.integers(-12, 12, 400)
    depth[rows, columns] = rng.uniform(1.0, 3.0, 400)
    distance = scan_of(depth)
    assert np.isnan(distance[2])
    assert distance[0] == np.inf and distance[5] == np.inf
