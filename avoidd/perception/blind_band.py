"""The left border band's blind zone: where a nearer surface may stand that no match can see.

At column ``x`` of the left view, a point nearer than ``f B / x`` lies outside the right view,
so no matcher can measure it: it leaves its pixels unmeasured (the band's readings are kept
only where the right view confirms them, see :mod:`avoidd.vision.matchers.border`). Wider than
the baseline, such a surface shows in the columns right of ``f B / Z``; narrower (a pole, a
cable), it can vanish from the band. The band's confirmed readings stand: what the right view
confirms is there. But a bin whose band pixels are left unmeasured where its reading's surface
would have been measured, in a patch as large as the smallest obstacle would look there, holds
something nearer that no match could see (:func:`hidden_bins`); that bin reads what its other
columns show when that is no farther (what it read before the band was used), else unknown,
never clear (:func:`settle_hidden`).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from avoidd.perception.frames import Pose, axis_per_depth
from avoidd.perception.sectors import bin_of_bearing
from avoidd.types import SECTOR_COUNT, BoolArray, FloatArray, RectifiedRig, SectorScan

EDGE_MARGIN_PX = 6
"""How far inside the right image a match must land to be measurable: the band check's
11-pixel window (and the matcher's own) runs off the image nearer its edge than this."""


def patch_side_px(first_column: int, baseline_m: float, min_size_m: float, min_pixels: int) -> int:
    """Side of the smallest obstacle hidden at column ``first_column`` (odd).

    Hidden there, it is nearer than ``f B / x``, so it spans at least
    ``f min_size / (f B / x) = min_size x / B`` pixels (the focal length cancels); and it
    covers at least the ``min_pixels`` a bin needs to report anything it sees.
    """
    wanted = min_size_m * first_column / baseline_m if baseline_m > 0 else 0.0
    return max(math.ceil(math.sqrt(min_pixels)), math.floor(wanted)) | 1


def hidden_bins(
    band_unresolved: BoolArray,
    rig: RectifiedRig,
    to_level: Pose,
    min_size_m: float,
    min_pixels: int,
    distance_m: FloatArray,
) -> BoolArray:
    """Bins whose band pixels show that a surface nearer than their reading stands unseen.

    A band pixel is evidence against its bin's reading (or clear) when it is left
    unmeasured although the reading's surface would be measurable there (its match at that
    pixel lands at least :data:`EDGE_MARGIN_PX` inside the right image): then something
    nearer stands in it, in the blind zone. Only rays at or above the level count (as for
    :func:`~avoidd.perception.ground.unseen_surfaces`): below it the ground leaves such
    patches whatever stands. The evidence must fill a
    square as large as the smallest obstacle hidden at the patch's column would look
    (:func:`patch_side_px`).

    Args:
        band_unresolved: (H, band) the band's textured pixels left without a measurement
            that are evidence of a surface it cannot see: not matched at all, or contradicted
            by the right view (a reading the right view could not check is no evidence).
        rig: The rectified rig.
        to_level: Rectified camera to level frame (see
            :func:`~avoidd.perception.perceive.rectified_to_level`).
        min_size_m: Side of the smallest obstacle the sensor promises to see.
        min_pixels: Pixels a bin needs to report an obstacle it sees.
        distance_m: (72,) the bins' horizontal readings (NaN unknown, ``inf`` clear).

    Returns:
        (72,) True where the bin's reading (or clear) cannot be vouched for.
    """
    hidden = np.zeros(SECTOR_COUNT, dtype=np.bool_)
    band_px = band_unresolved.shape[1]
    if band_px <= 0 or not band_unresolved.any():
        return hidden
    focal_baseline = np.float32(rig.fx * rig.baseline_m)
    # The band is the image's first columns: the maps of those columns alone.
    forward, right, down = (
        axis_per_depth(rig, band_unresolved.shape, to_level, axis) for axis in (0, 1, 2)
    )
    columns = np.arange(band_px, dtype=np.float32)[None, :]
    # Rays below the level are left out: they meet the ground, which near the vehicle is in
    # the blind zone and far away is seen at a grazing angle that matchers leave unmeasured
    # whatever stands (so a hidden obstacle lower than the camera is not caught here).
    evidence = band_unresolved & (down <= 0.0)
    # Horizontal range per metre of depth, and the bin of each pixel's horizontal bearing.
    horizontal = np.hypot(forward, right)
    pixel_bins = bin_of_bearing(np.degrees(np.arctan2(right, forward))) % SECTOR_COUNT
    for sector in np.unique(pixel_bins[evidence]):
        reading_m = float(distance_m[sector])
        if math.isnan(reading_m):
            continue
        # The reading's surface at each pixel: disparity f B / depth, depth = range / horizontal.
        reading_px = focal_baseline * horizontal / np.float32(reading_m) - rig.doffs_px
        suspect = evidence & (pixel_bins == sector) & (reading_px + EDGE_MARGIN_PX <= columns)
        if not suspect.any():
            continue
        first_column = int(np.flatnonzero(suspect.any(axis=0))[0])
        side = patch_side_px(first_column, rig.baseline_m, min_size_m, min_pixels)
        opened = cv2.morphologyEx(
            suspect.astype(np.uint8),
            cv2.MORPH_OPEN,
            np.ones((side, side), dtype=np.uint8),
            borderType=cv2.BORDER_CONSTANT,
            borderValue=0,
        )
        hidden[sector] = bool(opened.any())
    return hidden


def without_band_columns(image: FloatArray, band_px: int) -> FloatArray:
    """A copy of a depth or disparity map with the band's columns unmeasured (NaN)."""
    blanked = image.copy()
    blanked[:, :band_px] = np.nan
    return blanked


def settle_hidden(scan: SectorScan, without_band: SectorScan, hidden: BoolArray) -> None:
    """What the hidden bins of ``scan`` read, in place: never farther, never clear.

    A hidden bin (:func:`hidden_bins`) holds something nearer than its reading. It takes the
    reading of the scan made without the band when that is finite and no farther (the
    surface its other columns show: what it read before the band was used), else unknown.

    Args:
        scan: The scan made with the band's readings.
        without_band: The same frame's scan made without them.
        hidden: (72,) the bins :func:`hidden_bins` found.
    """
    here, there = scan.distance_m, without_band.distance_m
    with np.errstate(invalid="ignore"):
        keep = hidden & np.isfinite(there) & (there <= here)
    gone = hidden & ~keep
    here[keep] = there[keep]
    here[gone] = np.nan
    if scan.points_frd_m is not None:
        if without_band.points_frd_m is not None:
            scan.points_frd_m[keep] = without_band.points_frd_m[keep]
        else:
            scan.points_frd_m[keep] = np.nan
        scan.points_frd_m[gone] = np.nan
