"""Offline processing of every frame of a source into one JSON object per frame."""

from __future__ import annotations

import json
import logging
import math
import statistics
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from avoidd.config import AppConfig, FilesSourceConfig, HeadConfig, HistogramConfig
from avoidd.errors import BrokenFrame, ConfigError, SourceExhausted
from avoidd.loading import obstacle_range_cm
from avoidd.mavlink.codec import Codec
from avoidd.mavlink.messages import sectors_to_cm
from avoidd.perception.sectors import bin_of_bearing
from avoidd.perception.temporal import SectorFilter
from avoidd.pipeline import STAGES, HeadPipeline
from avoidd.progress import Progress
from avoidd.sources import open_source
from avoidd.sources.truth import nearest_obstacle
from avoidd.types import FloatArray, Nearest, VehicleSample
from avoidd.vision.calibration import Calibration
from avoidd.vision.depth import depth_histogram

logger = logging.getLogger(__name__)


@dataclass
class ReplaySummary:
    """Totals of a replay run.

    Attributes:
        source: What was read (the source's description).
        frames: Frames processed.
        dropped: Frames dropped as broken.
        stage_ms: Mean milliseconds per stage.
        distance_errors_pct: Per frame, nearest distance error against the synthetic truth.
        bin_matches: Per frame, whether the nearest bin is the truth's bin.
        ended_early: How the source fell short of the frames its file announces (None: it
            did not).
    """

    source: str = ""
    frames: int = 0
    dropped: int = 0
    stage_ms: dict[str, float] = field(default_factory=dict)
    distance_errors_pct: list[float] = field(default_factory=list)
    bin_matches: list[bool] = field(default_factory=list)
    ended_early: str | None = None


def select_head(config: AppConfig, name: str | None) -> HeadConfig:
    """The head to replay: the named one, or the only/first one.

    Raises:
        ConfigError: No head has that name.
    """
    if name is None:
        return config.heads[0]
    for head in config.heads:
        if head.name == name:
            return head
    names = ", ".join(h.name for h in config.heads)
    raise ConfigError([f"--head {name}: no such head; the config has {names}"])


def _nearest_json(nearest: Nearest | None) -> dict[str, float] | None:
    if nearest is None:
        return None
    return {
        "distance_m": round(nearest.distance_m, 4),
        "bearing_deg": round(nearest.bearing_deg, 2),
    }


def _vehicle_json(vehicle: VehicleSample | None) -> dict[str, float | None] | None:
    """A recorded heading and local position (None for unknown values)."""
    if vehicle is None:
        return None
    return {
        name: round(value, 4) if math.isfinite(value) else None
        for name, value in vehicle._asdict().items()
    }


class _RealTime:
    """Sleeps so that frames go through at the pace of their capture times."""

    def __init__(self) -> None:
        self._first_ns: int | None = None
        self._started = 0.0

    def wait(self, t_capture_ns: int) -> None:
        if self._first_ns is None or t_capture_ns < self._first_ns:
            self._first_ns, self._started = t_capture_ns, time.monotonic()
            return
        due = self._started + (t_capture_ns - self._first_ns) / 1e9
        delay = due - time.monotonic()
        if delay > 0:
            time.sleep(delay)


def _frame_count(source: object, max_frames: int | None) -> int | None:
    """How many frames a replay will take, when known (for the progress bar)."""
    try:
        total: int | None = len(source)  # type: ignore[arg-type]
    except TypeError:
        total = None
    if max_frames is not None:
        total = max_frames if total is None else min(total, max_frames)
    return total


def replay(
    config: AppConfig,
    calibration: Calibration,
    head: HeadConfig,
    out: IO[str],
    input_path: Path | None = None,
    max_frames: int | None = None,
    realtime: bool = False,
) -> ReplaySummary:
    """Process every frame of a head's source and write JSON lines.

    Each line holds ``seq``, ``t_capture_ns``, ``nearest`` (``{"distance_m", "bearing_deg"}`` of
    the frame's own scan, or null), ``sectors_cm`` (the 72 values as they would be sent, after
    the temporal filter), ``raw_sectors_cm`` (before it), ``obstacles`` (see
    :meth:`avoidd.perception.obstacles.Obstacle.to_json`), ``pose`` (attitude and height used),
    ``timing_ms`` per stage, ``vehicle`` (a recording's heading and local position, or null)
    and, for the synthetic source, ``truth`` (``{"nearest_m", "nearest_bearing_deg"}``).

    Args:
        config: The configuration.
        calibration: The head's calibration.
        head: The head to replay.
        out: Where the JSON lines go.
        input_path: A folder or side-by-side video to read instead of the configured source.
        max_frames: Stop after this many frames.
        realtime: Pace frames by their capture times (a recording plays at its recorded
            speed) instead of going as fast as possible.

    A recorded source is read once, even when its config says ``loop`` (the daemon's
    playback setting): a replay ends.

    Returns:
        Totals of the run.
    """
    od = config.mavlink.obstacle_distance
    min_cm, max_cm = obstacle_range_cm(od, [(head, calibration)])
    pipeline = HeadPipeline(head, calibration, max_cm / 100.0, config.perception)
    temporal = SectorFilter(config.perception.temporal)
    codec = Codec(config.mavlink.fixed_system_id or 1, config.mavlink.component_id)
    config_source = head.source
    if isinstance(config_source, FilesSourceConfig) and config_source.loop:
        config_source = config_source.model_copy(update={"loop": False})
    source = open_source(
        config_source, calibration.rig, head.name, paced=False, input_path=input_path
    )
    summary = ReplaySummary(source=source.description)
    totals: dict[str, list[float]] = {stage: [] for stage in (*STAGES, "encode")}
    pace = _RealTime() if realtime else None
    progress = Progress(_frame_count(source, max_frames))
    try:
        while max_frames is None or summary.frames < max_frames:
            try:
                frame = source.read()
                if pace is not None:
                    pace.wait(frame.t_capture_ns)
                result = pipeline.process(frame, with_obstacles=True)
            except BrokenFrame as exc:
                summary.dropped += 1
                logger.warning("%s", exc)
                progress.step("dropped")
                continue
            except SourceExhausted as exc:
                if exc.early:
                    logger.warning("%s", exc)
                    summary.ended_early = str(exc)
                break
            started = time.perf_counter()
            scan = temporal.update(result.scan)
            sectors_cm = sectors_to_cm(scan, min_cm, max_cm)
            codec.pack(
                codec.obstacle_distance(result.t_capture_ns // 1000, sectors_cm, min_cm, max_cm)
            )
            timing = {**result.timing_ms, "encode": (time.perf_counter() - started) * 1000.0}
            nearest = result.scan.nearest()
            pose = result.pose
            record: dict[str, Any] = {
                "head": head.name,
                "seq": result.seq,
                "t_capture_ns": result.t_capture_ns,
                "nearest": _nearest_json(nearest),
                "sectors_cm": sectors_cm,
                "raw_sectors_cm": sectors_to_cm(result.scan, min_cm, max_cm),
                "obstacles": [o.to_json() for o in result.obstacles],
                "pose": None
                if pose is None
                else {
                    "roll_deg": round(pose.roll_deg, 2),
                    "pitch_deg": round(pose.pitch_deg, 2),
                    "height_m": round(pose.height_m, 3),
                    "source": pose.source,
                    "height_source": pose.height_source,
                },
                "vehicle": _vehicle_json(frame.vehicle),
                "valid_fraction": round(result.valid_fraction, 4),
                "timing_ms": {k: round(v, 3) for k, v in timing.items()},
                "preprocess_steps_ms": {k: round(v, 3) for k, v in result.steps_ms.items()},
                "depth_histogram": _histogram_json(result.depth_m, head.histogram),
            }
            if frame.truth is not None and pose is not None:
                truth = nearest_obstacle(frame.truth, pipeline.mount, pose, config.perception)
                record["truth"] = {
                    "nearest_m": round(truth.distance_m, 4) if truth else None,
                    "nearest_bearing_deg": round(truth.bearing_deg, 2) if truth else None,
                }
                if truth is not None and nearest is not None:
                    error = 100.0 * (nearest.distance_m / truth.distance_m - 1.0)
                    summary.distance_errors_pct.append(error)
                    same = int(bin_of_bearing(truth.bearing_deg)) == int(
                        bin_of_bearing(nearest.bearing_deg)
                    )
                    summary.bin_matches.append(same)
            out.write(json.dumps(record, separators=(",", ":")) + "\n")
            for stage, value in timing.items():
                totals[stage].append(value)
            summary.frames += 1
            progress.step(f"frame {result.seq}")
    finally:
        progress.close()
        source.close()
    summary.stage_ms = {k: statistics.fmean(v) for k, v in totals.items() if v}
    return summary


def _histogram_json(depth_m: FloatArray, config: HistogramConfig) -> dict[str, list[Any]]:
    """The frame's depth histogram (computed here, off the daemon's hot path)."""
    edges, counts = depth_histogram(depth_m, config.min_m, config.max_m, config.bins)
    return {"edges_m": [round(float(e), 3) for e in edges], "counts": counts.tolist()}


def format_summary(summary: ReplaySummary) -> str:
    """A short human-readable report of a replay run."""
    lines = [f"frames {summary.frames}, dropped {summary.dropped}"]
    if summary.ended_early is not None:
        lines.append(f"input ended early: {summary.ended_early}")
    if summary.stage_ms:
        total = sum(summary.stage_ms.values())
        stages = ", ".join(f"{k} {v:.1f}" for k, v in summary.stage_ms.items())
        lines.append(f"mean ms per stage: {stages} (total {total:.1f})")
    if summary.distance_errors_pct:
        errors = summary.distance_errors_pct
        abs_errors = [abs(e) for e in errors]
        lines.append(
            f"nearest vs truth: median error {statistics.median(errors):+.2f}%, "
            f"max |error| {max(abs_errors):.2f}%, "
            f"same bin {sum(summary.bin_matches)}/{len(summary.bin_matches)}"
        )
    return "\n".join(lines)
