"""Disparity post-processing shared by the matchers.

Left-right consistency, speckle removal, sub-pixel refinement, median smoothing, and hole
filling. Hole filling invents values: its result is for display and recordings only, never for
obstacle detection (``avoidd.pipeline`` keeps the measured map for that).
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import cv2
import numpy as np
import numpy.typing as npt

from avoidd.config import PostprocessConfig
from avoidd.types import BoolArray, FloatArray, Image
from avoidd.vision.edges import (
    ambiguous_left_edges,
    column_means,
    fattened_indices,
    hidden_from_right,
    short_gap_indices,
)
from avoidd.vision.fixed import FIXED_INF, FIXED_LIMIT, to_sixteenths
from avoidd.vision.scratch import scratch


def refine_subpixel(
    left: Image, right: Image, disparity_px: FloatArray, window_px: int = 7
) -> FloatArray:
    """Refine a disparity map to sub-pixel precision with one Gauss-Newton step per pixel.

    Semi-global matching with a sampling-insensitive cost tends to lock disparities to whole
    pixels. This step warps the right view by the current disparity and solves, over a square
    window, the 1-D least-squares shift that best aligns it with the left view (Lucas-Kanade along
    the epipolar line). Updates are limited to half a pixel, so the step never changes which
    surface a pixel belongs to. Invalid pixels stay invalid.

    Args:
        left: Rectified left view, (H, W) uint8.
        right: Rectified right view, same shape.
        disparity_px: Disparity of the left view, NaN where invalid.
        window_px: Side of the square window of the least-squares fit (odd).

    Returns:
        The refined disparity, float32, NaN where the input is NaN.
    """
    height, width = disparity_px.shape
    # Invalid pixels are warped by zero (any value would do) and stay NaN in the sum below.
    current = cv2.patchNaNs(disparity_px.astype(np.float32, copy=True), 0.0)
    columns, rows = _pixel_grid(height, width)
    map_x = cv2.subtract(columns, current)
    # Remapping the 8-bit image is twice as fast as remapping floats and loses nothing the
    # one-step fit can use (OpenCV interpolates 8-bit images in fixed point, 1/32 px).
    warped = cv2.remap(right, map_x, rows, cv2.INTER_LINEAR)
    gradient = cv2.Sobel(warped, cv2.CV_32F, 1, 0, ksize=3, scale=0.125)
    residual = cv2.subtract(left, warped, dtype=cv2.CV_32F)
    size = (window_px, window_px)
    numerator = cv2.boxFilter(cv2.multiply(gradient, residual), -1, size, normalize=False)
    denominator = cv2.boxFilter(cv2.multiply(gradient, gradient), -1, size, normalize=False)
    # Gradients of the 8-bit warp are multiples of 1/8, so a window with any gradient has a
    # denominator of at least 1/64; below 1e-3 there is none (rounding residue), the
    # numerator is as small, and the step comes out about zero: nothing to fit.
    np.maximum(denominator, np.float32(1e-3), out=denominator)
    step = np.asarray(cv2.divide(numerator, denominator, scale=-1.0), np.float32)
    np.clip(step, -0.5, 0.5, out=step)
    return np.asarray(cv2.add(disparity_px.astype(np.float32, copy=False), step), np.float32)


_GRIDS: dict[tuple[int, int], tuple[FloatArray, FloatArray]] = {}


def _pixel_grid(height: int, width: int) -> tuple[FloatArray, FloatArray]:
    """Column and row coordinates of every pixel (cached per image size)."""
    grid = _GRIDS.get((height, width))
    if grid is None:
        columns = np.tile(np.arange(width, dtype=np.float32), (height, 1))
        rows = np.repeat(np.arange(height, dtype=np.float32)[:, None], width, axis=1)
        grid = _GRIDS[(height, width)] = (columns, rows)
    return grid


_HOLE_FILL = np.float32(1e6)
"""Stand-in for holes in the median: far outside any disparity, so it never passes for one."""

_CHECKERS: dict[tuple[int, int, str], npt.NDArray[Any]] = {}


def _checker_fill(height: int, width: int, dtype: npt.DTypeLike = np.float32) -> npt.NDArray[Any]:
    """The holes' stand-ins, high and low in a checkerboard (cached per image size and type)."""
    key = (height, width, np.dtype(dtype).str)
    fill = _CHECKERS.get(key)
    if fill is None:
        parity = (np.arange(height)[:, None] + np.arange(width)[None, :]) % 2
        high = _HOLE_FILL if np.dtype(dtype) == np.float32 else FIXED_INF
        fill = _CHECKERS[key] = np.where(parity == 1, high, -high).astype(dtype)
    return fill


def median_smooth(disparity_px: FloatArray, size: int) -> FloatArray:
    """Median-filter a disparity map over the measured pixels of each window.

    OpenCV's median has no NaN, so holes go in as a checkerboard of a very low and a very high
    stand-in. The window's median is then the median of its measured pixels moved by half the
    difference between its high and low stand-ins, in ranks: at most half a rank where holes
    fill whole rows or columns of the window (a straight hole edge), more only where they lie
    on one colour of the board (a diagonal line of holes). Counting holes as one number
    instead would pull every hole's edge toward that number, and a wire or a pole seen against
    unmatched sky would vanish. Where the median lands on a stand-in (a window almost all
    holes), the pixel keeps its own value.

    Args:
        disparity_px: Disparity, NaN where invalid.
        size: 3 or 5 (OpenCV's float median); 0 or 1 returns the input.

    Returns:
        The smoothed disparity, float32, NaN exactly where the input is NaN.

    Raises:
        ValueError: ``size`` is not 0, 1, 3 or 5.
    """
    if size in (0, 1):
        return disparity_px.astype(np.float32, copy=False)
    if size not in (3, 5):
        raise ValueError(f"median size must be 0, 3 or 5, got {size}")
    original = np.ascontiguousarray(disparity_px, dtype=np.float32)
    shape = original.shape
    measured = cv2.compare(original, original, cv2.CMP_EQ)  # 255 where not NaN
    # Whole sixteenths (SGBM, BM, the near-field pass): OpenCV's 16-bit median, three times
    # faster than its float one, gives the same map (a median picks one of its inputs).
    fixed = to_sixteenths(original, 0, "postprocess.median_smooth.sixteenths")
    if fixed is None:
        filled = scratch("postprocess.median_smooth", shape, np.float32)
        np.copyto(filled, _checker_fill(shape[0], shape[1]))
        cv2.copyTo(original, measured, filled)
        smoothed = cv2.medianBlur(filled, size)
        limit = float(_HOLE_FILL / 2)
        keep = cv2.bitwise_and(cv2.inRange(smoothed, -limit, limit), measured)
    else:
        filled16 = scratch("postprocess.median_smooth.fixed", shape, np.int16)
        np.copyto(filled16, _checker_fill(shape[0], shape[1], np.int16))
        cv2.copyTo(fixed, measured, filled16)
        median16 = cv2.medianBlur(filled16, size, dst=fixed)  # `fixed` is no longer needed
        keep = cv2.bitwise_and(cv2.inRange(median16, -FIXED_LIMIT, FIXED_LIMIT), measured)
        smoothed = np.multiply(median16, np.float32(1.0 / 16.0), dtype=np.float32)
    # Holes stay holes; unbalanced windows keep their own value.
    cv2.copyTo(original, cv2.bitwise_not(keep, dst=keep), smoothed)
    return np.asarray(smoothed, dtype=np.float32)


def left_right_check(
    left_px: npt.NDArray[np.int32], right_px: npt.NDArray[np.int32], max_diff_px: float
) -> FloatArray:
    """Keep left-view disparities that the right view's disparities point back to.

    Args:
        left_px: Integer disparity of every left pixel.
        right_px: Integer disparity of every right pixel (its match is at x + d in the left).
        max_diff_px: Largest disagreement kept.

    Returns:
        The left disparity as float32, NaN where the check fails or the match is off-image.
    """
    width = left_px.shape[1]
    columns = np.arange(width, dtype=np.int32)[None, :] - left_px
    back = np.take_along_axis(right_px, np.clip(columns, 0, width - 1), axis=1)
    disparity = left_px.astype(np.float32)
    disparity[(columns < 0) | (np.abs(back - left_px) > max_diff_px)] = np.nan
    return disparity


def remove_speckles(disparity_px: FloatArray, max_size_px: int, max_diff_px: float) -> FloatArray:
    """Drop small islands of similar disparity (OpenCV's filterSpeckles).

    Args:
        disparity_px: Disparity, NaN where invalid.
        max_size_px: Islands of fewer pixels are dropped (0: return the input).
        max_diff_px: Neighbours within this disparity belong to the same island.

    Returns:
        A copy with the islands set to NaN.
    """
    if max_size_px <= 0:
        return disparity_px
    fixed = np.where(np.isfinite(disparity_px), disparity_px * 16.0, -16.0).astype(np.int16)
    cv2.filterSpeckles(fixed, -16, max_size_px, max(1, round(16 * max_diff_px)))
    out = disparity_px.copy()
    out[fixed == -16] = np.nan
    return out


def fill_holes(disparity_px: FloatArray) -> FloatArray:
    """Fill invalid pixels along each row from the farther of the nearest valid neighbours.

    A hole is usually an occlusion next to a near surface, so the background (smaller)
    disparity on either side is the better guess. Rows without any valid pixel stay NaN.
    This invents values: use the result for display only, never for obstacles.

    Args:
        disparity_px: Disparity, NaN where invalid.

    Returns:
        A filled copy, float32.
    """
    height, width = disparity_px.shape
    valid = ~np.isnan(disparity_px)
    index = np.where(valid, np.arange(width)[None, :], -1)
    from_left = np.maximum.accumulate(index, axis=1)
    index_r = np.where(valid, np.arange(width)[None, :], width)
    from_right = np.minimum.accumulate(index_r[:, ::-1], axis=1)[:, ::-1]
    rows = np.arange(height)[:, None]
    padded = np.concatenate([disparity_px, np.full((height, 1), np.nan, np.float32)], axis=1)
    left_value = np.where(from_left >= 0, padded[rows, from_left], np.nan)
    right_value = padded[rows, np.minimum(from_right, width)]
    guess = np.fmin(left_value, right_value)
    return np.asarray(np.where(valid, disparity_px, guess), np.float32)


_NOISE_KERNEL_1D = np.array([1.0, -2.0, 1.0], dtype=np.float32)
"""Immerkaer's 3x3 kernel is the outer product of this with itself (separable)."""


QUANTISATION_SIGMA = 1.0 / math.sqrt(12.0)
"""Standard deviation of rounding to whole grey levels: the least noise an 8-bit image has."""
_NOISE_BLOCK_PX = 16
_NOISE_PERCENTILE = 10.0
# The 10th percentile of 16 x 16 block means of pure noise lies 1.28 standard errors below
# their mean; the block mean of |response| has a relative standard error of
# sqrt(pi / 2 - 1) / 16 = 0.047 for Gaussian noise, so the percentile reads 6% low.
_PERCENTILE_BIAS = 1.0 - 1.2816 * math.sqrt(math.pi / 2.0 - 1.0) / _NOISE_BLOCK_PX


def noise_sigma(grey: Image) -> float:
    """Standard deviation of the sensor noise of an image.

    Immerkaer's operator, the difference of two 3x3 Laplacians, cancels image structure up to
    second order and leaves the noise: for Gaussian noise its mean absolute response is
    ``6 * sigma * sqrt(2 / pi)``. Over a whole image, fine texture and edges leak into that
    mean and inflate it (three to five times on Middlebury 2001 scenes), so the mean is taken
    per 16 x 16 block and the estimate comes from the quietest blocks (the 10th percentile,
    corrected for its small-sample bias): any image with a few smooth patches shows its
    noise there.

    Args:
        grey: An 8-bit grey image (at least 3x3).

    Returns:
        The estimate in grey levels.
    """
    kernel = _NOISE_KERNEL_1D
    response = scratch("postprocess.noise_sigma", grey.shape, np.float32)
    cv2.sepFilter2D(grey, cv2.CV_32F, kernel, kernel, dst=response)
    magnitude = np.abs(response, out=response)[1:-1, 1:-1]
    height, width = magnitude.shape
    block = _NOISE_BLOCK_PX
    rows, columns = height // block, width // block
    if rows and columns:
        means = cv2.resize(
            magnitude[: rows * block, : columns * block],
            (columns, rows),
            interpolation=cv2.INTER_AREA,
        )
        level = float(np.percentile(means, _NOISE_PERCENTILE)) / _PERCENTILE_BIAS
    else:
        level = float(np.mean(magnitude))
    return float(np.sqrt(np.pi / 2.0) / 6.0 * level)


def texture_gate(
    grey: Image, window_px: int, min_snr: float, sigma: float | None = None
) -> npt.NDArray[np.bool_]:
    """Pixels with more texture along the epipolar line than the sensor noise alone would give.

    Texture is the grey-level variance along each row segment of ``window_px`` pixels,
    averaged over the ``window_px`` rows of the window; a pixel passes when it is at least
    ``min_snr`` squared times what pure noise gives (see :func:`noise_sigma`). Only texture
    along the row can fix a disparity: smooth regions (sky, blank walls) and horizontal
    stripes (far ground seen at a grazing angle) match equally well at many disparities, and
    a matcher's answer there is a guess, often smoothly propagated from the surroundings
    (SGBM) and dense enough to pass for an obstacle. The threshold follows each frame's own
    noise, not a fixed grey level.

    Args:
        grey: The rectified left view the disparity belongs to.
        window_px: Side of the window (odd).
        min_snr: Required ratio of local row-wise standard deviation to noise.
        sigma: The view's :func:`noise_sigma`, when already known (else it is estimated).

    Returns:
        (H, W) mask, True where the image carries texture along its rows.
    """
    n = window_px
    ones, one = np.ones(n, np.float32), np.ones(1, np.float32)
    border = cv2.BORDER_REFLECT
    # Unnormalised sums keep every step exact integers in float32 up to the column sum, and
    # OpenCV's separable filter is two to three times faster than its box filter down columns.
    shape = grey.shape
    total = scratch("postprocess.texture_gate.total", shape, np.float32)
    squares = scratch("postprocess.texture_gate.squares", shape, np.float32)
    total_sq = scratch("postprocess.texture_gate.total_sq", shape, np.float32)
    cv2.sepFilter2D(grey, cv2.CV_32F, ones, one, dst=total, borderType=border)
    cv2.multiply(grey, grey, dst=squares, dtype=cv2.CV_32F)
    cv2.sepFilter2D(squares, -1, ones, one, dst=total_sq, borderType=border)
    # n^2 times the variance of each row segment: n * sum(x^2) - sum(x)^2 (in place).
    spread = cv2.multiply(total, total, dst=total, scale=-1.0)
    cv2.scaleAdd(total_sq, float(n), spread, dst=spread)
    summed = cv2.sepFilter2D(spread, -1, one, ones, dst=squares, borderType=border)
    # summed: n^3 times the mean variance.
    # An 8-bit image is never known better than its rounding: without this floor a flat,
    # noise-free image (a saturated or black frame) has sigma 0 and every pixel passes.
    sigma = max(noise_sigma(grey) if sigma is None else sigma, QUANTISATION_SIGMA)
    noise_variance = sigma * sigma * (1.0 - 1.0 / n)
    threshold = min_snr * min_snr * noise_variance * n * n * n
    return np.asarray(summed >= np.float32(threshold), dtype=np.bool_)


class PostResult(NamedTuple):
    """What the post-processing of one disparity map gives.

    Attributes:
        disparity: The measured disparity, NaN where nothing trustworthy was measured (a new
            array: the input is not modified).
        textured: Pixels with texture enough to match (the texture mask and the texture
            gate, where on), or None when neither is on.
        filled: The hole-filled map for display (``fill_holes`` on), else None.
        noise_sigma: The left view's sensor noise in grey levels (see :func:`noise_sigma`).
    """

    disparity: FloatArray
    textured: BoolArray | None
    filled: FloatArray | None
    noise_sigma: float


def postprocess_disparity(
    left: Image,
    right: Image,
    disparity_px: FloatArray,
    config: PostprocessConfig,
    texture: BoolArray | None = None,
    filled_by_matcher: BoolArray | None = None,
    gate: BoolArray | None = None,
) -> PostResult:
    """Every post-processing step after the matcher, in order, on one disparity map.

    Sub-pixel refinement, median, speckles, the texture mask and gate, the depth-edge checks
    (hidden from the right camera, too narrow occlusion gaps, foreground fattening), the
    display fill, and last the matcher's filled pixels dropped. The view's noise is estimated
    once and serves the texture gate, the fattening check and, through the result, the ground
    check of the obstacle stage.

    Args:
        left: Rectified left grey view (the disparity's reference).
        right: Rectified right grey view.
        disparity_px: The matcher's disparity (NaN invalid); not modified.
        config: The head's ``postprocess`` section.
        texture: The preprocessing's texture mask (True: textured), if any.
        filled_by_matcher: Pixels the matcher filled rather than measured, if any.
        gate: The left view's :func:`texture_gate` with this ``config``'s window and
            threshold, when already computed for this frame (the near-field pass computes it
            when it sees something near); else it is computed here.

    Returns:
        The measured map, the textured pixels and the display map.
    """
    disparity = disparity_px
    if config.subpixel_refine:
        disparity = refine_subpixel(left, right, disparity, config.refine_window_px)
    disparity = median_smooth(disparity, config.median_size)
    disparity = remove_speckles(disparity, config.speckle_window_px, config.speckle_range_px)
    if disparity is disparity_px or not disparity.flags.c_contiguous:
        disparity = np.array(disparity, dtype=np.float32, order="C")  # never the input
    nan = np.float32(np.nan)
    flat = disparity.ravel()  # a view: the map is contiguous
    sigma = noise_sigma(left)
    # Untextured pixels first: what the matcher guessed there (sky, blank walls) is no surface,
    # so a silhouette against them is a depth edge for the checks below.
    if texture is not None:
        np.copyto(disparity, nan, where=~texture)  # untextured: not measured, never guessed
    textured = texture
    if config.min_texture_snr > 0:
        if gate is None:
            gate = texture_gate(left, config.texture_window_px, config.min_texture_snr, sigma)
        np.copyto(disparity, nan, where=~gate)  # contrast below the noise: a guess
        textured = gate if textured is None else textured & gate
    if config.edge_radius_px:
        np.copyto(disparity, nan, where=hidden_from_right(disparity))
        radius, jump = config.edge_radius_px, config.edge_jump_px
        flat[short_gap_indices(disparity, jump, 2 * radius)] = nan
        # Background that took the silhouette's disparity, then background left of a
        # silhouette that the right camera cannot see (the runs as the first check left them).
        means = column_means(
            left,
            right,
            scratch("postprocess.left_mean", left.shape, np.uint8),
            scratch("postprocess.right_mean", right.shape, np.uint8),
        )
        flat[fattened_indices(left, right, disparity, radius, jump, sigma, means=means)] = nan
        flat[ambiguous_left_edges(left, right, disparity, radius, jump, sigma, means=means)] = nan
    # The display map is filled before anything is blanked; the map obstacles see is not.
    filled = fill_holes(disparity) if config.fill_holes else None
    if filled_by_matcher is not None:
        np.copyto(disparity, nan, where=filled_by_matcher)  # filled, not measured
    return PostResult(disparity, textured, filled, sigma)
