"""Depth from disparity: Z = f * B / (d + doffs), in metres."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from avoidd.types import FloatArray, RectifiedRig


def resolved_range_m(rig: RectifiedRig, disparity_error_px: float) -> float:
    """How far a rig resolves: the range at which ``disparity_error_px`` is half the disparity.

    There a reading may be off by half its range (``dZ / Z = Z * error / (f * B)``); beyond
    it a surface cannot be told from open space, so nothing beyond is claimed clear.

    Args:
        rig: The rig of the images the matcher sees.
        disparity_error_px: The matcher's disparity error to count on.
    """
    return rig.fx * rig.baseline_m / (2.0 * disparity_error_px)


THIN_MIN_PX = 1.25
"""Width in pixels from which an obstacle is counted on to be read. On the rendered rigs a 5 cm
pole was first read at about 1 px wide (9.8 m at f = 200 px, 19-21 m at f = 400 px) and then in
only about half the frames (docs/perception.md, "Thin poles"): a quarter pixel more is the
margin."""


def thin_range_m(rig: RectifiedRig, width_m: float, resolved_m: float) -> float:
    """How far an obstacle ``width_m`` wide is read: where it spans :data:`THIN_MIN_PX`.

    Args:
        rig: The rig of the images the matcher sees.
        width_m: The obstacle's width (``sectors.min_size_m``: the smallest promised).
        resolved_m: The head's resolved range (:func:`resolved_range_m`), a ceiling.

    Returns:
        Metres; ``inf`` when ``width_m`` is 0 (no size promised: nothing to stop for).
    """
    if width_m <= 0.0:
        return math.inf
    return min(rig.fx * width_m / THIN_MIN_PX, resolved_m)


def depth_from_disparity(disparity_px: FloatArray, rig: RectifiedRig) -> FloatArray:
    """Convert a disparity map to depth along the optical axis.

    Args:
        disparity_px: Disparity of the left view in pixels, NaN where invalid.
        rig: The rectified rig (focal length, baseline, principal point offset).

    Returns:
        Depth in metres, float32. NaN where the disparity is invalid or ``d + doffs < 0``
        (a point behind the cameras: impossible, so no measurement); ``inf`` where
        ``d + doffs == 0`` (a point at infinity: measured, and far).
    """
    shifted = disparity_px.astype(np.float32, copy=False)
    if rig.doffs_px:
        shifted = shifted + np.float32(rig.doffs_px)
    numerator = np.float32(rig.fx * rig.baseline_m)
    with np.errstate(divide="ignore", invalid="ignore"):
        depth = np.divide(numerator, shifted, dtype=np.float32)  # NaN stays NaN
        depth[shifted == 0] = np.inf
        depth[shifted < 0] = np.nan
    return depth


def disparity_from_depth(depth_m: FloatArray, rig: RectifiedRig) -> FloatArray:
    """Inverse of :func:`depth_from_disparity` (ground truth rendering, tests).

    Args:
        depth_m: Depth along the optical axis in metres; NaN invalid, ``inf`` at infinity.
        rig: The rectified rig.

    Returns:
        Disparity in pixels, float32, NaN where the depth is NaN.
    """
    with np.errstate(divide="ignore"):
        disparity = np.float32(rig.fx * rig.baseline_m) / depth_m.astype(np.float32)
    return (disparity - np.float32(rig.doffs_px)).astype(np.float32)


def depth_histogram(
    depth_m: FloatArray, min_m: float, max_m: float, bins: int
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64]]:
    """Histogram of measured depths over linearly spaced edges, as the paper computes it.

    Pixels without a measurement (NaN) and infinitely far ones are left out; depths outside
    ``[min_m, max_m]`` are left out too.

    Returns:
        The ``bins + 1`` edges in metres and the ``bins`` counts.
    """
    edges = np.linspace(min_m, max_m, bins + 1)
    finite = depth_m[np.isfinite(depth_m)]
    counts, _ = np.histogram(finite, bins=edges)
    return edges, counts.astype(np.int64)
