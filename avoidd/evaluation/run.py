"""``avoidd eval``: run matchers over datasets with ground truth and score them."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from avoidd.config import (
    CensusConfig,
    PostprocessConfig,
    SadConfig,
    SegmentConfig,
    SgbmConfig,
)
from avoidd.errors import ConfigError
from avoidd.evaluation.datasets import Scene, find_scenes, no_scene_lines
from avoidd.evaluation.metrics import (
    REGIONS,
    Details,
    Scores,
    details,
    mean_details,
    mean_scores,
    region_mask,
    score,
)
from avoidd.progress import Progress
from avoidd.types import FloatArray, Image
from avoidd.vision.matchers import Matcher, create_matcher
from avoidd.vision.postprocess import median_smooth, refine_subpixel, texture_gate
from avoidd.vision.preprocess import to_grey

Compute = Callable[[Image, Image], FloatArray]
"""Grey left and right views in, disparity out (NaN invalid)."""


def _product(
    matcher: Matcher, gated: bool = False, post: PostprocessConfig | None = None
) -> Compute:
    """A matcher followed by avoidd's post-processing, as the pipeline runs it.

    Args:
        matcher: The matcher.
        gated: Also blank what the texture gate rejects, as obstacle detection sees the map.
        post: The post-processing (default: the configuration's defaults).
    """
    post = post or PostprocessConfig()

    def compute(left: Image, right: Image) -> FloatArray:
        disparity = matcher.compute(left, right)
        if post.subpixel_refine:
            disparity = refine_subpixel(left, right, disparity, post.refine_window_px)
        disparity = median_smooth(disparity, post.median_size)
        if gated and post.min_texture_snr > 0:
            textured = texture_gate(left, post.texture_window_px, post.min_texture_snr)
            disparity[~textured] = np.nan
        return disparity

    return compute


def _opencv_sgbm(num_disparities: int) -> Compute:
    """Bare OpenCV SGBM with the parameters most users start from (the baseline to beat)."""
    block = 5
    sgbm = cv2.StereoSGBM.create(
        minDisparity=0,
        numDisparities=num_disparities,
        blockSize=block,
        P1=8 * block * block,
        P2=32 * block * block,
        uniquenessRatio=10,
        speckleWindowSize=100,
        speckleRange=2,
        mode=cv2.StereoSGBM_MODE_SGBM_3WAY,
    )

    def compute(left: Image, right: Image) -> FloatArray:
        raw = np.asarray(sgbm.compute(left, right), dtype=np.int16)
        disparity = raw.astype(np.float32) / np.float32(16.0)
        disparity[raw < 0] = np.nan
        return disparity

    return compute


MATCHERS: dict[str, tuple[str, Callable[[int], Compute]]] = {
    "sgbm": (
        "avoidd's default: SGBM as configured by default, then a 5x5 median",
        lambda n: _product(create_matcher(SgbmConfig(num_disparities=n))),
    ),
    "sgbm-gated": (
        "as sgbm, then the texture gate (the map obstacle detection sees)",
        lambda n: _product(create_matcher(SgbmConfig(num_disparities=n)), gated=True),
    ),
    "sgbm-raw": (
        "SGBM as configured by default, without avoidd's post-processing",
        lambda n: _product(
            create_matcher(SgbmConfig(num_disparities=n)),
            post=PostprocessConfig(median_size=0),
        ),
    ),
    "sgbm-refined": (
        "as sgbm, plus the optional sub-pixel refinement step (subpixel_refine: true)",
        lambda n: _product(
            create_matcher(SgbmConfig(num_disparities=n)),
            post=PostprocessConfig(subpixel_refine=True),
        ),
    ),
    "sgbm-nopad": (
        "as sgbm, leaving the left border band unmatched (pad_left false)",
        lambda n: _product(create_matcher(SgbmConfig(num_disparities=n, pad_left=False))),
    ),
    "sad": (
        "SAD block matching (OpenCV StereoBM, 11x11) with avoidd's post-processing",
        lambda n: _product(create_matcher(SadConfig(kind="sad", num_disparities=n))),
    ),
    "sad-pad": (
        "as sad, also matching the left border band",
        lambda n: _product(create_matcher(SadConfig(kind="sad", num_disparities=n, pad_left=True))),
    ),
    "census": (
        "census (5x5 sparse) + sum of Hamming distances over 11x11, avoidd's post-processing",
        lambda n: _product(create_matcher(CensusConfig(kind="census", num_disparities=n))),
    ),
    "segment": (
        "the paper's hybrid: K-means lightness regions, SAD (9x9) on boundaries, interiors "
        "filled by a plane per region",
        lambda n: _product(create_matcher(SegmentConfig(kind="segment", num_disparities=n))),
    ),
    "opencv-sgbm": (
        "baseline: bare OpenCV SGBM_3WAY, blockSize 5, P1 8*bs^2, P2 32*bs^2, uniqueness 10, "
        "speckle 100/2",
        _opencv_sgbm,
    ),
}


@dataclass
class Run:
    """One matcher's results over the scenes.

    Attributes:
        matcher: The matcher's name in :data:`MATCHERS`.
        region: The pixels scored, ``all`` or ``overlap`` (see :func:`region_mask`).
        threads: OpenCV's thread count while the matcher ran (its ``ms`` were timed so).
        scenes: Per scene, its name and scores.
        num_disparities: Per scene, the search range used.
        details: Per scene, in the order of ``scenes``.
    """

    matcher: str
    region: str = "all"
    threads: int = 1
    scenes: list[tuple[str, Scores]] = field(default_factory=list)
    num_disparities: list[int] = field(default_factory=list)
    details: list[Details] = field(default_factory=list)

    @property
    def mean(self) -> Scores:
        """Mean of each score over the scenes."""
        return mean_scores([s for _, s in self.scenes])

    def as_json(self) -> dict[str, Any]:
        """The run as JSON.

        ``{"matcher", "region", "threads", "scenes": [{"scene", "num_disparities", scores...}],
        "mean": {scores...}}``.
        """
        return {
            "matcher": self.matcher,
            "region": self.region,
            "threads": self.threads,
            "scenes": [
                {"scene": name, "num_disparities": n, **_rounded(s)}
                for (name, s), n in zip(self.scenes, self.num_disparities, strict=True)
            ],
            "mean": _rounded(self.mean),
        }


def _rounded(scores: Scores) -> dict[str, float | None]:
    return {k: (round(v, 3) if v is not None else None) for k, v in scores.as_dict().items()}


def evaluate(
    path: Path,
    matchers: list[str],
    max_scenes: int | None = None,
    *,
    region: str = "all",
    num_disparities: int | None = None,
    threads: int | None = None,
) -> list[Run]:
    """Run each named matcher on every scene found under ``path``.

    Args:
        path: A scene folder, a dataset folder, or a folder of them.
        matchers: Names in :data:`MATCHERS`.
        max_scenes: Stop after this many scenes.
        region: Pixels scored: ``all``, or ``overlap`` (right of the left border band).
        num_disparities: Search range for every scene (rounded up to 16); default: per
            dataset, never from the ground truth (see :mod:`avoidd.evaluation.datasets`).
        threads: OpenCV threads for the run (``cv2.setNumThreads``), restored afterwards;
            default: OpenCV's current setting.

    Raises:
        ConfigError: Unknown matcher name or region, a bad number, or no scene found.
    """
    unknown = [m for m in matchers if m not in MATCHERS]
    if unknown:
        raise ConfigError(
            [f"--matcher {', '.join(unknown)}: unknown; use one of {', '.join(MATCHERS)}"]
        )
    if region not in REGIONS:
        raise ConfigError([f"--region {region}: unknown; use one of {', '.join(REGIONS)}"])
    for option, value in (("--num-disparities", num_disparities), ("--threads", threads)):
        if value is not None and value < 1:
            raise ConfigError([f"{option} {value}: must be 1 or more"])
    scenes: list[Scene] = []
    for scene in find_scenes(path, num_disparities=num_disparities):
        scenes.append(scene)
        if max_scenes is not None and len(scenes) >= max_scenes:
            break
    if not scenes:
        raise ConfigError(no_scene_lines(path))
    if threads is None:
        return _run(scenes, matchers, region, cv2.getNumThreads())
    previous_threads = cv2.getNumThreads()
    cv2.setNumThreads(threads)
    try:
        return _run(scenes, matchers, region, cv2.getNumThreads())
    finally:
        cv2.setNumThreads(previous_threads)


def _run(scenes: list[Scene], matchers: list[str], region: str, threads: int) -> list[Run]:
    runs = [Run(name, region, threads) for name in matchers]
    with Progress(len(scenes) * len(matchers)) as progress:
        for scene in scenes:
            left, right = to_grey(scene.left), to_grey(scene.right)
            scored = region_mask(scene.truth_px.shape, scene.num_disparities, region)
            if not (scored & np.isfinite(scene.truth_px)).any():
                raise ConfigError(
                    [
                        f"{scene.name}: no pixel with ground truth right of the first "
                        f"{scene.num_disparities} columns (--region {region}); give a smaller "
                        "--num-disparities"
                    ]
                )
            for run in runs:
                compute = MATCHERS[run.matcher][1](scene.num_disparities)
                started = time.perf_counter()
                disparity = compute(left, right)
                ms = (time.perf_counter() - started) * 1000.0
                run.scenes.append(
                    (scene.name, score(disparity, scene.truth_px, scene.calib, ms, scored))
                )
                run.num_disparities.append(scene.num_disparities)
                run.details.append(details(disparity, scene.truth_px, scene.num_disparities))
                progress.step(f"{run.matcher} {scene.name}")
    return runs


def format_details(runs: list[Run]) -> str:
    """One row per matcher: its :class:`Details` averaged over the scenes."""
    lines = [
        "means over scenes: estimates on a whole pixel (%; 6.25 if spread evenly over 1/16 "
        "steps); mean error of those within 1 px of the truth (px); estimates too far by more "
        "than 2 px in the left border band (columns < ndisp) and right of it (% of the "
        "estimates there with ground truth); the band's density (% of its pixels with ground "
        "truth)",
        f"{'matcher':<14} {'whole%':>7} {'fine px':>8} {'band far%':>10} {'rest far%':>10} "
        f"{'band dens%':>11}",
    ]
    for run in runs:
        d = mean_details(run.details)
        band = f"{d.band_too_far:10.1f}" if np.isfinite(d.band_too_far) else f"{'-':>10}"
        lines.append(
            f"{run.matcher:<14} {d.whole_px:7.1f} {d.fine_err:8.3f} {band} {d.rest_too_far:10.1f} "
            f"{d.band_density:11.1f}"
        )
    return "\n".join(lines)


def format_runs(runs: list[Run]) -> str:
    """A table per matcher: one row per scene and the mean."""
    lines: list[str] = []
    header = (
        f"{'scene':<30} {'ndisp':>5} {'bad1':>6} {'bad2':>6} {'bad4':>6} {'dens':>6} "
        f"{'avgerr':>7} {'Z>10%':>6} {'ms':>7}"
    )
    for run in runs:
        region = (
            "all pixels with ground truth"
            if run.region == "all"
            else "overlap only (columns >= ndisp)"
        )
        lines += [
            f"matcher {run.matcher}: {MATCHERS[run.matcher][0]}",
            f"scored: {region}; ms with {run.threads} OpenCV thread(s)",
            header,
        ]
        rows = [(*scene, str(n)) for scene, n in zip(run.scenes, run.num_disparities, strict=True)]
        for name, s, ndisp in [*rows, ("MEAN", run.mean, "")]:
            depth = f"{s.depth_bad10:6.1f}" if s.depth_bad10 is not None else f"{'-':>6}"
            lines.append(
                f"{name:<30} {ndisp:>5} {s.bad1:6.1f} {s.bad2:6.1f} {s.bad4:6.1f} "
                f"{s.density:6.1f} {s.avgerr:7.2f} {depth} {s.ms:7.1f}"
            )
        lines.append("")
    return "\n".join(lines)
