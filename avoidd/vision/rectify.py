"""Apply the rectification computed at load time to a raw stereo pair."""

from __future__ import annotations

import cv2
import numpy as np

from avoidd.types import Image
from avoidd.vision.calibration import RectifyMaps


def rectify_pair(left: Image, right: Image, maps: RectifyMaps | None) -> tuple[Image, Image]:
    """Remap a raw pair into the rectified geometry (rows aligned).

    Args:
        left: Raw left image.
        right: Raw right image.
        maps: Remap tables, or None when the pair is already rectified.

    Returns:
        The rectified left and right images (the inputs themselves when ``maps`` is None).
    """
    if maps is None:
        return left, right
    out_left = cv2.remap(left, maps.left[0], maps.left[1], cv2.INTER_LINEAR)
    out_right = cv2.remap(right, maps.right[0], maps.right[1], cv2.INTER_LINEAR)
    return np.asarray(out_left, np.uint8), np.asarray(out_right, np.uint8)
