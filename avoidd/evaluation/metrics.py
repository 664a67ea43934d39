"""Disparity quality measures, as the Middlebury and KITTI benchmarks define them."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from avoidd.evaluation.datasets import Calib
from avoidd.types import FloatArray

THRESHOLDS_PX = (1.0, 2.0, 4.0)


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


def score(estimate: FloatArray, truth: FloatArray, calib: Calib | None, ms: float) -> Scores:
    """Score a disparity map against ground truth (NaN = none, in both).

    Every pixel with ground truth counts, including the left border band a matcher cannot fill.
    """
    known = np.isfinite(truth)
    total = int(known.sum())
    if total == 0:
        raise ValueError("the ground truth has no valid pixel")
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
