"""Loading a configuration with everything it refers to: calibrations, signing key, cross-checks."""

from __future__ import annotations

import math
import os
from collections.abc import Iterable
from pathlib import Path

from avoidd.config import (
    AppConfig,
    FilesSourceConfig,
    HeadConfig,
    ObstacleDistanceConfig,
    SimSourceConfig,
    load_config,
)
from avoidd.config.sim import load_world
from avoidd.errors import BrokenFrame, ConfigError, SourceError, SourceExhausted
from avoidd.fileread import not_regular
from avoidd.mavlink.messages import sensor_orientation
from avoidd.mavlink.signing import load_key
from avoidd.sources.files import open_files
from avoidd.types import Mount
from avoidd.vision.calibration import Calibration, load_calibration
from avoidd.vision.depth import resolved_range_m
from avoidd.vision.nearfield import min_range_m
from avoidd.vision.preprocess import scale_rig


def load_all(path: Path, input_given: bool = False) -> tuple[AppConfig, dict[str, Calibration]]:
    """Load a configuration and the calibration of each head, collecting every problem.

    Args:
        path: The configuration file.
        input_given: The command reads its own input (``--input``): a ``files`` source's
            path is neither required nor read.

    Returns:
        The configuration and the calibrations by head name.

    Raises:
        ConfigError: Any problem in the configuration or a calibration file.
    """
    config = load_config(path, input_given)
    calibrations: dict[str, Calibration] = {}
    problems: list[str] = []
    for head in config.heads:
        try:
            calibration = load_calibration(head.calibration)
        except ConfigError as exc:
            problems.extend(exc.lines)
            continue
        source = head.source
        rig = calibration.rig
        if source.kind == "synthetic" and (calibration.maps is not None or rig.doffs_px != 0):
            problems.append(
                f"{head.calibration}: head '{head.name}' renders a synthetic scene, which needs "
                "a 'rectified' calibration with doffs 0"
            )
        if source.kind == "v4l2" and (source.width, source.height) != (rig.width, rig.height):
            problems.append(
                f"{path}: heads.{head.name}.source asks {source.width}x{source.height} but "
                f"{head.calibration} is for {rig.width}x{rig.height}; make them agree"
            )
        if source.kind == "synthetic" and (
            source.camera_pitch_deg != head.mount.pitch_deg or head.mount.roll_deg != 0.0
        ):
            problems.append(
                f"{path}: heads.{head.name}: the synthetic camera is pitched "
                f"{source.camera_pitch_deg} deg but mount.pitch_deg says {head.mount.pitch_deg} "
                f"(roll {head.mount.roll_deg}); make the mount pitch equal camera_pitch_deg, "
                "roll 0"
            )
        problems.extend(_check_resolution(path, head, calibration))
        if isinstance(head.source, SimSourceConfig):
            problems.extend(_check_sim_source(path, head, calibration))
        if config.mavlink.distance_sensor.enabled:
            m = head.mount
            if sensor_orientation(Mount(m.yaw_deg, m.pitch_deg, m.roll_deg)) is None:
                problems.append(
                    f"{path}: heads.{head.name}.mount: yaw {m.yaw_deg} deg, pitch {m.pitch_deg} "
                    "deg has no DISTANCE_SENSOR orientation (yaw within 2.5 deg of a multiple "
                    "of 45, pitch within +-30); fix the mount or set "
                    "mavlink.distance_sensor.enabled: false"
                )
        calibrations[head.name] = calibration
    signing = config.mavlink.signing
    if signing is not None:
        try:
            load_key(signing.key_file, signing.key_credential)
        except ConfigError as exc:
            problems.extend(exc.lines)
        if signing.timestamp_file is not None:
            problems.extend(
                _check_state_file("mavlink.signing.timestamp_file", signing.timestamp_file)
            )
    if config.avoidance.params_file is not None:
        problems.extend(_check_state_file("avoidance.params_file", config.avoidance.params_file))
    problems.extend(_check_min_distance(path, config, calibrations))
    if not input_given:
        problems.extend(_check_recordings(path, config, calibrations))
    if problems:
        raise ConfigError(problems)
    return config, calibrations


def _check_state_file(key: str, path: Path) -> list[str]:
    """A file avoidd keeps across restarts: a regular file if it exists, in a writable folder."""
    reason = not_regular(path)
    if reason is not None:
        return [f"{key}: {path} is {reason}; name a file (or nothing yet) in a writable folder"]
    if not os.access(path.parent, os.W_OK):
        return [
            f"{key}: folder {path.parent} missing or not writable; create it "
            "(systemd: StateDirectory=avoidd)"
        ]
    return []


def _check_sim_source(path: Path, head: HeadConfig, calibration: Calibration) -> list[str]:
    """A ``sim`` source's world file is valid and its rig is one the renderer draws."""
    assert isinstance(head.source, SimSourceConfig)
    problems = []
    try:
        load_world(head.source.world)
    except ConfigError as exc:
        problems.extend(exc.lines)
    if calibration.rig.doffs_px != 0.0:
        problems.append(
            f"{path}: heads.{head.name}.source: a sim source renders rigs with doffs 0; "
            f"{calibration.source} has doffs {calibration.rig.doffs_px:g} px: use a rectified rig"
        )
    return problems


def head_min_range_m(head: HeadConfig, calibration: Calibration) -> float:
    """Nearest range a head measures, from its rig, matcher range and near-field pass."""
    rig = scale_rig(calibration.rig, head.preprocess.resize_scale)
    return min_range_m(rig, head.matcher.num_disparities, head.near_field)


def head_resolved_range_m(head: HeadConfig, calibration: Calibration) -> float:
    """Farthest range a head resolves (see :func:`avoidd.vision.depth.resolved_range_m`)."""
    rig = scale_rig(calibration.rig, head.preprocess.resize_scale)
    return resolved_range_m(rig, head.disparity_error_px)


def obstacle_range_cm(
    config: ObstacleDistanceConfig, heads: Iterable[tuple[HeadConfig, Calibration]]
) -> tuple[int, int]:
    """The ``(min, max)`` OBSTACLE_DISTANCE claims: from the least capable head at each end.

    The maximum is also the range a clear bin vouches for (each head's ``max_range_m``).

    Args:
        config: ``mavlink.obstacle_distance``.
        heads: Every head with its calibration.
    """
    ranges = [(head_min_range_m(h, c), head_resolved_range_m(h, c)) for h, c in heads]
    nearest_m = max((near for near, _ in ranges), default=0.0)
    farthest_m = min((far for _, far in ranges), default=math.inf)
    return config.range_cm(nearest_m, farthest_m)


MIN_RESOLVED_RANGE_M = 3.0
"""A head that resolves less far than this is no obstacle sensor (config error)."""
_SHORT_BASELINE_M = 0.005


def _check_resolution(path: Path, head: HeadConfig, calibration: Calibration) -> list[str]:
    """The head resolves at least :data:`MIN_RESOLVED_RANGE_M`: its f * B is not too small."""
    rig = scale_rig(calibration.rig, head.preprocess.resize_scale)
    resolved = resolved_range_m(rig, head.disparity_error_px)
    if resolved >= MIN_RESOLVED_RANGE_M:
        return []
    hint = (
        f"a baseline of {rig.baseline_m:g} m is too short for stereo ranging (is it in metres?); "
        if rig.baseline_m < _SHORT_BASELINE_M
        else ""
    )
    return [
        f"{path}: heads.{head.name}: {calibration.source} resolves only to {resolved:.2g} m "
        f"(f*B = {rig.fx:.4g} px * {rig.baseline_m:.4g} m at a disparity error of "
        f"{head.disparity_error_px:g} px; at least {MIN_RESOLVED_RANGE_M:g} m is needed); "
        f"{hint}use a wider baseline, a longer focal length or less downscaling"
    ]


def _check_min_distance(
    path: Path, config: AppConfig, calibrations: dict[str, Calibration]
) -> list[str]:
    """A configured ``min_distance_cm`` must not claim ranges a head cannot measure."""
    configured = config.mavlink.obstacle_distance.min_distance_cm
    if configured is None or len(calibrations) != len(config.heads):
        return []
    ranges = {h.name: head_min_range_m(h, calibrations[h.name]) for h in config.heads}
    name = max(ranges, key=lambda n: ranges[n])
    needed_cm, _ = config.mavlink.obstacle_distance.model_copy(
        update={"min_distance_cm": None}
    ).range_cm(ranges[name])
    if configured >= needed_cm:
        return []
    return [
        f"{path}: mavlink.obstacle_distance.min_distance_cm: {configured} claims ranges the rig "
        f"cannot measure (head '{name}' measures from {needed_cm} cm); set it to at least "
        f"{needed_cm} or leave it out to follow the rig"
    ]


def _check_recordings(
    path: Path, config: AppConfig, calibrations: dict[str, Calibration]
) -> list[str]:
    """Every ``files`` source opens and yields a first frame of its calibration's size.

    ``frames.csv`` is parsed whole; the first pair is decoded (its size read from the image
    headers first, so a huge image is refused before it is decoded).
    """
    problems = []
    for head in config.heads:
        source = head.source
        if not isinstance(source, FilesSourceConfig):
            continue
        where = f"{path}: heads.{head.name}.source.path"
        try:
            opened = open_files(source.path, source.fps, paced=False, loop=False)
            try:
                frame = opened.read()
            finally:
                opened.close()
        except (SourceError, BrokenFrame, SourceExhausted) as exc:
            problems.append(f"{where}: {exc}")
            continue
        calibration = calibrations.get(head.name)
        if calibration is None:
            continue
        rig = calibration.rig
        for side, view in (("left", frame.left), ("right", frame.right)):
            height, width = view.shape[:2]
            if (width, height) != (rig.width, rig.height):
                problems.append(
                    f"{where}: the first {side} view is {width}x{height} but "
                    f"{calibration.source} is for {rig.width}x{rig.height}; record with that "
                    "camera or use its calibration"
                )
                break
    return problems
