"""The cell-based searches against the point-based reference: same bins, never farther."""

from __future__ import annotations

import math

import numpy as np
import pytest

from avoidd.config import HistogramConfig, ObstaclesConfig, SectorsConfig
from avoidd.perception.grid import (
    NearestCells,
    SizeRule,
    nearest_cells,
    point_cells,
    refine,
    row_targets,
    sector_counts,
)
from avoidd.perception.obstacles import cluster_obstacles
from avoidd.perception.sectors import _bins_of_points, nearest_cluster
from avoidd.types import SECTOR_COUNT

FOCAL_BASELINE = 48.0
BASELINE_M = 0.12
RULES = [
    (20, 0.8, 0.05 / BASELINE_M, 0.05 / FOCAL_BASELINE),  # the default sector rule
    (20, 0.8, 0.0, 0.0),
    (5, 0.3, 0.0, 0.0),
    (40, 2.0, 1.0, 0.01),
]


def _scene(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Scattered points and a few dense surfaces (as a frame sees them), level frame."""
    rng = np.random.default_rng(seed)
    count = int(rng.integers(200, 6000))
    bearing = [rng.uniform(-60.0, 60.0, count)]
    range_m = [rng.uniform(0.5, 20.0, count)]
    for _ in range(int(rng.integers(1, 12))):
        size = int(rng.integers(5, 3000))
        centre = rng.uniform(-60.0, 60.0)
        bearing.append(rng.uniform(centre - rng.uniform(0.1, 8.0), centre + 1.0, size))
        near_px = rng.uniform(2.5, 60.0)
        spread_px = rng.uniform(0.01, 1.5)
        disparity = np.clip(rng.normal(near_px, spread_px, size), 2.4, None)
        range_m.append(FOCAL_BASELINE / disparity)
    angle = np.radians(np.concatenate(bearing))
    distance = np.concatenate(range_m)
    forward = (distance * np.cos(angle)).astype(np.float32)
    right = (distance * np.sin(angle)).astype(np.float32)
    return forward, right


def _grid_scan(
    forward: np.ndarray, right: np.ndarray, rule: SizeRule
) -> tuple[np.ndarray, np.ndarray]:
    """Per bin: the distance read on the cells (as the sector scan does) and its point."""
    cells = point_cells(forward, right, FOCAL_BASELINE, rule.window_px)
    per_bin, bin_index = sector_counts(cells)
    found = nearest_cells(per_bin, cells.first_cell, cells.cell_px, rule)
    where = NearestCells(np.full(SECTOR_COUNT, -1, np.int64), np.full(SECTOR_COUNT, -1, np.int64))
    where.cell[bin_index], where.rank[bin_index] = found.cell, found.rank
    row_bin = np.mod((np.arange(cells.counts.shape[0]) + cells.first_degree) // 5 + 36, 72)
    near_px, picked = refine(cells, forward, right, row_targets(cells, row_bin, where), where)
    with np.errstate(divide="ignore", invalid="ignore"):
        distance = (np.float32(FOCAL_BASELINE) / near_px.astype(np.float32)).astype(np.float32)
    return distance, picked


def _reference(forward: np.ndarray, right: np.ndarray, rule: SizeRule) -> np.ndarray:
    bins, _ = _bins_of_points(forward, right)
    range_m = np.sqrt(forward * forward + right * right)
    disparity = np.asarray(np.float32(FOCAL_BASELINE) / np.maximum(range_m, 1e-3), np.float32)
    distance, _ = nearest_cluster(bins, disparity, FOCAL_BASELINE, *rule)
    return distance


def test_cells_find_the_same_bins_never_farther_and_close() -> None:
    gaps_cells = []
    extra = 0
    for seed in range(40):
        forward, right = _scene(seed)
        rule = SizeRule(*RULES[seed % len(RULES)])
        expected = _reference(forward, right, rule)
        got, picked = _grid_scan(forward, right, rule)
        found = np.isfinite(expected)
        # Every bin the points say holds a cluster holds one on the cells ...
        missed = np.flatnonzero(found & ~np.isfinite(got))
        assert missed.size == 0, (missed, seed)
        # ... never farther.
        assert (got[found] <= expected[found] * (1 + 1e-6)).all(), seed
        cell_px = rule.window_px / 16
        gap_px = FOCAL_BASELINE / got[found] - FOCAL_BASELINE / expected[found]
        gaps_cells.extend(gap_px / cell_px)
        extra += int(np.count_nonzero(np.isfinite(got) & ~found))
        # Each reading comes with a measured point of the bin, at or beyond the reading.
        bins, _ = _bins_of_points(forward, right)
        for index in np.flatnonzero(np.isfinite(got)):
            point = picked[index]
            assert point >= 0 and bins[point] == index
            assert math.hypot(forward[point], right[point]) >= got[index] * (1 - 1e-6)
    # Nearer in disparity by a cell or two (a cell is a sixteenth of the window) for most
    # bins; more where scattered points nearly make a nearer cluster (counted a cell wider,
    # it passes): safe, and rare in frames (see the one-surface test).
    gaps = np.array(gaps_cells)
    assert len(gaps) > 500
    assert np.median(gaps) <= 2.0 and np.mean(gaps <= 2.5) >= 0.6, np.percentile(gaps, [50, 80])
    # A bin found on the cells alone is one the points nearly make.
    assert extra <= len(gaps) * 0.02


def test_one_surface_reads_within_a_slice_of_the_points() -> None:
    # A wall filling a bin: the reading is the reference's to a few hundredths of a pixel.
    rng = np.random.default_rng(5)
    bearing = np.radians(rng.uniform(-2.4, 2.4, 5000))
    disparity = rng.normal(8.0, 0.15, 5000)
    range_m = FOCAL_BASELINE / disparity
    forward = (range_m * np.cos(bearing)).astype(np.float32)
    right = (range_m * np.sin(bearing)).astype(np.float32)
    rule = SizeRule(*RULES[0])
    expected = _reference(forward, right, rule)[0]
    got = _grid_scan(forward, right, rule)[0][0]
    assert got <= expected
    assert FOCAL_BASELINE / got - FOCAL_BASELINE / expected < 0.02


def test_unkept_points_count_nowhere() -> None:
    forward, right = _scene(3)
    kept = np.random.default_rng(0).uniform(size=forward.size) < 0.5
    rule = SizeRule(*RULES[0])
    whole = point_cells(forward.copy(), right.copy(), FOCAL_BASELINE, 0.8, kept=kept)
    only = point_cells(forward[kept], right[kept], FOCAL_BASELINE, 0.8)
    assert whole.counts.sum() == kept.sum()
    assert np.array_equal(whole.counts, only.counts)
    assert (whole.first_degree, whole.first_cell) == (only.first_degree, only.first_cell)
    assert (whole.key[~kept] == whole.counts.size).all()
    assert np.array_equal(
        nearest_cells(whole.counts, whole.first_cell, whole.cell_px, rule).cell,
        nearest_cells(only.counts, only.first_cell, only.cell_px, rule).cell,
    )


def test_obstacle_distances_are_never_farther_than_their_points() -> None:
    rng = np.random.default_rng(8)
    parts = []
    for forward_m, right_m, size in ((4.0, 0.0, 2000), (6.0, 3.0, 800), (9.0, -4.0, 400)):
        lateral = rng.uniform(-0.3, 0.3, size)
        depth = rng.normal(0.0, 0.02, size)
        parts.append(
            np.stack([forward_m + depth, right_m + lateral, rng.uniform(0.3, 1.5, size)], axis=1)
        )
    points = np.vstack(parts).astype(np.float32)
    obstacles = cluster_obstacles(
        points[:, 0],
        points[:, 1],
        points[:, 2],
        FOCAL_BASELINE,
        BASELINE_M,
        ObstaclesConfig(),
        SectorsConfig(),
        HistogramConfig(),
    )
    assert len(obstacles) == 3
    rule = SizeRule(*RULES[0])
    for obstacle, part in zip(obstacles, parts, strict=True):
        range_m = np.hypot(part[:, 0], part[:, 1]).astype(np.float32)
        disparity = np.asarray(np.float32(FOCAL_BASELINE) / range_m, np.float32)
        reference, _ = nearest_cluster(
            np.zeros(range_m.size, dtype=np.int64), disparity, FOCAL_BASELINE, *rule
        )
        assert obstacle.distance_m <= reference[0] * (1 + 1e-6)
        assert obstacle.distance_m >= reference[0] * 0.99
        assert sum(obstacle.histogram_counts) == obstacle.points == part.shape[0]
        assert obstacle.width_m == pytest.approx(0.6, abs=0.05)
        assert obstacle.top_m == pytest.approx(1.476, abs=0.03)  # the 98th percentile
