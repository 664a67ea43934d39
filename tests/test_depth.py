from __future__ import annotations

import cv2
import numpy as np
import pytest

from avoidd.config import PostprocessConfig, SgbmConfig
from avoidd.sources.scene import FIRST_OBSTACLE_ID, Box, Pole, Scene
from avoidd.types import RectifiedRig
from avoidd.vision.depth import depth_from_disparity, disparity_from_depth
from avoidd.vision.matchers import SgbmMatcher
from avoidd.vision.postprocess import median_smooth, noise_sigma, refine_subpixel, texture_gate
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
    assert depth[0, 3] == np.inf  # d + doffs == 0: at infinity, measured far
    # d + doffs < 0 would put the point behind the cameras: no measurement, never "far"
    # (a calibration with doffs -1000 once made every pixel read far, every bin clear).
    assert np.isnan(depth[0, 4])
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


def _depth(left: np.ndarray, right: np.ndarray, post: PostprocessConfig) -> np.ndarray:
    disparity = SgbmMatcher(SgbmConfig()).compute(left, right)
    if post.subpixel_refine:
        disparity = refine_subpixel(left, right, disparity, post.refine_window_px)
    disparity = median_smooth(disparity, post.median_size)
    return depth_from_disparity(disparity, RIG)


def test_synthetic_depth_within_two_percent_with_refinement(near_scene: tuple) -> None:
    # The renderer's textures lock SGBM to whole pixels harder than real images do (41% of
    # disparities within 1/16 px of a whole pixel, against 29-32% on Middlebury 2014 and
    # 2003), so this is where the optional refinement step shows what it is for.
    left, right, truth = near_scene
    depth = _depth(left, right, PostprocessConfig(subpixel_refine=True))
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


def test_refinement_leaves_windows_without_gradient_alone() -> None:
    rng = np.random.default_rng(1)
    left = np.full((40, 80), 120, dtype=np.uint8)
    left[:, 50:] = rng.integers(0, 255, (40, 30), dtype=np.uint8)
    right = np.roll(left, -3, axis=1)
    disparity = np.full((40, 80), 3.3, dtype=np.float32)
    disparity[5, 5] = np.nan
    refined = refine_subpixel(left, right, disparity, 7)
    # Flat on both sides (away from the warp's zero border on the left): no gradient in the
    # window, no step (not a division by about zero).
    assert np.array_equal(refined[:, 9:44], disparity[:, 9:44], equal_nan=True)
    assert np.isnan(refined[5, 5])
    # Textured: the step moves toward the true 3 px from the 3.3 px start.
    assert np.all(refined[10:-10, 58:-8] < 3.3)


def test_median_smooth_sizes() -> None:
    data = np.ones((7, 7), dtype=np.float32)
    data[2, 2] = 9.0  # a spike whose windows are fully measured
    data[6, 6] = np.nan
    for size in (3, 5):
        smoothed = median_smooth(data, size)
        assert smoothed[2, 2] == 1.0 and np.isnan(smoothed[6, 6])
        assert np.count_nonzero(np.isnan(smoothed)) == 1
    assert median_smooth(data, 0)[2, 2] == 9.0
    with pytest.raises(ValueError, match="median size must be 0, 3 or 5"):
        median_smooth(data, 7)


def test_median_never_pulls_a_hole_edge_toward_zero() -> None:
    # A wire (1 px) and a pole (2 px) seen against unmatched sky: most of each window is holes.
    data = np.full((12, 16), np.nan, dtype=np.float32)
    data[:, 4] = 40.0
    data[:, 9:11] = 30.0
    data[6, 9] = 33.0  # a spike on the pole: the median of the measured pixels removes it
    expected = data.copy()
    expected[6, 9] = 30.0
    for size in (3, 5):
        smoothed = median_smooth(data, size)
        assert np.array_equal(smoothed, expected, equal_nan=True)


def test_median_of_the_measured_pixels_where_holes_are_many() -> None:
    rng = np.random.default_rng(4)
    data = rng.uniform(10.0, 20.0, (40, 40)).astype(np.float32)
    data[rng.random((40, 40)) < 0.4] = np.nan
    smoothed = median_smooth(data, 5)
    assert np.array_equal(np.isnan(smoothed), np.isnan(data))
    parity = np.indices(data.shape).sum(axis=0) % 2
    checked = 0
    for y in range(2, 38):
        for x in range(2, 38):
            if np.isnan(data[y, x]):
                continue
            window = data[y - 2 : y + 3, x - 2 : x + 3]
            holes = np.isnan(window)
            measured = np.sort(window[~holes])
            # Holes on odd cells count above every value, on even cells below: the median
            # is the measured median moved by half the imbalance, in ranks.
            above = int(np.count_nonzero(holes & (parity[y - 2 : y + 3, x - 2 : x + 3] == 1)))
            below = int(np.count_nonzero(holes)) - above
            rank = 12 - below
            if 0 <= rank < measured.size:
                assert smoothed[y, x] == measured[rank]
                assert abs(rank - (measured.size - 1) / 2) == abs(above - below) / 2
                checked += 1
            else:
                assert smoothed[y, x] == data[y, x]
    assert checked > 500


def test_grey_conversion_shapes() -> None:
    bgr = np.zeros((4, 5, 3), dtype=np.uint8)
    bgr[..., 2] = 255
    assert to_grey(bgr).shape == (4, 5)
    assert to_grey(bgr)[0, 0] == 76  # ITU-R BT.601 weight of red
    assert to_grey(bgr[..., :1]).shape == (4, 5)
    with pytest.raises(ValueError, match="8-bit"):
        to_grey(np.zeros((2, 2), dtype=np.float32))  # type: ignore[arg-type]


def _textured_half(noise_std: float, seed: int = 0) -> np.ndarray:
    """Fine, strong texture on the left half, a smooth ramp on the right, Gaussian noise."""
    rng = np.random.default_rng(seed)
    image = np.tile(np.linspace(60.0, 190.0, 320, dtype=np.float32), (240, 1))
    texture = cv2.GaussianBlur(rng.uniform(0, 255, (240, 160)).astype(np.float32), (0, 0), 0.7)
    image[:, :160] = texture
    image += rng.normal(0.0, noise_std, image.shape).astype(np.float32)
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)


@pytest.mark.parametrize("noise_std", [0.7, 1.5, 3.0])
def test_noise_estimate_is_not_fooled_by_fine_texture(noise_std: float) -> None:
    grey = _textured_half(noise_std)
    assert noise_sigma(grey) == pytest.approx(noise_std, rel=0.15)
    # Averaged over the whole image, the texture would read far above the noise.
    response = cv2.filter2D(
        grey.astype(np.float32), -1, np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)
    )[1:-1, 1:-1]
    whole_image = float(np.sqrt(np.pi / 2.0) / 6.0 * np.mean(np.abs(response)))
    assert whole_image > 1.5 * noise_std


def test_texture_gate_keeps_texture_and_drops_flat_and_horizontal_stripes() -> None:
    rng = np.random.default_rng(4)
    image = np.full((120, 240), 128.0, dtype=np.float32)  # flat: the sky
    image[:, 80:160] = np.tile(rng.uniform(40, 220, (1, 80)), (120, 1))  # vertical structure
    image[:, 160:] = np.repeat(rng.uniform(40, 220, (120, 1)), 80, axis=1)  # horizontal stripes
    image += rng.normal(0.0, 1.5, image.shape).astype(np.float32)
    grey = np.clip(np.rint(image), 0, 255).astype(np.uint8)
    gate = texture_gate(grey, 7, 1.5)
    inner = (slice(10, -10),)
    assert gate[inner][:, 90:150].mean() > 0.95
    assert gate[inner][:, 5:70].mean() < 0.05
    assert gate[inner][:, 170:235].mean() < 0.05


@pytest.mark.parametrize("window_px", [3, 7, 15])
def test_texture_gate_is_the_row_segment_variance_against_the_noise(window_px: int) -> None:
    # The definition computed the slow way: the variance of every row segment of the window,
    # averaged over its rows, against min_snr^2 times the noise variance of such a segment.
    rng = np.random.default_rng(window_px)
    image = cv2.GaussianBlur(rng.uniform(0, 255, (60, 90)).astype(np.float32), (0, 0), 1.2)
    image[:, 30:60] = 128.0 + 3.0 * (image[:, 30:60] - 128.0) / 17.0  # faint: near the threshold
    image[:, 60:] = 128.0  # flat
    image += rng.normal(0.0, 2.0, image.shape)
    grey = np.clip(np.rint(image), 0, 255).astype(np.uint8)
    half = window_px // 2
    padded = np.pad(grey.astype(np.float64), half, mode="symmetric")  # OpenCV's BORDER_REFLECT
    windows = np.lib.stride_tricks.sliding_window_view(padded, (window_px, window_px))
    variance = windows.var(axis=3).mean(axis=2)
    sigma = noise_sigma(grey)
    threshold = 1.5**2 * sigma**2 * (1.0 - 1.0 / window_px)
    gate = texture_gate(grey, window_px, 1.5)
    clear = np.abs(variance - threshold) > 1e-4 * threshold  # away from float rounding
    assert clear.mean() > 0.99
    np.testing.assert_array_equal(gate[clear], (variance >= threshold)[clear])
    assert 0.05 < gate.mean() < 0.95  # both sides of the threshold are exercised
