"""Depth map to the 72 x 5 degree sector grid in body FRD; merging the grids of several heads."""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from avoidd.config import SectorsConfig
from avoidd.types import (
    SECTOR_COUNT,
    SECTOR_WIDTH_DEG,
    FloatArray,
    Mount,
    RectifiedRig,
    SectorScan,
)

IntArray = npt.NDArray[np.int64]


def column_bearings_deg(rig: RectifiedRig, mount: Mount) -> FloatArray:
    """Body-frame bearing of the viewing ray of every image column (level camera, mount yaw).

    Args:
        rig: The rectified rig.
        mount: The head's mount; only its yaw is used by this first version.

    Returns:
        (W,) bearings in degrees, increasing to the right, unwrapped around the mount yaw.
    """
    u = np.arange(rig.width, dtype=np.float64)
    return (np.degrees(np.arctan((u - rig.cx) / rig.fx)) + mount.yaw_deg).astype(np.float32)


def covered_bins(rig: RectifiedRig, mount: Mount) -> npt.NDArray[np.bool_]:
    """Bins whose centre bearing lies inside the head's horizontal field of view.

    Args:
        rig: The rectified rig.
        mount: The head's mount.

    Returns:
        (72,) boolean mask.
    """
    bearings = column_bearings_deg(rig, mount)
    first, last = float(bearings[0]), float(bearings[-1])
    centres = np.arange(SECTOR_COUNT) * SECTOR_WIDTH_DEG
    offset = np.mod(centres - first, 360.0)
    return np.asarray(offset <= (last - first), dtype=np.bool_)


def band_rows(height: int, row_band: tuple[float, float]) -> tuple[int, int]:
    """First and end row of a band given as fractions of the image height (never empty)."""
    top = min(math.floor(row_band[0] * height), height - 1)
    return top, max(math.ceil(row_band[1] * height), top + 1)


def bin_of_bearing(bearing_deg: npt.NDArray[np.floating] | float) -> IntArray:
    """Sector index of a bearing (bin i covers i*5 +- 2.5 degrees)."""
    index = np.floor(np.asarray(bearing_deg, dtype=np.float64) / SECTOR_WIDTH_DEG + 0.5)
    return np.mod(index, SECTOR_COUNT).astype(np.int64)


def sector_scan(
    depth_m: FloatArray,
    rig: RectifiedRig,
    mount: Mount,
    params: SectorsConfig,
    max_range_m: float,
    t_capture_ns: int,
) -> SectorScan:
    """Reduce a depth map to the 72-bin distance grid of one head.

    Every pixel of the configured row band counts. A bin reports its nearest cluster of at least
    ``min_pixels`` pixels (see :func:`nearest_cluster_m`); without one it is clear when enough of
    its pixels are valid, else unknown. Bins outside the field of view are unknown.

    Args:
        depth_m: Depth along the optical axis, NaN invalid, ``inf`` at infinity.
        rig: The rectified rig.
        mount: The head's mount (yaw and horizontal position are applied).
        params: Band and robustness parameters.
        max_range_m: Readings at or beyond this range count as clear.
        t_capture_ns: Capture time of the frame, carried into the scan.

    Returns:
        The scan: metres, NaN unknown, ``inf`` clear.
    """
    top, bottom = band_rows(depth_m.shape[0], params.row_band)
    band = depth_m[top:bottom, :]
    columns = _column_geometry(rig, mount)

    finite = np.isfinite(band)
    z = np.where(finite, band, np.float32(0.0))
    forward = z * columns.ray_forward[None, :] + np.float32(mount.position_m[0])
    right = z * columns.ray_right[None, :] + np.float32(mount.position_m[1])
    range_m = np.hypot(forward, right)
    near = finite & (range_m < max_range_m)
    near_forward, near_right = forward[near], right[near]

    # Pixel counts per bin go through the columns (W values, not W x H).
    valid_per_column = np.count_nonzero(~np.isnan(band), axis=0)
    total = np.bincount(columns.bins, minlength=SECTOR_COUNT) * band.shape[0]
    valid_count = np.bincount(columns.bins, weights=valid_per_column, minlength=SECTOR_COUNT)

    focal_baseline = np.float32(rig.fx * rig.baseline_m)
    nearest = nearest_cluster_m(
        bin_of_bearing(np.degrees(np.arctan2(near_right, near_forward))),
        focal_baseline / range_m[near],
        focal_baseline,
        params.min_pixels,
        params.cluster_window_px,
    )
    has_obstacle = np.isfinite(nearest)
    distance = nearest.astype(np.float32)

    with np.errstate(invalid="ignore", divide="ignore"):
        valid_fraction = np.where(total > 0, valid_count / np.maximum(total, 1), 0.0)
    clear = ~has_obstacle & (total > 0) & (valid_fraction >= params.min_valid_fraction)
    distance[clear] = np.inf
    distance[~columns.covered] = np.nan
    return SectorScan(t_capture_ns, distance)


class _Columns(NamedTuple):
    ray_forward: FloatArray
    ray_right: FloatArray
    bins: IntArray
    covered: npt.NDArray[np.bool_]


@functools.lru_cache(maxsize=32)
def _column_geometry(rig: RectifiedRig, mount: Mount) -> _Columns:
    """Horizontal viewing ray, bin and coverage of every column: fixed for a head, so cached."""
    yaw = math.radians(mount.yaw_deg)
    normalised_x = (np.arange(rig.width, dtype=np.float32) - np.float32(rig.cx)) / np.float32(
        rig.fx
    )
    ray_forward = np.float32(math.cos(yaw)) - np.float32(math.sin(yaw)) * normalised_x
    ray_right = np.float32(math.sin(yaw)) + np.float32(math.cos(yaw)) * normalised_x
    bins = bin_of_bearing(np.degrees(np.arctan2(ray_right, ray_forward)))
    columns = _Columns(ray_forward, ray_right, bins, covered_bins(rig, mount))
    for array in columns:
        array.flags.writeable = False
    return columns


def nearest_cluster_m(
    bins: IntArray,
    disparity_px: FloatArray,
    focal_baseline: float | np.float32,
    min_pixels: int,
    window_px: float,
) -> FloatArray:
    """Distance of the nearest dense cluster of points in every bin.

    Working in disparity (where stereo noise is about constant), a bin's cluster starts at the
    largest disparity that has at least ``min_pixels`` points within ``window_px`` below it. The
    bin reports the point a quarter of the way into that window from its near end: close to the
    nearest surface when the window spans an oblique face, and barely moved by noise when it
    holds one compact surface. Fewer than ``min_pixels`` stray points (speckle) cannot form a
    cluster, while a thin pole in front of a wall still does.

    Args:
        bins: Sector index of every point.
        disparity_px: Disparity-equivalent ``f * B / range`` of every point (> 0).
        focal_baseline: ``f * B`` in pixel metres, to turn disparity back into range.
        min_pixels: Points a cluster needs.
        window_px: Width of the cluster window in disparity pixels.

    Returns:
        (72,) distances in metres, NaN where a bin has no cluster.
    """
    distance = np.full(SECTOR_COUNT, np.nan, dtype=np.float32)
    if bins.size < min_pixels:
        return distance
    # One sort orders points by bin, then by decreasing disparity (nearest first).
    span = float(np.max(disparity_px)) + 1.0
    keys = np.sort(bins.astype(np.float64) * span + (span - disparity_px.astype(np.float64)))
    sorted_bins = np.floor(keys / span).astype(np.int64)
    sorted_disp = span - (keys - sorted_bins * span)
    last = sorted_bins.size - min_pixels + 1
    if last <= 0:
        return distance
    dense = (sorted_bins[:last] == sorted_bins[min_pixels - 1 :]) & (
        sorted_disp[:last] - sorted_disp[min_pixels - 1 :] <= window_px
    )
    seeds = np.flatnonzero(dense)
    if seeds.size == 0:
        return distance
    seed_bins = sorted_bins[seeds]
    first = np.flatnonzero(np.diff(seed_bins, prepend=-1) != 0)
    seeds = seeds[first]
    seed_bins = seed_bins[first]
    # Window members are contiguous after the seed: same bin, disparity within the window.
    seed_of_point = np.full(SECTOR_COUNT, -1, dtype=np.int64)
    seed_of_point[seed_bins] = seeds
    point_seed = seed_of_point[sorted_bins]
    index = np.arange(sorted_bins.size)
    member = (point_seed >= 0) & (index >= point_seed)
    member &= sorted_disp >= sorted_disp[np.maximum(point_seed, 0)] - window_px
    counts = np.bincount(sorted_bins[member], minlength=SECTOR_COUNT)[seed_bins]
    picked = sorted_disp[seeds + (counts - 1) // 4]
    distance[seed_bins] = (np.float32(focal_baseline) / picked).astype(np.float32)
    return distance


def merge_scans(scans: list[SectorScan]) -> SectorScan:
    """Merge the scans of several heads: the nearest reading per bin, unknown where none sees.

    Args:
        scans: One scan per head (at least one).

    Returns:
        The merged scan, stamped with the oldest capture time of its inputs.
    """
    if not scans:
        return SectorScan.unknown()
    stacked = np.stack([scan.distance_m for scan in scans])
    merged = np.fmin.reduce(stacked, axis=0).astype(np.float32)
    return SectorScan(min(scan.t_capture_ns for scan in scans), merged)
