"""``avoidd bench``: per-stage milliseconds of the vision pipeline, next to bare OpenCV SGBM.

Frames are rendered by the synthetic scene at each resolution and pushed through the real
:class:`~avoidd.pipeline.HeadPipeline` with a calibration that needs remapping (so the rectify
stage does real work). In the same run and on the same frames, bare ``StereoSGBM.compute``
(MODE_SGBM_3WAY, blockSize 5) is timed, and every figure is also given as a ratio to it, so
that results compare across machines.

A recorded sequence can be timed too (:func:`euroc_frames`): the rendered scene is mostly
ground and open space, while a camera flying in a room sees walls in most pixels, and the
obstacle stage's cost grows with the number of obstacle points.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NamedTuple

import cv2
import numpy as np

from avoidd.calibrate.importers import euroc_stereo
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
from avoidd.errors import ConfigError
from avoidd.mavlink.codec import Codec
from avoidd.mavlink.messages import sectors_to_cm
from avoidd.pipeline import HeadPipeline
from avoidd.progress import Progress
from avoidd.sources.scene import render_pair, to_uint8
from avoidd.sources.synthetic import scene_at
from avoidd.types import RectifiedRig, StereoFrame
from avoidd.vision.calibration import Calibration, RectifyMaps, rectify_stereo
from avoidd.vision.preprocess import to_grey
from avoidd.vision.rectify import rectify_pair

RESOLUTIONS = ((320, 240), (640, 480), (1280, 720))
DISPARITIES = (64, 128)
MATCHERS = ("sgbm", "sad", "census", "segment")
"""Every matcher the bench knows, in the order it reports them."""
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


class FrameSet(NamedTuple):
    """Frames to time and the calibration they come with.

    Attributes:
        source: Name shown in the report (``synthetic`` or the sequence's).
        calibration: Their calibration (with remap tables: rectify does real work).
        pairs: The raw stereo pairs.
    """

    source: str
    calibration: Calibration
    pairs: list[StereoFrame]


def synthetic_frames(width: int, height: int, count: int) -> FrameSet:
    """The rendered scene at one resolution, with fresh sensor noise on every frame."""
    rig = _rig(width, height)
    return FrameSet("synthetic", Calibration(rig, _maps(rig), Path("bench")), _frames(rig, count))


def euroc_frames(folder: Path, count: int) -> FrameSet:
    """``count`` pairs spread evenly over a EuRoC sequence, with its own calibration.

    Args:
        folder: The sequence's ``mav0`` folder (or the folder that holds it).
        count: Pairs to take (at least 1).

    Returns:
        The frames (grey, native size) and the calibration imported from the sensor files.

    Raises:
        ConfigError: The folder is not a EuRoC sequence or its images are unreadable.
    """
    mav0 = folder / "mav0" if (folder / "mav0").is_dir() else folder
    left_dir, right_dir = mav0 / "cam0" / "data", mav0 / "cam1" / "data"
    names = sorted(left_dir.glob("*.png")) if left_dir.is_dir() else []
    if not names:
        raise ConfigError(
            [f"bench --euroc {folder}: no cam0/data/*.png; give a EuRoC sequence's mav0 folder"]
        )
    model = euroc_stereo(mav0 / "cam0" / "sensor.yaml", mav0 / "cam1" / "sensor.yaml")
    rig, maps, rotation = rectify_stereo(model)
    picked = [names[i] for i in np.linspace(0, len(names) - 1, max(1, count)).astype(int)]
    pairs = []
    for seq, name in enumerate(picked):
        left = cv2.imread(str(name), cv2.IMREAD_GRAYSCALE)
        right = cv2.imread(str(right_dir / name.name), cv2.IMREAD_GRAYSCALE)
        if left is None or right is None:
            raise ConfigError([f"bench --euroc: cannot read the pair {name.name} in {mav0}"])
        pairs.append(
            StereoFrame(
                seq, time.monotonic_ns(), np.asarray(left, np.uint8), np.asarray(right, np.uint8)
            )
        )
    return FrameSet(mav0.parent.name or "euroc", Calibration(rig, maps, mav0, rotation), pairs)


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
    recorded: Sequence[FrameSet] = (),
) -> list[dict[str, Any]]:
    """Time every stage for each matcher, frame set, disparity range and thread setting.

    Args:
        matchers: Matcher names.
        resolutions: Sizes of the rendered frame sets.
        disparities: Disparity ranges.
        frames: Rendered frames per size.
        recorded: Recorded frame sets (see :func:`euroc_frames`), timed after the rendered ones.

    Returns:
        One record per configuration: ``matcher``, ``source``, ``width``, ``height``,
        ``disparities``, ``threads``, ``stages_ms`` (medians), ``total_ms``,
        ``opencv_sgbm_ms`` and the ratios ``match_vs_opencv``, ``total_vs_opencv`` and
        ``non_match_vs_match``.
    """
    all_threads = cv2.getNumberOfCPUs()
    codec = Codec(1, 196)
    records: list[dict[str, Any]] = []
    steps = (len(resolutions) + len(recorded)) * len(disparities) * 2 * len(matchers)
    progress = Progress(steps)
    previous_threads = cv2.getNumThreads()
    try:
        sets = [synthetic_frames(w, h, frames) for w, h in resolutions] + list(recorded)
        for frame_set in sets:
            rig = frame_set.calibration.rig
            for num_disparities in disparities:
                for threads in (1, all_threads):
                    cv2.setNumThreads(threads)
                    baseline_ms = _opencv_sgbm_ms(
                        frame_set.pairs, frame_set.calibration, num_disparities
                    )
                    for name in matchers:
                        pipeline = HeadPipeline(
                            _head(_matcher(name, num_disparities)), frame_set.calibration, 20.0
                        )
                        stages = _time_pipeline(pipeline, frame_set.pairs, codec)
                        total = sum(stages.values())
                        records.append(
                            {
                                "matcher": name,
                                "source": frame_set.source,
                                "width": rig.width,
                                "height": rig.height,
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
                        progress.step(
                            f"{name} {frame_set.source} {rig.width}x{rig.height}"
                            f"/{num_disparities} t{threads}"
                        )
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
        f"{'matcher':<8} {'frames':<16} {'size':>9} {'disp':>4} {'thr':>3} "
        + " ".join(f"{s[:7]:>7}" for s in STAGES)
        + f" {'total':>7} {'opencv':>7} {'match/cv':>8} {'rest/match':>10}"
    )
    lines = [head]
    for r in records:
        stages = " ".join(f"{r['stages_ms'][s]:7.2f}" for s in STAGES)
        lines.append(
            f"{r['matcher']:<8} {r['source'][:16]:<16} {r['width']:>4}x{r['height']:<4} "
            f"{r['disparities']:>4} "
            f"{r['threads']:>3} {stages} {r['total_ms']:7.2f} {r['opencv_sgbm_ms']:7.2f} "
            f"{r['match_vs_opencv']:8.2f} {r['non_match_vs_match']:10.2f}"
        )
    return "\n".join(lines)
