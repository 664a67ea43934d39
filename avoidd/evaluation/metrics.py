"""Disparity quality measures, as the Middlebury and KITTI benchmarks define them."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from avoidd.evaluation.datasets import Calib
from avoidd.types import BoolArray, FloatArray

THRESHOLDS_PX = (1.0, 2.0, 4.0)

REGIONS = ("all", "overlap")
"""Pixels scored: ``all`` with ground truth, or only those in the ``overlap`` both views see."""


def region_mask(shape: tuple[int, ...], num_disparities: int, region: str) -> BoolArray:
    """The pixels of a left view that ``region`` scores.

    Args:
        shape: The view's shape, (H, W) or (H, W, C).
        num_disparities: The search range: the first ``num_disparities`` columns are the left
            border band, where a match over the whole range would fall outside the right view.
        region: ``all`` (every pixel) or ``overlap`` (columns ``num_disparities`` and right).

    Raises:
        ValueError: An unknown region.
    """
    if region not in REGIONS:
        raise ValueError(f"region {region!r}: use one of {', '.join(REGIONS)}")
    mask = np.ones(shape[:2], dtype=bool)
    if region == "overlap":
        mask[:, :num_disparities] = False
    return mask


@dataclass(frozen=True)
class Scores:
    """Scores of one disparity map (percentages 0 to 100).

    Attributes:
        bad1: Pixels with ground truth whose estimate is missing or off by more than 1 px.
        bad2: The same at 2 px.
        bad4: The same at 4 px.
        density: Pixels with ground truth that have an estimate.
        avgerr: Mean absolute disparity error (px) where both exist.
        depth_bad10: Pixels with ground truth whose depth is missing or off by more than 10%
            (None without a calibration).
        ms: Matching time in milliseconds.
    """

    bad1: float
    bad2: float
    bad4: float
    density: float
    avgerr: float
    depth_bad10: float | None
    ms: float

    def as_dict(self) -> dict[str, float | None]:
        """The scores as a plain dict."""
        return asdict(self)


def score(
    estimate: FloatArray,
    truth: FloatArray,
    calib: Calib | None,
    ms: float,
    region: BoolArray | None = None,
) -> Scores:
    """Score a disparity map against ground truth (NaN = none, in both).

    Every pixel with ground truth in ``region`` counts (default: the whole view, including the
    left border band a matcher cannot fill; see :func:`region_mask`).

    Raises:
        ValueError: No pixel of ``region`` has ground truth.
    """
    known = np.isfinite(truth)
    if region is not None:
        known &= region
    total = int(known.sum())
    if total == 0:
        raise ValueError("the ground truth has no valid pixel in the scored region")
    have = known & np.isfinite(estimate)
    error = np.abs(estimate[have] - truth[have])
    bads = [100.0 * (total - int((error <= t).sum())) / total for t in THRESHOLDS_PX]
    depth_bad10 = None
    if calib is not None:
        with np.errstate(divide="ignore"):  # zero disparity (and doffs): infinitely far
            z_true = calib.focal_px * calib.baseline_m / (truth[have] + calib.doffs_px)
            z_est = calib.focal_px * calib.baseline_m / (estimate[have] + calib.doffs_px)
        good = np.abs(z_est - z_true) <= 0.10 * z_true
        depth_bad10 = 100.0 * (total - int(good.sum())) / total
    return Scores(
        bad1=bads[0],
        bad2=bads[1],
        bad4=bads[2],
        density=100.0 * int(have.sum()) / total,
        avgerr=float(error.mean()) if error.size else float("nan"),
        depth_bad10=depth_bad10,
        ms=ms,
    )


def mean_scores(all_scores: list[Scores]) -> Scores:
    """The plain mean of each score over scenes (depth_bad10 over scenes that have it)."""
    depth = [s.depth_bad10 for s in all_scores if s.depth_bad10 is not None]
    return Scores(
        bad1=float(np.mean([s.bad1 for s in all_scores])),
        bad2=float(np.mean([s.bad2 for s in all_scores])),
        bad4=float(np.mean([s.bad4 for s in all_scores])),
        density=float(np.mean([s.density for s in all_scores])),
        avgerr=float(np.nanmean([s.avgerr for s in all_scores])),
        depth_bad10=float(np.mean(depth)) if depth else None,
        ms=float(np.mean([s.ms for s in all_scores])),
    )


@dataclass(frozen=True)
class Details:
    """Finer figures of one disparity map (``avoidd eval --detail``).

    Attributes:
        whole_px: Estimates on a whole pixel (to 1/32 px), percent of all estimates; SGBM
            reports 1/16 px steps, so estimates spread evenly would give 6.25.
        fine_err: Mean absolute error (px) of the estimates within 1 px of the truth: the
            sub-pixel error.
        band_too_far: In the left border band (the first ``band_px`` columns), estimates that
            read too far (disparity too small) by more than 2 px, percent of the band's
            estimates that have ground truth.
        rest_too_far: The same right of the band.
        band_density: Pixels of the band with ground truth that have an estimate (percent).
    """

    whole_px: float
    fine_err: float
    band_too_far: float
    rest_too_far: float
    band_density: float = float("nan")


def details(estimate: FloatArray, truth: FloatArray, band_px: int) -> Details:
    """The :class:`Details` of one disparity map (NaN = none, in both; NaN where undefined)."""
    valid = np.isfinite(estimate)
    values = estimate[valid]
    whole = np.abs(values - np.round(values)) < 1.0 / 32.0
    known = np.isfinite(truth)
    have = valid & known
    error = estimate - truth
    fine = np.abs(error[have]) <= 1.0
    band = np.zeros(truth.shape, dtype=bool)
    band[:, :band_px] = True

    def too_far(region: np.ndarray) -> float:
        counted = have & region
        if not counted.any():
            return float("nan")
        return 100.0 * float((error[counted] < -2.0).mean())

    return Details(
        whole_px=100.0 * float(whole.mean()) if values.size else float("nan"),
        fine_err=float(np.abs(error[have][fine]).mean()) if fine.any() else float("nan"),
        band_too_far=too_far(band),
        rest_too_far=too_far(~band),
        band_density=(
            100.0 * float(valid[band & known].mean()) if (band & known).any() else float("nan")
        ),
    )


def mean_details(all_details: list[Details]) -> Details:
    """The mean of each figure over scenes (those where it is defined)."""

    def mean(name: str) -> float:
        values = np.array([getattr(d, name) for d in all_details], dtype=np.float64)
        values = values[np.isfinite(values)]
        return float(values.mean()) if values.size else float("nan")

    return Details(
        *(
            mean(name)
            for name in ("whole_px", "fine_err", "band_too_far", "rest_too_far", "band_density")
        )
    )
