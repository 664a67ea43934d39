"""The paper's segmentation-based hybrid matcher: SAD on region boundaries, interiors filled.

1. Lightness: the L channel of CIE Lab (for a grey input, a monotone function of grey).
2. K-means on L, run on the 256-bin histogram rather than on pixels (same result, far cheaper).
3. Each cluster is cleaned by a morphological opening and split into 4-connected regions;
   regions smaller than ``min_region_px`` are left unsegmented.
4. SAD block matching (OpenCV StereoBM) is kept on region boundaries and unsegmented pixels
   only. StereoBM computes the whole image in one vectorised pass, which costs less than
   gathering windows at scattered boundary pixels would; the kept values are the same.
5. Each region's interior is filled from the SAD disparities on its own boundary band: a plane
   ``d = a x + b y + c`` fitted with two rounds of outlier trimming (a region on a slanted
   surface such as the ground is not fronto-parallel). A region whose boundary does not fit a
   plane well (or where the plane explains under 80% of them) spans a depth edge and is left
   empty rather than guessed.

Interior pixels are filled, not measured; ``last_filled`` marks them so the pipeline keeps
them out of obstacle detection.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from avoidd.config import SadConfig, SegmentConfig
from avoidd.types import BoolArray, FloatArray, Image
from avoidd.vision.matchers.sad import SadMatcher

IntArray = npt.NDArray[np.int32]

_KMEANS_ROUNDS = 30
# A region is filled only if one plane explains this share of its boundary measurements;
# otherwise trimming has thrown away a whole surface and the region spans a depth edge.
_MIN_INLIER_SHARE = 0.8
UNSEGMENTED = -1


def lightness(grey: Image) -> Image:
    """Lab L of a grey image, scaled 0..255 as OpenCV stores it for 8-bit images."""
    bgr = cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR)
    return np.ascontiguousarray(cv2.cvtColor(bgr, cv2.COLOR_BGR2Lab)[:, :, 0])


def kmeans_levels(image: Image, clusters: int) -> npt.NDArray[np.uint8]:
    """1-D K-means over the grey-level histogram.

    Args:
        image: 8-bit image.
        clusters: K.

    Returns:
        A 256-entry table from grey level to cluster index (clusters ordered dark to light).
    """
    counts = np.bincount(image.ravel(), minlength=256).astype(np.float64)
    levels = np.arange(256, dtype=np.float64)
    cumulative = np.cumsum(counts) / max(counts.sum(), 1.0)
    # Start at the histogram's quantiles, so every centre begins among real pixels.
    quantiles = (np.arange(clusters) + 0.5) / clusters
    centres = np.searchsorted(cumulative, quantiles).astype(np.float64)
    labels = np.zeros(256, np.int64)
    for _ in range(_KMEANS_ROUNDS):
        labels = np.argmin(np.abs(levels[:, None] - centres[None, :]), axis=1)
        weights = np.bincount(labels, weights=counts, minlength=clusters)
        sums = np.bincount(labels, weights=counts * levels, minlength=clusters)
        updated = np.where(weights > 0, sums / np.maximum(weights, 1e-12), centres)
        if np.allclose(updated, centres):
            break
        centres = updated
    order = np.argsort(np.argsort(centres))
    return np.asarray(order[labels], np.uint8)


def segment_regions(
    image: Image, clusters: int, open_px: int, min_region_px: int
) -> tuple[IntArray, int]:
    """Regions of similar lightness.

    Returns:
        A region id per pixel (``UNSEGMENTED`` for fragments) and the number of regions.
    """
    labels = kmeans_levels(image, clusters)[image]
    kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (open_px, open_px))
    regions = np.full(image.shape, UNSEGMENTED, np.int32)
    count = 0
    for cluster in range(clusters):
        mask = (labels == cluster).view(np.uint8)
        if open_px > 1:
            mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, kernel)
        n, components, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=4)
        large = np.flatnonzero(stats[1:, cv2.CC_STAT_AREA] >= min_region_px) + 1
        if large.size == 0:
            continue
        table = np.full(n, UNSEGMENTED, np.int32)
        table[large] = np.arange(count, count + large.size, dtype=np.int32)
        chosen = table[components]
        keep = chosen != UNSEGMENTED
        regions[keep] = chosen[keep]
        count += int(large.size)
    return regions, count


def boundary_band(regions: IntArray, width_px: int) -> BoolArray:
    """Pixels within ``width_px`` of a region edge, and every unsegmented pixel."""
    ids = regions.astype(np.float32)  # exact for fewer than 2**24 regions
    kernel = np.ones((2 * width_px + 1, 2 * width_px + 1), np.uint8)
    edge = cv2.dilate(ids, kernel) != cv2.erode(ids, kernel)
    return np.asarray(edge | (regions == UNSEGMENTED), np.bool_)


@dataclass(frozen=True)
class _Plane:
    a: npt.NDArray[np.float64]
    b: npt.NDArray[np.float64]
    c: npt.NDArray[np.float64]
    ok: BoolArray


def fit_region_planes(
    regions: IntArray,
    count: int,
    measured_px: FloatArray,
    min_points: int,
    max_residual_px: float,
) -> _Plane:
    """A plane per region from the measured disparities on its boundary band.

    Args:
        regions: Region id per pixel.
        count: Number of regions.
        measured_px: Disparity where measured on a boundary, NaN elsewhere.
        min_points: Measurements a region needs.
        max_residual_px: Largest median absolute residual of an accepted plane.

    Returns:
        Plane coefficients per region and whether each region may be filled.
    """
    a, b, c = np.zeros(count), np.zeros(count), np.zeros(count)
    ok = np.zeros(count, np.bool_)
    ys, xs = np.nonzero(~np.isnan(measured_px) & (regions >= 0))
    if xs.size == 0:
        return _Plane(a, b, c, ok)
    ids = regions[ys, xs]
    order = np.argsort(ids, kind="stable")
    ids, xs, ys = ids[order], xs[order].astype(np.float64), ys[order].astype(np.float64)
    ds = measured_px[ys.astype(np.intp), xs.astype(np.intp)].astype(np.float64)
    starts = np.flatnonzero(np.r_[True, ids[1:] != ids[:-1]])
    ends = np.r_[starts[1:], ids.size]
    for start, end in zip(starts, ends, strict=True):
        if end - start < min_points:
            continue
        region = int(ids[start])
        x, y, d = xs[start:end], ys[start:end], ds[start:end]
        design = np.column_stack([x, y, np.ones_like(x)])
        keep = np.ones(x.size, np.bool_)
        coefficients = np.zeros(3)
        residual = np.zeros(x.size)
        for _ in range(3):
            if keep.sum() < min_points:
                break
            coefficients = np.linalg.lstsq(design[keep], d[keep], rcond=None)[0].astype(np.float64)
            residual = np.abs(design @ coefficients - d)
            spread = max(float(np.median(residual[keep])), 0.25)
            keep = residual <= 3.0 * spread
        enough = keep.sum() >= max(min_points, _MIN_INLIER_SHARE * x.size)
        if enough and float(np.median(residual[keep])) <= max_residual_px:
            a[region], b[region], c[region] = coefficients
            ok[region] = True
    return _Plane(a, b, c, ok)


class SegmentMatcher:
    """The segmentation-based hybrid matcher (see the module docstring).

    Args:
        config: Matcher parameters.
    """

    def __init__(self, config: SegmentConfig) -> None:
        self._config = config
        self._sad = SadMatcher(
            SadConfig(
                kind="sad",
                num_disparities=config.num_disparities,
                block_size=config.block_size,
                texture_threshold=config.texture_threshold,
                uniqueness_ratio=config.uniqueness_ratio,
                pad_left=config.pad_left,
            )
        )
        self.last_filled: BoolArray | None = None
        self.last_unchecked: BoolArray | None = None
        """Pixels of the last result that were filled from a plane rather than measured."""

    @property
    def num_disparities(self) -> int:
        """Width of the disparity search range in pixels."""
        return self._config.num_disparities

    def compute(self, left: Image, right: Image) -> FloatArray:
        """Match a rectified grey pair; see :class:`avoidd.vision.matchers.base.Matcher`."""
        cfg = self._config
        regions, count = segment_regions(
            lightness(left), cfg.clusters, cfg.open_px, cfg.min_region_px
        )
        boundary = boundary_band(regions, cfg.boundary_px)
        disparity = self._sad.compute(left, right)
        disparity[~boundary] = np.nan
        planes = fit_region_planes(
            regions, count, disparity, cfg.min_boundary_px, cfg.max_residual_px
        )
        interior = ~boundary & (regions >= 0)
        ys, xs = np.nonzero(interior)
        ids = regions[ys, xs]
        fill = planes.ok[ids]
        ys, xs, ids = ys[fill], xs[fill], ids[fill]
        values = planes.a[ids] * xs + planes.b[ids] * ys + planes.c[ids]
        inside = (values >= 0.0) & (values < cfg.num_disparities)
        disparity[ys[inside], xs[inside]] = values[inside].astype(np.float32)
        filled = np.zeros(left.shape, np.bool_)
        filled[ys[inside], xs[inside]] = True
        self.last_filled = filled
        return disparity
