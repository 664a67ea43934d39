"""Loading a configuration with everything it refers to: calibrations, signing key, cross-checks."""

from __future__ import annotations

import os
from pathlib import Path

from avoidd.config import AppConfig, load_config
from avoidd.errors import ConfigError
from avoidd.mavlink.messages import sensor_orientation
from avoidd.mavlink.signing import load_key
from avoidd.types import Mount
from avoidd.vision.calibration import Calibration, load_calibration


def load_all(path: Path) -> tuple[AppConfig, dict[str, Calibration]]:
    """Load a configuration and the calibration of each head, collecting every problem.

    Args:
        path: The configuration file.

    Returns:
        The configuration and the calibrations by head name.

    Raises:
        ConfigError: Any problem in the configuration or a calibration file.
    """
    config = load_config(path)
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
        folder = signing.timestamp_file.parent if signing.timestamp_file else None
        if folder is not None and not os.access(folder, os.W_OK):
            problems.append(
                f"mavlink.signing.timestamp_file: folder {folder} missing or not writable; "
                "create it (systemd: StateDirectory=avoidd)"
            )
    if problems:
        raise ConfigError(problems)
    return config, calibrations
