from __future__ import annotations

import cv2
import numpy as np
import pytest

from avoidd.config import PostprocessConfig, SgbmConfig
from avoidd.sources.scene import FIRST_OBSTACLE_ID, Box, Pole, Scene
from avoidd.types import RectifiedRig
from avoidd.vision.depth import depth_from_disparity, disparity_from_depth
from avoidd.vision.matchers import SgbmMatcher
from avoidd.vision.postprocess import median_smooth, refine_subpixel
from avoidd.vision.preprocess import to_grey
from tests.helpers import noisy_grey_pair

RIG = RectifiedRig(640, 480, 400.0, 400.0, 319.5, 239.5, 0.12, 0.0)


def test_depth_formula_with_doffs() -> None:
    rig = RectifiedRig(100, 50, 1000.0, 1000.0, 50.0, 25.0, 0.2, 10.0)
    disparity = np.array([[90.0, 40.0, np.nan, -10.0, -20.0]], dtype=np.float32)
    depth = depth_from_disparity(disparity, rig)
    assert depth[0, 0] == pytest.approx(1000 * 0.2 / 100.0)
    assert depth[0, 1] == pytest.approx(1000 * 0.2 / 50.0)
    assert np.isnan(depth[0, 2])
    assert depth[0, 3] == np.inf and depth[0, 4] == np.inf
    back = disparity_from_depth(depth[:, :2], rig)
    np.testing.assert_allclose(back, disparity[:, :2], rtol=1e-6)


def _pair(scene: Scene, seed: int) -> tuple[np.ndarray, np.ndarray, object]:
    return noisy_grey_pair(scene, RIG, seed, 1.5)


@pytest.fixture(scope="module")
def near_scene() -> tuple[np.ndarray, np.ndarray, object]:
    # Obstacles within the rig's useful range (one pixel of disparity <= 10% of depth: 4.8 m).
    scene = Scene(
        camera_height_m=1.5,
        camera_pitch_deg=0.0,
        obstacles=(
            Box(2.5, -1.3, 0.6, 1.0, 2.5),
            Pole(3.4, 0.2, 0.25, 3.0),
            Box(4.6, 1.6, 0.8, 1.4, 3.0),
        ),
        backdrop_m=40.0,
        seed=11,
    )
    return _pair(scene, 5)


def _depth(left: np.ndarray, right: np.ndarray, refine: bool) -> np.ndarray:
    disparity = SgbmMatcher(SgbmConfig()).compute(left, right)
    post = PostprocessConfig()
    if refine:
        disparity = refine_subpixel(left, right, disparity, post.refine_window_px)
        disparity = median_smooth(disparity, post.median_size)
    return depth_from_disparity(disparity, RIG)


def test_synthetic_depth_within_two_percent(near_scene: tuple) -> None:
    left, right, truth = near_scene
    depth = _depth(left, right, refine=True)
    matchable = np.zeros(depth.shape, dtype=bool)
    matchable[:, SgbmConfig().num_disparities :] = True  # the left border has no partner
    for offset in range(3):
        surface = (truth.object_id == FIRST_OBSTACLE_ID + offset) & matchable
        valid = surface & np.isfinite(depth)
        assert valid.sum() > 0.8 * surface.sum()
        relative = depth[valid] / truth.depth_m[valid] - 1.0
        assert abs(np.median(relative)) < 0.02
        # Away from depth edges (where every window-based matcher mixes two surfaces), most
        # pixels, not just the median, are within 2%.
        interior = cv2.erode(surface.astype(np.uint8), np.ones((9, 9), np.uint8)) > 0
        inside = interior & np.isfinite(depth)
        relative = depth[inside] / truth.depth_m[inside] - 1.0
        assert np.mean(np.abs(relative) < 0.02) > 0.85


def test_subpixel_refinement_removes_whole_pixel_locking(near_scene: tuple) -> None:
    left, right, truth = near_scene
    surface = (truth.object_id >= FIRST_OBSTACLE_ID) & np.isfinite(truth.depth_m)
    gt = disparity_from_depth(truth.depth_m, RIG)
    raw = SgbmMatcher(SgbmConfig()).compute(left, right)
    refined = refine_subpixel(left, right, raw, 7)
    valid = surface & np.isfinite(raw)
    raw_error = np.abs(raw[valid] - gt[valid])
    refined_error = np.abs(refined[valid] - gt[valid])
    assert np.median(refined_error) < 0.8 * np.median(raw_error)

    # SGBM piles disparities up on whole pixels; after refinement the fractions spread out.
    def near_integer(d: np.ndarray) -> float:
        return float(np.mean(np.abs(d - np.rint(d)) < 0.0625))

    assert near_integer(refined[valid]) < 0.5 * near_integer(raw[valid])


def test_refinement_keeps_invalid_pixels_invalid() -> None:
    rng = np.random.default_rng(0)
    left = rng.integers(0, 255, (60, 80), dtype=np.uint8)
    right = np.roll(left, -4, axis=1)
    disparity = np.full((60, 80), 4.0, dtype=np.float32)
    disparity[:, :10] = np.nan
    refined = refine_subpixel(left, right, disparity, 7)
    assert np.isnan(refined[:, :10]).all()
    inner = refined[10:-10, 20:-10]
    assert np.all(np.abs(inner - 4.0) <= 0.5)
    assert np.median(np.abs(inner - 4.0)) < 0.05


def test_median_smooth_sizes() -> None:
    data = np.array([[1, 1, 1], [1, 9, 1], [1, 1, np.nan]], dtype=np.float32)
    smoothed = median_smooth(data, 3)
    assert smoothed[1, 1] == 1.0 and np.isnan(smoothed[2, 2])
    assert median_smooth(data, 0) is not None
    with pytest.raises(ValueError, match="median size must be 0, 3 or 5"):
        median_smooth(data, 7)


def test_grey_conversion_shapes() -> None:
    bgr = np.zeros((4, 5, 3), dtype=np.uint8)
    bgr[..., 2] = 255
    assert to_grey(bgr).shape == (4, 5)
    assert to_grey(bgr)[0, 0] == 76  # ITU-R BT.601 weight of red
    assert to_grey(bgr[..., :1]).shape == (4, 5)
    with pytest.raises(ValueError, match="8-bit"):
        to_grey(np.zeros((2, 2), dtype=np.float32))  # type: ignore[arg-type]
