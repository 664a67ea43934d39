"""The segmentation-based hybrid matcher and the shared post-processing steps."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from avoidd.config import SegmentConfig
from avoidd.evaluation.metrics import score
from avoidd.loading import load_all
from avoidd.pipeline import HeadPipeline
from avoidd.sources import open_source
from avoidd.vision.matchers import create_matcher
from avoidd.vision.matchers.segment import (
    UNSEGMENTED,
    boundary_band,
    fit_region_planes,
    kmeans_levels,
    segment_regions,
)
from avoidd.vision.postprocess import fill_holes, left_right_check, remove_speckles
from tests.helpers import synthetic_config
from tests.test_stereo_eval import NUM_DISPARITIES, textured_pair  # noqa: F401 (a fixture)


def test_kmeans_on_the_histogram_finds_the_grey_levels() -> None:
    rng = np.random.default_rng(0)
    image = (
        np.concatenate([rng.normal(mean, 4.0, 3000) for mean in (40, 120, 200)])
        .clip(0, 255)
        .astype(np.uint8)
    )
    table = kmeans_levels(image, 3)
    assert table[40] == 0 and table[120] == 1 and table[200] == 2
    assert table[0] == 0 and table[255] == 2
    assert np.all(np.diff(table.astype(int)) >= 0)  # ordered dark to light


def test_regions_split_clusters_into_components_and_drop_fragments() -> None:
    image = np.full((60, 90), 50, np.uint8)
    image[10:30, 10:30] = 200  # two separate bright squares: two regions
    image[10:30, 50:70] = 200
    image[45, 45] = 200  # a one-pixel fragment: unsegmented after the opening
    regions, count = segment_regions(image, 2, 3, 20)
    assert count == 3  # background + two squares
    assert regions[20, 20] != regions[20, 60] and regions[20, 20] >= 0
    assert regions[45, 45] == UNSEGMENTED  # a fragment the opening removed: left to SAD
    band = boundary_band(regions, 1)
    assert band[10, 20] and band[9, 20] and not band[20, 20] and not band[50, 5]


def test_planes_fill_from_boundaries_and_refuse_depth_edges() -> None:
    regions = np.zeros((40, 40), np.int32)
    regions[:, 20:] = 1
    regions[0, 0] = UNSEGMENTED
    ys, xs = np.mgrid[0:40, 0:40]
    measured = (0.1 * xs + 0.05 * ys + 3.0).astype(np.float32)  # region 0: a slanted plane
    measured[:, 20:] = np.where(xs[:, 20:] < 30, 5.0, 15.0)  # region 1: two depths
    edge = (xs % 19 == 0) | (ys % 39 == 0)
    measured[~edge] = np.nan
    planes = fit_region_planes(regions, 2, measured, 8, 1.0)
    assert planes.ok[0] and not planes.ok[1]
    assert (planes.a[0], planes.b[0], planes.c[0]) == pytest.approx((0.1, 0.05, 3.0), abs=1e-6)


def test_segment_matcher_on_a_rendered_scene(
    textured_pair: tuple[np.ndarray, np.ndarray, np.ndarray],  # noqa: F811
) -> None:
    left, right, truth = textured_pair
    matcher = create_matcher(SegmentConfig(kind="segment", num_disparities=NUM_DISPARITIES))
    disparity = matcher.compute(left, right)
    filled = matcher.last_filled
    assert filled is not None and filled.shape == truth.shape
    assert 0.05 < filled.mean() < 0.5  # interiors were filled, boundaries measured
    scores = score(disparity, truth, None, 0.0)
    assert scores.density >= 75.0 and scores.avgerr <= 0.4, scores
    error = np.abs(disparity - truth)
    assert np.nanmean(error[filled] > 2.0) <= 0.08  # filled interiors are mostly right
    measured = ~np.isnan(disparity) & ~filled
    assert np.nanmean(error[measured] > 2.0) <= 0.03
    valid = np.isfinite(disparity)
    assert np.all(disparity[valid] >= 0) and np.all(disparity[valid] < NUM_DISPARITIES)


def test_left_right_check_keeps_only_consistent_matches() -> None:
    left = np.array([[0, 0, 2, 2, 2, 5]], np.int32)
    right = np.array([[2, 2, 2, 9, 2, 2]], np.int32)
    checked = left_right_check(left, right, 1)
    # Left x with disparity d lands on right x - d, whose own disparity must agree within 1.
    assert checked[0, 2] == 2 and checked[0, 3] == 2 and checked[0, 4] == 2
    assert np.isnan(checked[0, 5])
    assert np.isnan(checked[0, 0]) and np.isnan(checked[0, 1])  # the right view says 2, not 0


def test_speckles_are_removed_but_surfaces_stay() -> None:
    disparity = np.full((50, 50), 10.0, np.float32)
    disparity[20:23, 20:23] = 30.0  # a 9-pixel island
    cleaned = remove_speckles(disparity, 20, 1.0)
    assert np.isnan(cleaned[21, 21]) and cleaned[5, 5] == 10.0
    assert np.count_nonzero(np.isnan(cleaned)) == 9
    assert remove_speckles(disparity, 0, 1.0) is disparity  # off


def test_hole_filling_takes_the_farther_neighbour_and_is_explicit() -> None:
    disparity = np.array(
        [[5.0, np.nan, np.nan, 20.0], [np.nan, 7.0, np.nan, np.nan], [np.nan] * 4], np.float32
    )
    filled = fill_holes(disparity)
    assert filled[0].tolist() == [5.0, 5.0, 5.0, 20.0]  # background (smaller disparity) wins
    assert filled[1].tolist() == [7.0, 7.0, 7.0, 7.0]
    assert np.isnan(filled[2]).all()  # nothing to fill from
    assert np.isnan(disparity[0, 1])  # the input is untouched


def _pipeline_results(tmp_path: Path, matcher: dict[str, object], post: dict[str, object]) -> Any:
    head = {
        "name": "front",
        "calibration": str(tmp_path / "calib.yaml"),
        "source": {
            "kind": "synthetic",
            "fps": 10,
            "seed": 2,
            "obstacles": [{"shape": "box", "forward_m": 3.0, "right_m": -0.8, "width_m": 0.8}],
        },
        "matcher": matcher,
        "postprocess": post,
    }
    tmp_path.mkdir(parents=True, exist_ok=True)
    config, calibrations = load_all(
        synthetic_config(tmp_path, "udpout:127.0.0.1:14550", heads=[head])
    )
    pipeline = HeadPipeline(config.heads[0], calibrations["front"], 20.0)
    source = open_source(config.heads[0].source, pipeline.rig, "front", paced=False)
    try:
        frame = source.read()
    finally:
        source.close()
    return pipeline, frame


def test_hole_filling_never_reaches_the_obstacles(tmp_path: Path) -> None:
    sgbm = {"kind": "sgbm", "num_disparities": 48}
    pipeline, frame = _pipeline_results(tmp_path / "a", sgbm, {})
    plain = pipeline.process(frame)
    pipeline, frame = _pipeline_results(tmp_path / "b", sgbm, {"fill_holes": True})
    filled = pipeline.process(frame)
    assert plain.filled_depth_m is None and filled.filled_depth_m is not None
    assert np.count_nonzero(np.isnan(filled.filled_depth_m)) < np.count_nonzero(
        np.isnan(filled.depth_m)
    )
    np.testing.assert_array_equal(plain.scan.distance_m, filled.scan.distance_m)
    np.testing.assert_array_equal(plain.depth_m, filled.depth_m)


def test_segment_interiors_are_kept_out_of_the_measured_depth(tmp_path: Path) -> None:
    segment = {"kind": "segment", "num_disparities": 48}
    pipeline, frame = _pipeline_results(tmp_path, segment, {"fill_holes": True})
    result = pipeline.process(frame)
    filled_by_matcher = pipeline._matcher.last_filled
    assert filled_by_matcher is not None and filled_by_matcher.any()
    assert np.isnan(result.depth_m[filled_by_matcher]).all()
    assert result.filled_depth_m is not None
    assert np.isfinite(result.filled_depth_m[filled_by_matcher]).mean() > 0.9
