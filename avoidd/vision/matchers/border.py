"""Matching the left border band.

The first ``n`` columns of the left view may have their match outside the right image, and
OpenCV's matchers leave them unmatched. Padding both views lets the matcher search the band,
but what it finds there is biased far: at column ``x`` only disparities up to ``x`` can be
checked, so a surface nearer than that (its match outside the right image) can only take a
wrong, smaller disparity, and for an ambiguous pixel (a blank wall) the nearer guesses are
the ones that land in the padding and are dropped, the farther ones stay. So the band keeps
only readings that the right view confirms on its own (:func:`confirm_band`).
"""

from __future__ import annotations

import cv2
import numpy as np

from avoidd.types import BoolArray, FloatArray, Image

CHECK_BLOCK_PX = 11
"""Window of the band's confirming match (the ``sad`` matcher's default block)."""
CHECK_UNIQUENESS = 15
"""Uniqueness ratio of the confirming match (percent; the ``sad`` matcher's default)."""
CHECK_TOLERANCE_PX = 1.0
"""Largest disagreement between a band reading and the right view's match back to it."""


def pad_left(image: Image, columns: int) -> Image:
    """Prepend ``columns`` copies of the first column (so the matcher searches the band)."""
    return np.asarray(
        cv2.copyMakeBorder(image, 0, 0, columns, 0, cv2.BORDER_REPLICATE), dtype=np.uint8
    )


def crop_padded(disparity_px: FloatArray, columns: int) -> FloatArray:
    """Undo :func:`pad_left` on a disparity map.

    Estimates whose match lies in the padding (disparity greater than the column index) are
    dropped: they compared against copies, not measurements.
    """
    cropped = np.ascontiguousarray(disparity_px[:, columns:])
    x = np.arange(cropped.shape[1], dtype=np.float32)[None, :]
    cropped[cropped > x] = np.nan
    return cropped


def right_strip_disparity(
    left: Image, right: Image, columns: int, num_disparities: int, min_disparity: int = 0
) -> FloatArray:
    """Disparity of the right view's first ``columns`` columns, matched with the right as reference.

    The views are mirrored and swapped, so the right view's matches lie to the left of each
    pixel as OpenCV expects, and only the strip those columns and their matches span is
    matched: a block matcher (SAD over :data:`CHECK_BLOCK_PX` squared, texture threshold,
    uniqueness :data:`CHECK_UNIQUENESS`), independent of the left view's costs and paths, and
    invalid where the window has too little texture to decide.

    Args:
        left: Left grey view.
        right: Right grey view, same shape.
        columns: How many of the right view's first columns are needed.
        num_disparities: Width of the search range (multiple of 16).
        min_disparity: Smallest disparity searched.

    Returns:
        (H, ``columns``) float32: at right column ``c``, the disparity ``d`` of its match at
        left column ``c + d``; NaN where there is none (or the strip is too narrow to search).
    """
    height, width = right.shape[:2]
    reach = max(min_disparity + num_disparities, 0)
    strip = min(width, columns + reach + CHECK_BLOCK_PX)
    result = np.full((height, columns), np.nan, dtype=np.float32)
    if strip <= reach or height < CHECK_BLOCK_PX:
        return result  # nothing can be confirmed
    # Replicated by half a window at the top, the bottom and the image's left edge (the
    # mirror's right end), where the block matcher would otherwise leave its window's margin.
    margin = CHECK_BLOCK_PX // 2
    mirrored_right, mirrored_left = (
        cv2.copyMakeBorder(
            np.ascontiguousarray(view[:, strip - 1 :: -1]),
            margin,
            margin,
            0,
            margin,
            cv2.BORDER_REPLICATE,
        )
        for view in (right, left)
    )
    matcher = cv2.StereoBM.create(num_disparities, CHECK_BLOCK_PX)  # cheap; not shared by threads
    matcher.setMinDisparity(min_disparity)
    matcher.setUniquenessRatio(CHECK_UNIQUENESS)
    raw = np.asarray(matcher.compute(mirrored_right, mirrored_left), dtype=np.int16)
    raw = raw[margin : margin + height, strip - 1 :: -1]  # back to the right view's columns
    have = min(columns, strip)
    values = raw[:, :have].astype(np.float32) * np.float32(1.0 / 16.0)
    values[raw[:, :have] < min_disparity * 16] = np.nan
    result[:, :have] = values
    return result


def confirm_band(
    left: Image,
    right: Image,
    disparity_px: FloatArray,
    num_disparities: int,
    min_disparity: int = 0,
) -> BoolArray:
    """Drop the left border band's readings that the right view does not point back to.

    A reading ``d`` at band column ``x`` stands only if the right view's own match of column
    ``x - d`` (:func:`right_strip_disparity`) is within :data:`CHECK_TOLERANCE_PX` of ``d``.
    A reading that cannot be confirmed becomes unknown, never another value: the band is where
    the matcher's errors lean far (see the module's docstring), and unknown is never farther.

    Args:
        left: Left grey view.
        right: Right grey view, same shape.
        disparity_px: The left view's disparity (NaN invalid), changed in place in the band
            (the first ``min_disparity + num_disparities - 1`` columns).
        num_disparities: Width of the search range.
        min_disparity: Smallest disparity searched.

    Returns:
        (H, band) the dropped readings that the right view could not check (no match of
        its own there: too little texture, not unique), as against those it contradicts.
        Only a contradiction or no match at all is evidence of a surface the band cannot
        see (see :mod:`avoidd.perception.blind_band`).
    """
    # Column x can match outside the right image when x - d < 0 for a searched d.
    band_px = min(min_disparity + num_disparities - 1, disparity_px.shape[1])
    if band_px <= 0:
        return np.zeros((disparity_px.shape[0], 0), dtype=np.bool_)
    band = disparity_px[:, :band_px]  # a view
    # Right columns the band's readings land on: x - d, d from min_disparity up.
    needed = band_px + max(0, -min_disparity)
    back = right_strip_disparity(left, right, needed, num_disparities, min_disparity)
    x = np.arange(band_px, dtype=np.float32)[None, :]
    landing = np.rint(x - np.nan_to_num(band, nan=0.0)).astype(np.intp)
    np.clip(landing, 0, needed - 1, out=landing)
    pointed = np.take_along_axis(back, landing, axis=1)
    with np.errstate(invalid="ignore"):
        confirmed = np.abs(pointed - band) <= CHECK_TOLERANCE_PX
    unchecked = np.isnan(pointed) & ~np.isnan(band)
    np.copyto(band, np.float32(np.nan), where=~confirmed)
    return unchecked


def run_opencv_matcher(
    matcher: cv2.StereoMatcher, left: Image, right: Image, pad: int, min_disparity: int = 0
) -> FloatArray:
    """Run an OpenCV stereo matcher (fixed-point output, 1/16 px) with optional padding.

    The padded band is returned as matched; the matchers then keep only what
    :func:`confirm_band` confirms.

    Args:
        matcher: A StereoBM or StereoSGBM object.
        left: Left grey view.
        right: Right grey view.
        pad: Columns of left padding (0: none); see :func:`pad_left`.
        min_disparity: The matcher's minimum disparity (below it means invalid).

    Returns:
        Disparity in pixels, NaN where OpenCV found no valid match.
    """
    if pad:
        left, right = pad_left(left, pad), pad_left(right, pad)
    raw = np.asarray(matcher.compute(left, right), dtype=np.int16)[:, pad:]
    # Converted once, cropped as it is converted (the padding is never copied).
    disparity = raw.astype(np.float32)
    disparity *= np.float32(1.0 / 16.0)
    np.copyto(disparity, np.float32(np.nan), where=raw < min_disparity * 16)
    if pad:
        # As crop_padded: matches that land in the padding compared against copies.
        x = np.arange(disparity.shape[1], dtype=np.float32)[None, :]
        np.copyto(disparity, np.float32(np.nan), where=disparity > x)
    return disparity
