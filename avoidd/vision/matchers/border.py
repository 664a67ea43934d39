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
