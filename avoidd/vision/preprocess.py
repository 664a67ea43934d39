"""Preprocessing before matching: grey conversion (the paper's stereoscopic view generation)."""

from __future__ import annotations

import cv2
import numpy as np

from avoidd.types import Image


def to_grey(image: Image) -> Image:
    """Convert a BGR or BGRA image to 8-bit grey; a grey image is returned unchanged.

    Args:
        image: (H, W), (H, W, 1), (H, W, 3) BGR or (H, W, 4) BGRA, uint8.

    Returns:
        The (H, W) grey image.

    Raises:
        ValueError: The image is not 8-bit or has an unsupported number of channels.
    """
    if image.dtype != np.uint8:
        raise ValueError(f"expected an 8-bit image, got {image.dtype}")
    if image.ndim == 2:
        return image
    channels = image.shape[2]
    if channels == 1:
        return image[:, :, 0]
    if channels == 3:
        return np.asarray(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY), np.uint8)
    if channels == 4:
        return np.asarray(cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY), np.uint8)
    raise ValueError(f"expected 1, 3 or 4 channels, got {channels}")
