"""The fast post-processing gives the same disparity as the reference implementations.

The ``_reference_*`` functions below are the implementations the fast ones replaced (issue 23),
kept here only as the reference: boolean numpy chains and whole-row accumulations. The fast
ones must agree with them exactly, pixel for pixel, on rendered frames and on random maps.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt
import pytest

from avoidd.config import NearFieldConfig, PostprocessConfig, SgbmConfig
from avoidd.sources.scene import Box, Pole, Scene
from avoidd.types import RectifiedRig
from avoidd.vision.edges import (
    ambiguous_left_edges,
    fattened_pixels,
    hidden_from_right,
    short_occlusion_gaps,
)
from avoidd.vision.fixed import FIXED_INF, to_sixteenths
from avoidd.vision.matchers import SgbmMatcher
from avoidd.vision.matchers.border import crop_padded, pad_left, run_opencv_matcher
from avoidd.vision.nearfield import NearField, unseen_behind
from avoidd.vision.postprocess import (
    _PERCENTILE_BIAS,
    QUANTISATION_SIGMA,
    fill_holes,
    median_smooth,
    noise_sigma,
    postprocess_disparity,
    refine_subpixel,
    remove_speckles,
    texture_gate,
)
from tests.helpers import noisy_grey_pair

RIG = RectifiedRig(640, 480, 400.0, 400.0, 319.5, 239.5, 0.12, 0.0)


def _reference_fattened(
    left: npt.NDArray[Any],
    right: npt.NDArray[Any],
    disparity_px: npt.NDArray[Any],
    radius_px: int,
    jump_px: float,
    noise_sigma: float,
    margin_sigmas: float = 2.0,
) -> npt.NDArray[np.bool_]:
    width = disparity_px.shape[1]
    valid = ~np.isnan(disparity_px)
    measured = np.where(valid, disparity_px, np.float32(np.inf)).astype(np.float32)
    valid_u8 = valid.astype(np.uint8)
    jump = np.float32(jump_px)

    def row_min(image: npt.NDArray[Any], half: int) -> npt.NDArray[Any]:
        kernel = np.ones((1, 2 * half + 1), dtype=np.uint8)
        return np.asarray(cv2.erode(image, kernel, borderType=cv2.BORDER_REPLICATE))

    with np.errstate(invalid="ignore"):
        step = measured - row_min(measured, radius_px) >= jump
    step |= row_min(valid_u8, radius_px) == 0
    rows, columns = np.nonzero(valid & step)
    if rows.size == 0:
        return np.zeros(valid.shape, dtype=np.bool_)
    d = disparity_px[rows, columns].astype(np.float32)
    reach = 2 * radius_px
    lowest = row_min(measured, reach)[rows, columns]
    blank = row_min(valid_u8, reach)[rows, columns] == 0
    far = np.where(lowest <= d - jump, lowest, np.where(blank, np.float32(0.0), d))
    checked = d - far >= jump
    rows, columns, d, far = rows[checked], columns[checked], d[checked], far[checked]
    left_mean = cv2.blur(left, (1, 5)).astype(np.float32)
    right_mean = cv2.blur(right, (1, 5)).astype(np.float32)

    def right_at(x: npt.NDArray[Any]) -> npt.NDArray[Any]:
        x = np.clip(x, np.float32(0.0), np.float32(width - 1.001))
        x0 = x.astype(np.int64)
        a = (x - x0).astype(np.float32)
        return np.asarray((1.0 - a) * right_mean[rows, x0] + a * right_mean[rows, x0 + 1])

    own = left_mean[rows, columns]
    at = columns.astype(np.float32)
    near_cost = np.abs(own - right_at(at - d))
    far_cost = np.abs(own - right_at(at - far))
    # Unmeasured far side: the best match over disparities 0..2 (the right view's columns
    # u - 2 .. u, clipped to the row, and every value between them).
    unseen = ~(lowest[checked] <= d - jump) & (d >= jump + np.float32(2.0))
    span = np.stack([right_mean[rows, np.maximum(columns - k, 0)] for k in range(3)])
    outside = np.maximum(span.min(axis=0) - own, own - span.max(axis=0))
    far_cost = np.where(unseen, np.minimum(far_cost, np.maximum(outside, 0.0)), far_cost)
    margin = np.float32(margin_sigmas * noise_sigma / np.sqrt(5))
    keep = _reference_vote(valid.shape, rows, columns, near_cost + margin < far_cost)
    out = np.zeros(valid.shape, dtype=np.bool_)
    out[rows[~keep], columns[~keep]] = True
    return out


def _reference_vote(
    shape: tuple[int, ...], rows: npt.NDArray[Any], columns: npt.NDArray[Any], keep: Any
) -> npt.NDArray[np.bool_]:
    """Each checked pixel kept when, of the checked pixels 6 rows up and down its column,
    more keep than not (running sums down each column)."""
    votes = np.zeros((shape[0] + 1, shape[1]), dtype=np.int64)
    votes[rows + 1, columns] = np.where(keep, 1, -1)
    running = np.cumsum(votes, axis=0)  # running[r + 1]: rows 0..r
    below = np.minimum(rows + 6, shape[0] - 1) + 1
    above = np.maximum(rows - 6, 0)
    return np.asarray(running[below, columns] - running[above, columns] > 0)


def _mask(shape: tuple[int, ...], flat: npt.NDArray[Any]) -> npt.NDArray[np.bool_]:
    out = np.zeros(shape, dtype=np.bool_)
    out.ravel()[flat] = True
    return out


def _reference_left_edges(
    left: npt.NDArray[Any],
    right: npt.NDArray[Any],
    disparity_px: npt.NDArray[Any],
    radius_px: int,
    jump_px: float,
    noise_sigma: float,
    margin_sigmas: float = 3.0,
) -> npt.NDArray[np.bool_]:
    """Pixel by pixel: walk each row's runs, check the first ``radius_px`` pixels of each run
    that starts out of nothing or with a step up, after nothing measured or something a jump
    farther."""
    height, width = disparity_px.shape
    left_mean = cv2.blur(left, (1, 5)).astype(np.float32)
    right_mean = cv2.blur(right, (1, 5)).astype(np.float32)
    jump = np.float32(jump_px)
    margin = np.float32(margin_sigmas * noise_sigma / np.sqrt(5))
    checked_rows: list[int] = []
    checked_columns: list[int] = []
    kept: list[bool] = []

    def right_at(row: int, x: np.float32) -> np.float32:
        x = np.float32(min(max(x, np.float32(0.0)), np.float32(width - 1.001)))
        x0 = int(x)
        a = np.float32(x - np.float32(x0))
        return np.float32((np.float32(1.0) - a) * right_mean[row, x0] + a * right_mean[row, x0 + 1])

    for row in range(height):
        d = disparity_px[row].astype(np.float32)
        start, rising = -1, False
        for u in range(width):
            if np.isnan(d[u]):
                start = -1
                continue
            before = d[u - 1] if u > 0 else np.float32(np.nan)
            if np.isnan(before) or not abs(d[u] - before) < jump:
                start, rising = u, not (d[u] - before <= -jump)
                # Nothing measured within twice the radius to its left, or something a
                # jump farther: a silhouette.
                earlier = d[max(u - 2 * radius_px, 0) : u]
                earlier = earlier[~np.isnan(earlier)]
                rising &= earlier.size == 0 or bool(earlier.min() <= d[u] - jump)
            if not rising or u - start >= radius_px:
                continue
            beside = np.float32(start) - d[u] - jump
            if beside < 0:
                continue
            own = left_mean[row, u]
            near_cost = abs(own - right_at(row, np.float32(u) - d[u]))
            background_cost = abs(own - right_at(row, beside))
            checked_rows.append(row)
            checked_columns.append(u)
            kept.append(bool(near_cost + margin < background_cost))
    rows, columns = np.array(checked_rows, dtype=np.int64), np.array(checked_columns, np.int64)
    out = np.zeros((height, width), dtype=np.bool_)
    if rows.size:
        keep = _reference_vote((height, width), rows, columns, np.array(kept))
        out[rows[~keep], columns[~keep]] = True
    return out


def _reference_hidden(disparity_px: npt.NDArray[Any]) -> npt.NDArray[np.bool_]:
    valid = ~np.isnan(disparity_px)
    columns = np.arange(disparity_px.shape[1], dtype=np.float32)[None, :]
    lands = np.where(valid, columns - disparity_px, np.float32(np.inf)).astype(np.float32)
    after = np.full(lands.shape, np.inf, dtype=np.float32)
    after[:, :-1] = np.minimum.accumulate(lands[:, :0:-1], axis=1)[:, ::-1]
    hidden = after <= lands + np.float32(0.5)
    return np.asarray(hidden & valid)


def _reference_short_gaps(
    disparity_px: npt.NDArray[Any], jump_px: float, max_columns: int
) -> npt.NDArray[np.bool_]:
    height, width = disparity_px.shape
    valid = ~np.isnan(disparity_px)
    starts = valid.copy()
    starts[:, 1:] &= ~valid[:, :-1]
    starts[:, 0] = False
    rows, columns = np.nonzero(starts)
    drop = np.zeros((height, width), dtype=np.bool_)
    if rows.size == 0:
        return drop
    marks = np.where(valid, np.arange(width, dtype=np.int32)[None, :], np.int32(-1))
    previous = np.maximum.accumulate(marks, axis=1)[rows, columns - 1]
    known = previous >= 0
    rows, columns, previous = rows[known], columns[known], previous[known]
    step = disparity_px[rows, columns] - disparity_px[rows, previous]
    gap = columns - previous - 1
    deficit = np.minimum(np.ceil(step - gap), max_columns).astype(np.int64)
    edge = (step >= np.float32(jump_px)) & (deficit > 0)
    for row, column, count in zip(rows[edge], columns[edge], deficit[edge], strict=True):
        run = valid[row, column : column + count]
        length = int(np.argmin(run)) if not run.all() else run.size
        drop[row, column : column + length] = True
    return drop


def _reference_median(disparity_px: npt.NDArray[Any], size: int) -> npt.NDArray[Any]:
    original = disparity_px.astype(np.float32, copy=False)
    measured = cv2.compare(original, original, cv2.CMP_EQ)
    parity = (np.arange(original.shape[0])[:, None] + np.arange(original.shape[1])[None, :]) % 2
    filled = np.where(parity == 1, np.float32(1e6), np.float32(-1e6)).astype(np.float32)
    cv2.copyTo(original, measured, filled)
    smoothed = cv2.medianBlur(filled, size)
    balanced = cv2.inRange(smoothed, -5e5, 5e5)
    result = original.copy()
    cv2.copyTo(smoothed, cv2.bitwise_and(balanced, measured), result)
    return result


def _reference_sigma(grey: npt.NDArray[Any]) -> float:
    kernel = np.array([1.0, -2.0, 1.0], dtype=np.float32)
    response = cv2.sepFilter2D(grey, cv2.CV_32F, kernel, kernel)[1:-1, 1:-1]
    magnitude = np.abs(response)
    height, width = magnitude.shape
    rows, columns = height // 16, width // 16
    if rows and columns:
        means = cv2.resize(
            magnitude[: rows * 16, : columns * 16], (columns, rows), interpolation=cv2.INTER_AREA
        )
        level = float(np.percentile(means, 10.0)) / _PERCENTILE_BIAS
    else:
        level = float(np.mean(magnitude))
    return float(np.sqrt(np.pi / 2.0) / 6.0 * level)


def _reference_gate(grey: npt.NDArray[Any], n: int, min_snr: float) -> npt.NDArray[np.bool_]:
    ones, one = np.ones(n, np.float32), np.ones(1, np.float32)
    border = cv2.BORDER_REFLECT
    total = cv2.sepFilter2D(grey, cv2.CV_32F, ones, one, borderType=border)
    squares = cv2.multiply(grey, grey, dtype=cv2.CV_32F)
    total_sq = cv2.sepFilter2D(squares, -1, ones, one, borderType=border)
    spread = cv2.scaleAdd(total_sq, float(n), cv2.multiply(total, total, scale=-1.0))
    summed = cv2.sepFilter2D(spread, -1, one, ones, borderType=border)
    sigma = max(_reference_sigma(grey), QUANTISATION_SIGMA)
    threshold = min_snr * min_snr * sigma * sigma * (1.0 - 1.0 / n) * n * n * n
    return np.asarray(summed >= np.float32(threshold), dtype=np.bool_)


def _random_map(rng: np.random.Generator, height: int, width: int, fine: bool) -> Any:
    """Rows of constant runs (some NaN) at random disparities: many edges of every kind."""
    out = np.empty((height, width), dtype=np.float32)
    for row in range(height):
        column = 0
        while column < width:
            length = int(rng.integers(1, 30))
            if rng.random() < 0.3:
                value = np.nan
            elif fine:
                value = rng.uniform(0.0, 80.0)
            else:
                value = rng.integers(0, 64 * 16) / 16.0
            out[row, column : column + length] = value
            column += length
    if fine:  # sloped surfaces too
        out += rng.normal(0.0, 0.3, out.shape).astype(np.float32)
    return out


def _checks(left: Any, right: Any, disparity: Any, radius: int, jump: float) -> None:
    """Every edge check, fast against reference, each on the map the previous one left."""
    d = disparity.copy()
    hidden = hidden_from_right(d)
    np.testing.assert_array_equal(hidden, _reference_hidden(d))
    d[hidden] = np.nan
    short = short_occlusion_gaps(d, jump, 2 * radius)
    np.testing.assert_array_equal(short, _reference_short_gaps(d, jump, 2 * radius))
    d[short] = np.nan
    sigma = noise_sigma(left)
    fattened = fattened_pixels(left, right, d, radius, jump, sigma)
    np.testing.assert_array_equal(
        fattened, _reference_fattened(left, right, d, radius, jump, sigma)
    )
    d[fattened] = np.nan
    np.testing.assert_array_equal(
        _mask(d.shape, ambiguous_left_edges(left, right, d, radius, jump, sigma)),
        _reference_left_edges(left, right, d, radius, jump, sigma),
    )
    # And each check alone on the map as it came (not cleaned by the ones before).
    np.testing.assert_array_equal(
        short_occlusion_gaps(disparity, jump, 2 * radius),
        _reference_short_gaps(disparity, jump, 2 * radius),
    )
    np.testing.assert_array_equal(
        fattened_pixels(left, right, disparity, radius, jump, sigma),
        _reference_fattened(left, right, disparity, radius, jump, sigma),
    )


@pytest.mark.parametrize("seed", range(6))
def test_edge_checks_match_the_reference_on_random_maps(seed: int) -> None:
    rng = np.random.default_rng(seed)
    height, width = int(rng.integers(1, 40)), int(rng.integers(2, 300))
    left = rng.integers(0, 256, (height, width), dtype=np.uint8)
    right = rng.integers(0, 256, (height, width), dtype=np.uint8)
    disparity = _random_map(rng, height, width, fine=seed % 2 == 1)
    radius, jump = int(rng.integers(1, 17)), float(rng.uniform(0.5, 8.0))
    _checks(left, right, disparity, radius, jump)


def test_edge_checks_match_the_reference_at_the_extremes() -> None:
    rng = np.random.default_rng(7)
    left = rng.integers(0, 256, (5, 50), dtype=np.uint8)
    right = rng.integers(0, 256, (5, 50), dtype=np.uint8)
    for disparity in (
        np.full((5, 50), np.nan, dtype=np.float32),  # nothing measured
        np.full((5, 50), 12.0, dtype=np.float32),  # no edge at all
        np.where(rng.random((5, 50)) < 0.5, np.nan, 30.0).astype(np.float32),  # salt
        np.tile(np.arange(50, dtype=np.float32), (5, 1)),  # a slope steeper than 1 px/px
    ):
        _checks(left, right, disparity, 8, 2.0)
    one_column = np.array([[3.0], [np.nan]], dtype=np.float32)
    np.testing.assert_array_equal(hidden_from_right(one_column), _reference_hidden(one_column))
    np.testing.assert_array_equal(
        short_occlusion_gaps(one_column, 2.0, 16), _reference_short_gaps(one_column, 2.0, 16)
    )


def _scenes() -> list[Scene]:
    return [
        Scene(
            camera_height_m=1.5,
            camera_pitch_deg=0.0,
            obstacles=(
                Box(2.5, -1.3, 0.6, 1.0, 2.5),
                Pole(3.4, 0.2, 0.25, 3.0),
                Box(4.6, 1.6, 0.8, 1.4, 3.0),
            ),
            backdrop_m=40.0,
            seed=11,
        ),
        Scene(  # a box nearer than the main range: the near-field pass measures it
            camera_height_m=1.2,
            camera_pitch_deg=5.0,
            obstacles=(Box(0.5, 0.3, 0.4, 0.5, 1.5), Pole(6.0, -1.0, 0.05, 3.0)),
            backdrop_m=25.0,
            seed=3,
        ),
    ]


@pytest.fixture(scope="module")
def rendered() -> list[tuple[Any, Any, Any]]:
    """Left, right and the matched, merged, median-smoothed disparity of rendered scenes."""
    matcher = SgbmMatcher(SgbmConfig(num_disparities=64, pad_left=True))
    near = NearField(64, NearFieldConfig())
    post = PostprocessConfig()
    out = []
    for seed, scene in enumerate(_scenes()):
        left, right, _ = noisy_grey_pair(scene, RIG, seed, 1.5)
        disparity = near.apply(left, right, matcher.compute(left, right)).disparity
        out.append((left, right, median_smooth(disparity, post.median_size)))
    return out


def test_edge_checks_match_the_reference_on_rendered_frames(
    rendered: list[tuple[Any, Any, Any]],
) -> None:
    post = PostprocessConfig()
    for left, right, disparity in rendered:
        _checks(left, right, disparity, post.edge_radius_px, post.edge_jump_px)


def _reference_block(
    left: Any,
    right: Any,
    disparity: Any,
    post: PostprocessConfig,
    texture: Any,
    filled_by_matcher: Any,
) -> tuple[Any, Any, Any]:
    """The post block of ``HeadPipeline.process`` as it was, on the reference checks."""
    if post.subpixel_refine:
        disparity = refine_subpixel(left, right, disparity, post.refine_window_px)
    if post.median_size:
        disparity = _reference_median(disparity, post.median_size)
    disparity = remove_speckles(disparity, post.speckle_window_px, post.speckle_range_px)
    disparity = disparity.copy()
    if texture is not None:
        disparity[~texture] = np.nan
    textured = texture
    if post.min_texture_snr > 0:
        gate = _reference_gate(left, post.texture_window_px, post.min_texture_snr)
        disparity[~gate] = np.nan
        textured = gate if textured is None else textured & gate
    if post.edge_radius_px:
        disparity[_reference_hidden(disparity)] = np.nan
        short = _reference_short_gaps(disparity, post.edge_jump_px, 2 * post.edge_radius_px)
        disparity[short] = np.nan
        fattened = _reference_fattened(
            left, right, disparity, post.edge_radius_px, post.edge_jump_px, _reference_sigma(left)
        )
        disparity[fattened] = np.nan
        ambiguous = _reference_left_edges(
            left, right, disparity, post.edge_radius_px, post.edge_jump_px, _reference_sigma(left)
        )
        disparity[ambiguous] = np.nan
    filled_display = fill_holes(disparity) if post.fill_holes else None
    if filled_by_matcher is not None:
        disparity[filled_by_matcher] = np.nan
    return disparity, textured, filled_display


POST_CONFIGS = [
    PostprocessConfig(),
    PostprocessConfig(fill_holes=True, speckle_window_px=50, median_size=3),
    PostprocessConfig(subpixel_refine=True, median_size=0, edge_radius_px=4, edge_jump_px=1.0),
    PostprocessConfig(min_texture_snr=0.0, edge_radius_px=0),
]


@pytest.mark.parametrize("config", range(len(POST_CONFIGS)))
def test_the_whole_post_block_matches_the_reference(
    rendered: list[tuple[Any, Any, Any]], config: int
) -> None:
    post = POST_CONFIGS[config]
    rng = np.random.default_rng(config)
    for left, right, disparity in rendered:
        texture = rng.random(left.shape) < 0.9 if config % 2 else None
        filled = rng.random(left.shape) < 0.05 if config >= 2 else None
        before = disparity.copy()
        result = postprocess_disparity(left, right, disparity, post, texture, filled)
        expected = _reference_block(left, right, disparity, post, texture, filled)
        np.testing.assert_array_equal(disparity, before)  # the input is left alone
        np.testing.assert_array_equal(result.disparity, expected[0])
        for got, want in ((result.textured, expected[1]), (result.filled, expected[2])):
            assert (got is None) == (want is None)
            if got is not None:
                np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("seed", range(4))
def test_median_and_texture_gate_match_the_reference(seed: int) -> None:
    rng = np.random.default_rng(100 + seed)
    height, width = int(rng.integers(3, 60)), int(rng.integers(3, 200))
    disparity = _random_map(rng, height, width, fine=seed % 2 == 1)
    for size in (3, 5):
        np.testing.assert_array_equal(
            median_smooth(disparity, size), _reference_median(disparity, size)
        )
    grey = rng.integers(0, 256, (height, width), dtype=np.uint8)
    grey[:, : width // 2] = rng.integers(100, 103, (height, width // 2), dtype=np.uint8)
    assert noise_sigma(grey) == _reference_sigma(grey)
    for window in (3, 7, 11):
        np.testing.assert_array_equal(
            texture_gate(grey, window, 1.5), _reference_gate(grey, window, 1.5)
        )
        sigma = noise_sigma(grey)
        np.testing.assert_array_equal(
            texture_gate(grey, window, 1.5, sigma), _reference_gate(grey, window, 1.5)
        )


def test_median_and_texture_gate_match_the_reference_on_rendered_frames(
    rendered: list[tuple[Any, Any, Any]],
) -> None:
    for left, right, disparity in rendered:
        assert noise_sigma(left) == _reference_sigma(left)
        assert noise_sigma(right) == _reference_sigma(right)
        np.testing.assert_array_equal(median_smooth(disparity, 5), _reference_median(disparity, 5))
        np.testing.assert_array_equal(texture_gate(left, 7, 1.5), _reference_gate(left, 7, 1.5))


def test_threads_do_not_share_scratch_arrays(rendered: list[tuple[Any, Any, Any]]) -> None:
    # Two heads post-processed at once in two threads give what each gives alone.
    post = PostprocessConfig()
    alone = [
        postprocess_disparity(frame[0], frame[1], frame[2], post).disparity for frame in rendered
    ]
    with ThreadPoolExecutor(max_workers=2) as pool:
        for _ in range(3):
            together = list(
                pool.map(lambda f: postprocess_disparity(f[0], f[1], f[2], post), rendered)
            )
            for want, got in zip(alone, together, strict=True):
                np.testing.assert_array_equal(got.disparity, want)


def _reference_opencv(
    matcher: Any, left: Any, right: Any, pad: int, min_disparity: int
) -> npt.NDArray[Any]:
    if pad:
        left, right = pad_left(left, pad), pad_left(right, pad)
    raw = np.asarray(matcher.compute(left, right), dtype=np.int16)
    disparity = raw.astype(np.float32) * np.float32(1.0 / 16.0)
    disparity[raw < min_disparity * 16] = np.nan
    return crop_padded(disparity, pad) if pad else disparity


@pytest.mark.parametrize(("pad", "min_disparity"), [(0, 0), (64, 0), (32, -8), (0, 4)])
def test_the_opencv_wrapper_matches_the_reference(pad: int, min_disparity: int) -> None:
    left, right, _ = noisy_grey_pair(_scenes()[1], RIG, 9, 1.5)
    sgbm = cv2.StereoSGBM.create(minDisparity=min_disparity, numDisparities=64, blockSize=5)
    bm = cv2.StereoBM.create(numDisparities=64, blockSize=15)
    for matcher, low in ((sgbm, min_disparity), (bm, 0)):
        np.testing.assert_array_equal(
            run_opencv_matcher(matcher, left, right, pad, low),
            _reference_opencv(matcher, left, right, pad, low),
        )


def _reference_unseen(disparity: Any, near: Any) -> npt.NDArray[np.bool_]:
    hidden = np.zeros(near.shape, dtype=np.bool_)
    rows = np.flatnonzero(near.any(axis=1))
    if rows.size == 0:
        return hidden
    columns = np.arange(near.shape[1], dtype=np.float32)[None, :]
    near_rows = near[rows]
    reach = np.where(near_rows, disparity[rows], np.float32(0.0))
    start = np.where(near_rows, columns - reach, np.float32(np.inf))
    covered_from = np.minimum.accumulate(start[:, ::-1], axis=1)[:, ::-1]
    hidden[rows] = covered_from <= columns
    hidden[:, : int(np.ceil(float(reach.max())))] = True
    hidden &= ~near
    return hidden


@pytest.mark.parametrize("seed", range(4))
def test_the_near_field_shadow_matches_the_reference(seed: int) -> None:
    rng = np.random.default_rng(200 + seed)
    height, width = int(rng.integers(1, 30)), int(rng.integers(1, 400))
    disparity = rng.uniform(0.0, 120.0, (height, width)).astype(np.float32)
    near = rng.random((height, width)) < (0.02 if seed % 2 else 0.3)
    np.testing.assert_array_equal(
        unseen_behind(disparity, near), _reference_unseen(disparity, near)
    )


def test_the_near_field_merge_matches_the_reference_on_a_near_box() -> None:
    left, right, _ = noisy_grey_pair(_scenes()[1], RIG, 4, 1.5)
    main = SgbmMatcher(SgbmConfig(num_disparities=64)).compute(left, right)
    field = NearField(64, NearFieldConfig())
    coarse = field.coarse(left, right)
    result = field.merge(main, coarse)
    # The reference merge.
    merged = main.copy()
    near = coarse >= np.float32(64 - 1 - field.scale)
    saturated = coarse >= np.float32(field.max_disparity_px - field.scale)
    merged[near] = coarse[near]
    merged[saturated] = np.float32(field.max_disparity_px)
    hidden = _reference_unseen(merged, near)
    merged[hidden] = np.nan
    assert near.any()
    np.testing.assert_array_equal(result.disparity, merged)
    np.testing.assert_array_equal(result.near, near)


def test_sixteenths_only_when_exact() -> None:
    whole = np.array([[0.0, 1.0625, -3.5, np.nan], [1999.9375, -2000.0, 12.0, 0.5]], np.float32)
    fixed = to_sixteenths(whole, FIXED_INF, "test.sixteenths")
    assert fixed is not None
    np.testing.assert_array_equal(fixed, [[0, 17, -56, FIXED_INF], [31999, -32000, 192, 8]])
    assert to_sixteenths(whole, 0, "test.sixteenths")[0, 3] == 0  # type: ignore[index]
    for bad in (1.03125, 2000.0625, np.inf, 0.01):  # a 32nd, beyond the range, inf, a guess
        off = whole.copy()
        off[1, 2] = bad
        assert to_sixteenths(off, FIXED_INF, "test.sixteenths") is None
