"""``avoidd bench``: per-stage milliseconds of the vision pipeline, next to bare OpenCV SGBM.

Frames are rendered by the synthetic scene at each resolution and pushed through the real
:class:`~avoidd.pipeline.HeadPipeline` with a calibration that needs remapping (so the rectify
stage does real work). In the same run and on the same frames, bare ``StereoSGBM.compute``
(MODE_SGBM_3WAY, blockSize 5) is timed, and every figure is also given as a ratio to it, so
that results compare across machines.
"""

from __future__ import annotations

import statistics
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from avoidd.config import (
    CensusConfig,
    HeadConfig,
    HistogramConfig,
    MatcherConfig,
    MountConfig,
    PostprocessConfig,
    SadConfig,
    SectorsConfig,
    SegmentConfig,
    SgbmConfig,
    SyntheticSourceConfig,
)
from avoidd.evaluation.progress import Progress
from avoidd.mavlink.codec import Codec
from avoidd.mavlink.messages import sectors_to_cm
from avoidd.pipeline import HeadPipeline
from avoidd.sources.scene import render_pair, to_uint8
from avoidd.sources.synthetic import scene_at
from avoidd.types import RectifiedRig, StereoFrame
from avoidd.vision.calibration import Calibration, RectifyMaps
from avoidd.vision.preprocess import to_grey
from avoidd.vision.rectify import rectify_pair

RESOLUTIONS = ((320, 240), (640, 480), (1280, 720))
DISPARITIES = (64, 128)
STAGES = ("rectify", "preprocess", "match", "post", "depth", "obstacles", "encode")


def _matcher(name: str, num_disparities: int) -> MatcherConfig:
    if name == "sad":
        return SadConfig(kind="sad", num_disparities=num_disparities)
    if name == "census":
        return CensusConfig(kind="census", num_disparities=num_disparities)
    if name == "segment":
        return SegmentConfig(kind="segment", num_disparities=num_disparities)
    return SgbmConfig(num_disparities=num_disparities)


def _rig(width: int, height: int) -> RectifiedRig:
    focal_px = 0.625 * width  # about 77 degrees horizontal field of view
    return RectifiedRig(
        width, height, focal_px, focal_px, (width - 1) / 2, (height - 1) / 2, 0.12, 0.0
    )


def _maps(rig: RectifiedRig) -> RectifyMaps:
    """Remap tables of a slightly distorted camera (timing only: realistic work per pixel)."""
    k = np.array([[rig.fx, 0, rig.cx], [0, rig.fy, rig.cy], [0, 0, 1]], dtype=np.float64)
    dist = np.array([-0.02, 0.001, 0.0, 0.0], dtype=np.float64)
    size = (rig.width, rig.height)
    left = cv2.initUndistortRectifyMap(k, dist, np.eye(3), k, size, cv2.CV_16SC2)
    right = cv2.initUndistortRectifyMap(k, dist, np.eye(3), k, size, cv2.CV_16SC2)
    return RectifyMaps(
        (np.asarray(left[0], np.int16), np.asarray(left[1], np.uint16)),
        (np.asarray(right[0], np.int16), np.asarray(right[1], np.uint16)),
    )


def _frames(rig: RectifiedRig, count: int) -> list[StereoFrame]:
    scene = scene_at(SyntheticSourceConfig(kind="synthetic", seed=1), 0.0)
    rendered = render_pair(scene, rig)
    rng = np.random.default_rng(0)
    frames = []
    for seq in range(count):
        noise = rng.normal(0.0, 1.5, rendered.left.shape).astype(np.float32)
        left = to_uint8(rendered.left, noise)
        right = to_uint8(
            rendered.right, rng.normal(0.0, 1.5, rendered.left.shape).astype(np.float32)
        )
        frames.append(StereoFrame(seq, time.monotonic_ns(), left, right))
    return frames


def _head(matcher: MatcherConfig) -> HeadConfig:
    # Built without validation: the calibration comes as an object, not a file.
    return HeadConfig.model_construct(
        name="bench",
        calibration=Path("bench"),
        mount=MountConfig(),
        source=SyntheticSourceConfig(kind="synthetic"),
        matcher=matcher,
        postprocess=PostprocessConfig(),
        sectors=SectorsConfig(),
        histogram=HistogramConfig(),
    )


def run_bench(
    matchers: list[str],
    resolutions: tuple[tuple[int, int], ...] = RESOLUTIONS,
    disparities: tuple[int, ...] = DISPARITIES,
    frames: int = 5,
) -> list[dict[str, Any]]:
    """Time every stage for each matcher, resolution, disparity range and thread setting.

    Returns:
        One record per configuration: ``matcher``, ``width``, ``height``, ``disparities``,
        ``threads``, ``stages_ms`` (medians), ``total_ms``, ``opencv_sgbm_ms`` and the ratios
        ``match_vs_opencv``, ``total_vs_opencv`` and ``non_match_vs_match``.
    """
    all_threads = cv2.getNumberOfCPUs()
    codec = Codec(1, 196)
    records: list[dict[str, Any]] = []
    steps = len(resolutions) * len(disparities) * 2 * len(matchers)
    progress = Progress(steps)
    previous_threads = cv2.getNumThreads()
    try:
        for width, height in resolutions:
            rig = _rig(width, height)
            calibration = Calibration(rig, _maps(rig), Path("bench"))
            pairs = _frames(rig, frames)
            for num_disparities in disparities:
                for threads in (1, all_threads):
                    cv2.setNumThreads(threads)
                    baseline_ms = _opencv_sgbm_ms(pairs, calibration, num_disparities)
                    for name in matchers:
                        pipeline = HeadPipeline(
                            _head(_matcher(name, num_disparities)), calibration, 20.0
                        )
                        stages = _time_pipeline(pipeline, pairs, codec)
                        total = sum(stages.values())
                        records.append(
                            {
                                "matcher": name,
                                "width": width,
                                "height": height,
                                "disparities": num_disparities,
                                "threads": threads,
                                "stages_ms": {k: round(v, 3) for k, v in stages.items()},
                                "total_ms": round(total, 3),
                                "opencv_sgbm_ms": round(baseline_ms, 3),
                                "match_vs_opencv": round(stages["match"] / baseline_ms, 3),
                                "total_vs_opencv": round(total / baseline_ms, 3),
                                "non_match_vs_match": round(
                                    (total - stages["match"]) / stages["match"], 3
                                ),
                            }
                        )
                        progress.step(f"{name} {width}x{height}/{num_disparities} t{threads}")
    finally:
        cv2.setNumThreads(previous_threads)
    return records


def _opencv_sgbm_ms(
    pairs: list[StereoFrame], calibration: Calibration, num_disparities: int
) -> float:
    """Median time of bare OpenCV SGBM (3WAY, blockSize 5) on the rectified grey frames."""
    sgbm = cv2.StereoSGBM.create(
        minDisparity=0,
        numDisparities=num_disparities,
        blockSize=5,
        P1=8 * 25,
        P2=32 * 25,
        uniquenessRatio=10,
        speckleWindowSize=100,
        speckleRange=2,
        mode=cv2.StereoSGBM_MODE_SGBM_3WAY,
    )
    grey = []
    for frame in pairs:
        left, right = rectify_pair(frame.left, frame.right, calibration.maps)
        grey.append((to_grey(left), to_grey(right)))
    sgbm.compute(*grey[0])  # warm-up
    times = []
    for left, right in grey:
        started = time.perf_counter()
        sgbm.compute(left, right)
        times.append((time.perf_counter() - started) * 1000.0)
    return statistics.median(times)


def _time_pipeline(
    pipeline: HeadPipeline, pairs: list[StereoFrame], codec: Codec
) -> dict[str, float]:
    pipeline.process(pairs[0])  # warm-up
    per_stage: dict[str, list[float]] = {stage: [] for stage in STAGES}
    for frame in pairs:
        result = pipeline.process(frame)
        started = time.perf_counter()
        codec.pack(codec.obstacle_distance(0, sectors_to_cm(result.scan, 20, 2000), 20, 2000))
        encode_ms = (time.perf_counter() - started) * 1000.0
        timing = {**result.timing_ms, "encode": encode_ms}
        for stage in STAGES:
            per_stage[stage].append(timing[stage])
    return {stage: statistics.median(values) for stage, values in per_stage.items()}


def format_bench(records: list[dict[str, Any]]) -> str:
    """One row per configuration."""
    head = (
        f"{'matcher':<8} {'size':>9} {'disp':>4} {'thr':>3} "
        + " ".join(f"{s[:7]:>7}" for s in STAGES)
        + f" {'total':>7} {'opencv':>7} {'match/cv':>8} {'rest/match':>10}"
    )
    lines = [head]
    for r in records:
        stages = " ".join(f"{r['stages_ms'][s]:7.2f}" for s in STAGES)
        lines.append(
            f"{r['matcher']:<8} {r['width']:>4}x{r['height']:<4} {r['disparities']:>4} "
            f"{r['threads']:>3} {stages} {r['total_ms']:7.2f} {r['opencv_sgbm_ms']:7.2f} "
            f"{r['match_vs_opencv']:8.2f} {r['non_match_vs_match']:10.2f}"
        )
    return "\n".join(lines)
