"""Preprocessing before matching, as the paper has it.

Grey conversion, resize, median and mean denoising, and an adaptive-threshold texture mask.
"""

from __future__ import annotations

import cv2
import numpy as np
import numpy.typing as npt

from avoidd.types import Image, RectifiedRig


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


def resize(image: Image, scale: float) -> Image:
    """Scale an image (area interpolation when shrinking); 1.0 returns it unchanged."""
    if scale == 1.0:
        return image
    height, width = image.shape[:2]
    size = (max(1, round(width * scale)), max(1, round(height * scale)))
    return np.asarray(cv2.resize(image, size, interpolation=cv2.INTER_AREA), np.uint8)


def scale_rig(rig: RectifiedRig, scale: float) -> RectifiedRig:
    """The rig of images resized by ``scale`` (pixel sizes scale, the baseline does not)."""
    if scale == 1.0:
        return rig
    width, height = max(1, round(rig.width * scale)), max(1, round(rig.height * scale))
    sx, sy = width / rig.width, height / rig.height
    return RectifiedRig(
        width,
        height,
        rig.fx * sx,
        rig.fy * sy,
        (rig.cx + 0.5) * sx - 0.5,
        (rig.cy + 0.5) * sy - 0.5,
        rig.baseline_m,
        rig.doffs_px * sx,
    )


def denoise(image: Image, median_px: int, mean_px: int) -> Image:
    """Median then mean (box) filtering of a grey image; 0 skips a filter."""
    if median_px:
        image = np.asarray(cv2.medianBlur(image, median_px), np.uint8)
    if mean_px:
        image = np.asarray(cv2.blur(image, (mean_px, mean_px)), np.uint8)
    return image


def adaptive_texture_mask(
    image: Image, method: str, window_px: int, offset: float, spread_px: int
) -> npt.NDArray[np.bool_]:
    """The paper's adaptive threshold, used as a texture mask.

    Args:
        image: Grey image.
        method: ``mean`` or ``median``: the local statistic the pixel is compared with.
        window_px: Odd window of that statistic (3 to 31).
        offset: Grey levels by which a pixel must differ from it to count as texture.
        spread_px: Odd window over which a textured pixel marks its neighbours textured too
            (about the matcher's window: a pixel is matchable if its window has texture).

    Returns:
        True where the image has texture.
    """
    if method == "median":
        # OpenCV's median is 8-bit only beyond 5x5; it is exact for any odd window.
        local = np.asarray(cv2.medianBlur(image, window_px), np.float32)
    else:
        local = np.asarray(cv2.blur(image.astype(np.float32), (window_px, window_px)), np.float32)
    edges = (np.abs(image.astype(np.float32) - local) >= offset).astype(np.uint8)
    kernel = np.ones((spread_px, spread_px), np.uint8)
    return np.asarray(cv2.dilate(edges, kernel) > 0)
