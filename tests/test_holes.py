"""The hole suites: bins over a surface read, never too far (issue 53)."""

from __future__ import annotations

import numpy as np

from avoidd.config import SectorsConfig
from avoidd.evaluation.holes import SUITES, format_holes, hole_suite, run_hole_case, summarize
from avoidd.perception.grid import point_cells, sector_counts
from avoidd.perception.sectors import _nearer_points_px


def test_hole_suites_never_read_a_surface_too_far() -> None:
    # A few seeded scenes of each suite (`avoidd eval-perception --hole-scenes`): every bin
    # with a surface in it reads it within 10% or nearer, or unknown; never farther or clear.
    results = [run_hole_case(case, name) for name in SUITES for case in hole_suite(name, 4)]
    print(format_holes(results))
    summaries = summarize(results)
    assert [s.suite for s in summaries] == list(SUITES)
    assert all(s.bins > 0 for s in summaries)
    assert sum(s.too_far for s in summaries) == 0
    assert sum(s.read for s in summaries) >= 0.85 * sum(s.bins for s in summaries)


def test_a_reading_behind_many_nearer_points_reads_them_instead() -> None:
    # A bin holds a dense surface at 10 m and, nearer, 300 points spread from 0.4 to 0.8 m
    # that make no cluster (a pole too near for the matcher to measure well): the bin reads
    # where those points are, never 10 m. Before, it read the 10 m surface through them.
    rng = np.random.default_rng(3)
    far = np.full(2000, 10.0)
    near = rng.uniform(0.4, 0.8, 300)
    forward = np.concatenate((far, near)).astype(np.float32)
    right = np.zeros_like(forward)
    params = SectorsConfig()
    cells = point_cells(forward, right, 48.0, params.cluster_window_px)
    per_bin, bin_index = sector_counts(cells)
    near_px = np.full(72, np.nan)
    near_px[0] = 48.0 / 10.0
    read_px = _nearer_points_px(per_bin, bin_index, cells, near_px, params)
    assert np.isfinite(read_px[0])
    assert 48.0 / read_px[0] <= 0.45
    assert np.isnan(read_px[1:]).all()
    # Fewer nearer points than a cluster needs leave the reading alone.
    few = np.concatenate((far, near[:10])).astype(np.float32)
    sparse = point_cells(few, np.zeros_like(few), 48.0, params.cluster_window_px)
    per_bin, bin_index = sector_counts(sparse)
    assert np.isnan(_nearer_points_px(per_bin, bin_index, sparse, near_px, params)).all()
