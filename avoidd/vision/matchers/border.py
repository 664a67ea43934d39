"""Matching the left border band.

The first ``n`` columns of the left view may have their match outside the right image, and
OpenCV's matchers leave them unmatched.
"""

from __future__ import annotations

import cv2
import numpy as np

from avoidd.types import FloatArray, Image


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


def run_opencv_matcher(
    matcher: cv2.StereoMatcher, left: Image, right: Image, pad: int, min_disparity: int = 0
) -> FloatArray:
    """Run an OpenCV stereo matcher (fixed-point output, 1/16 px) with optional padding.

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
