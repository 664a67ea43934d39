"""``avoidd bench``: per-stage milliseconds of the vision pipeline, next to bare OpenCV SGBM.

Frames are rendered by the synthetic scene at each resolution and pushed through the real
:class:`~avoidd.pipeline.HeadPipeline` with a calibration that needs remapping (so the rectify
stage does real work). In the same run and on the same frames, bare ``StereoSGBM.compute``
(MODE_SGBM_3WAY, blockSize 5) is timed, and every figure is also given as a ratio to it, so
that results compare across machines.

A recorded sequence can be timed too (:func:`euroc_frames`): the rendered scene is mostly
ground and open space, while a camera flying in a room sees walls in most pixels. The
worst-case set (:func:`worst_case_frames`) renders such frames on purpose: a wall filling most of
the view at 1, 3 and 8 m and a dense pole forest, where most pixels are obstacle points. The
obstacle stage is also timed with the obstacle list (``with_obstacles``, as ``replay`` asks for
it), in its own column.
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
from avoidd.sources.scene import (
    FIRST_OBSTACLE_ID,
    Box,
    Pole,
    RenderedPair,
    Scene,
    render_pair,
    to_uint8,
)
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
WORST_CASE = ("wall-1m", "wall-3m", "wall-8m", "poles")
"""The worst-case frame sets, by name (see :func:`worst_case_frames`)."""
WORST_CASE_SIZE = (640, 480)


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
    return _noisy(render_pair(scene, rig), count)


def _noisy(rendered: RenderedPair, count: int) -> list[StereoFrame]:
    """``count`` frames of one rendered pair, each with fresh sensor noise."""
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
        mount: The mount the frames were rendered with (the pipeline is given it).
        filled: Share of the view the obstacles fill (rendered worst-case sets; else None).
    """

    source: str
    calibration: Calibration
    pairs: list[StereoFrame]
    mount: MountConfig = MountConfig()
    filled: float | None = None


def synthetic_frames(width: int, height: int, count: int) -> FrameSet:
    """The rendered scene at one resolution, with fresh sensor noise on every frame."""
    rig = _rig(width, height)
    return FrameSet("synthetic", Calibration(rig, _maps(rig), Path("bench")), _frames(rig, count))


def worst_case_scene(name: str, rig: RectifiedRig) -> tuple[Scene, float]:
    """A worst-case scene for the obstacle stage and the mount pitch it is seen with.

    ``wall-<D>m``: a wall at D metres, wide enough to fill about 80% of the view (at 8 m the
    camera is pitched up 15 degrees, so the ground in front of the wall stays small).
    ``poles``: a dense forest of poles from 1.5 to 12 m.

    Args:
        name: One of :data:`WORST_CASE`.
        rig: The rig it is rendered for.

    Returns:
        The scene and its camera pitch in degrees (positive up).

    Raises:
        ValueError: An unknown name.
    """
    half_width = (rig.width / 2) / rig.fx  # tangent of half the horizontal field of view
    height_m = SyntheticSourceConfig.model_fields["camera_height_m"].default
    if name.startswith("wall-") and name.endswith("m"):
        distance_m = float(name[5:-1])
        pitch_deg = 15.0 if distance_m > 5.0 else 0.0
        depth_m = 0.3
        wall = Box(distance_m + depth_m / 2, 0.0, depth_m, 1.8 * distance_m * half_width, 14.0)
        return Scene(height_m, pitch_deg, (wall,), 45.0, 5), pitch_deg
    if name == "poles":
        rng = np.random.default_rng(11)
        poles: list[Box | Pole] = []
        for forward_m in np.arange(1.5, 12.0, 0.7):
            spread_m = forward_m * half_width + 1.0
            for right_m in np.arange(-spread_m, spread_m, 0.9):
                poles.append(
                    Pole(
                        float(forward_m + rng.uniform(-0.25, 0.25)),
                        float(right_m + rng.uniform(-0.3, 0.3)),
                        float(rng.uniform(0.1, 0.35)),
                        float(rng.uniform(3.0, 6.0)),
                    )
                )
        return Scene(height_m, 0.0, tuple(poles), 45.0, 6), 0.0
    raise ValueError(f"unknown worst-case frame set {name!r}; known: {', '.join(WORST_CASE)}")


def worst_case_frames(name: str, width: int, height: int, count: int) -> FrameSet:
    """One worst-case frame set (see :func:`worst_case_scene`).

    Args:
        name: One of :data:`WORST_CASE`.
        width: Image width.
        height: Image height.
        count: Frames (each with fresh sensor noise).

    Returns:
        The frames, named after the set, with the share of the view the obstacles fill (exact,
        from the renderer's ground truth).
    """
    rig = _rig(width, height)
    scene, pitch_deg = worst_case_scene(name, rig)
    rendered = render_pair(scene, rig)
    ids = rendered.truth.object_id
    return FrameSet(
        name,
        Calibration(rig, _maps(rig), Path("bench")),
        _noisy(rendered, count),
        MountConfig(pitch_deg=pitch_deg),
        float(np.count_nonzero(ids >= FIRST_OBSTACLE_ID)) / ids.size,
    )


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


def _head(matcher: MatcherConfig, mount: MountConfig | None = None) -> HeadConfig:
    # Built without validation: the calibration comes as an object, not a file.
    return HeadConfig.model_construct(
        name="bench",
        calibration=Path("bench"),
        mount=mount or MountConfig(),
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
    with_list: bool = False,
) -> list[dict[str, Any]]:
    """Time every stage for each matcher, frame set, disparity range and thread setting.

    Args:
        matchers: Matcher names.
        resolutions: Sizes of the rendered frame sets.
        disparities: Disparity ranges.
        frames: Rendered frames per size.
        recorded: More frame sets (the worst-case ones of :func:`worst_case_frames`, recorded
            ones of :func:`euroc_frames`), timed after the rendered ones.
        with_list: Also time the obstacle stage with the obstacle list, in a second pass over
            the same frames.

    Returns:
        One record per configuration: ``matcher``, ``source``, ``width``, ``height``,
        ``disparities``, ``threads``, ``stages_ms`` (medians), ``total_ms``,
        ``opencv_sgbm_ms``, the ratios ``match_vs_opencv``, ``total_vs_opencv`` and
        ``non_match_vs_match``, ``candidates`` (median share of the pixels that are obstacle
        points), ``filled`` (the frame set's, or None) and, with ``with_list``,
        ``obstacles_list_ms`` (median obstacle stage with the list; else None).
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
                            _head(_matcher(name, num_disparities), frame_set.mount),
                            frame_set.calibration,
                            20.0,
                        )
                        stages, candidates = _time_pipeline(pipeline, frame_set.pairs, codec)
                        list_ms = _time_list(pipeline, frame_set.pairs) if with_list else None
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
                                "candidates": round(candidates, 3),
                                "filled": frame_set.filled,
                                "obstacles_list_ms": None if list_ms is None else round(list_ms, 3),
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
) -> tuple[dict[str, float], float]:
    """Median milliseconds per stage, and the median share of pixels kept as obstacle points."""
    pipeline.process(pairs[0])  # warm-up
    per_stage: dict[str, list[float]] = {stage: [] for stage in STAGES}
    candidates = []
    for frame in pairs:
        result = pipeline.process(frame)
        candidates.append(
            getattr(result, "obstacle_points", 0)
            / max(frame.left.shape[0] * frame.left.shape[1], 1)
        )
        started = time.perf_counter()
        codec.pack(codec.obstacle_distance(0, sectors_to_cm(result.scan, 20, 2000), 20, 2000))
        encode_ms = (time.perf_counter() - started) * 1000.0
        timing = {**result.timing_ms, "encode": encode_ms}
        for stage in STAGES:
            per_stage[stage].append(timing[stage])
    medians = {stage: statistics.median(values) for stage, values in per_stage.items()}
    return medians, statistics.median(candidates)


def _time_list(pipeline: HeadPipeline, pairs: list[StereoFrame]) -> float:
    """Median milliseconds of the obstacle stage when it also lists the obstacles."""
    return statistics.median(
        pipeline.process(frame, with_obstacles=True).timing_ms["obstacles"] for frame in pairs
    )


def format_bench(records: list[dict[str, Any]]) -> str:
    """One row per configuration.

    ``+list`` is the obstacle stage with the obstacle list (``-`` when not timed), ``cand%``
    the share of the pixels that are obstacle points, ``fill%`` the share of the view that
    the obstacles fill (rendered worst-case sets only).
    """
    head = (
        f"{'matcher':<8} {'frames':<16} {'size':>9} {'disp':>4} {'thr':>3} "
        + " ".join(f"{s[:7]:>7}" for s in STAGES)
        + f" {'+list':>7} {'total':>7} {'opencv':>7} {'match/cv':>8} {'rest/match':>10}"
        + f" {'cand%':>5} {'fill%':>5}"
    )
    lines = [head]
    for r in records:
        stages = " ".join(f"{r['stages_ms'][s]:7.2f}" for s in STAGES)
        listed = r.get("obstacles_list_ms")
        filled = r.get("filled")
        lines.append(
            f"{r['matcher']:<8} {r['source'][:16]:<16} {r['width']:>4}x{r['height']:<4} "
            f"{r['disparities']:>4} "
            f"{r['threads']:>3} {stages} "
            + (f"{listed:7.2f}" if listed is not None else f"{'-':>7}")
            + f" {r['total_ms']:7.2f} {r['opencv_sgbm_ms']:7.2f} "
            f"{r['match_vs_opencv']:8.2f} {r['non_match_vs_match']:10.2f}"
            f" {100 * r.get('candidates', 0.0):5.1f}"
            + (f" {100 * filled:5.1f}" if filled is not None else f" {'-':>5}")
        )
    return "\n".join(lines)
