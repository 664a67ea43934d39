"""``avoidd measure`` and ``avoidd calibrate-mount``: the paper's geometry next to stereo."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from avoidd.commands import EXIT_FAILURE, EXIT_OK
from avoidd.config import AppConfig, HeadConfig
from avoidd.errors import BrokenFrame, ConfigError, MeasureError, SourceExhausted
from avoidd.loading import load_all
from avoidd.perception.geometry import tilt_from_ground_point
from avoidd.perception.measure import (
    CameraGeometry,
    Measurement,
    camera_geometry,
    level_pose,
    measure_pixel,
    nearest_obstacle_pixel,
)
from avoidd.perception.mount_fit import MountFit, fit_mount
from avoidd.pipeline import HeadPipeline, HeadResult
from avoidd.replay import select_head
from avoidd.sources import open_source
from avoidd.vision.calibration import Calibration

_ROLL_WARN_DEG = 2.0
# An optical axis meeting the ground farther than this gives no OP anyone can measure.
_OP_FAR_M = 100.0


def configure(name: str, parser: argparse.ArgumentParser) -> None:
    """Add the options of ``measure`` or ``calibrate-mount``."""
    if name == "measure":
        parser.add_argument("--config", type=Path, required=True, help="YAML configuration file")
        parser.add_argument("--head", help="head name (default: the first)")
        parser.add_argument("--input", type=Path, help="read this folder or video instead")
        parser.add_argument("--frame", type=int, default=0, help="frame number (default 0)")
        parser.add_argument(
            "--pixel",
            type=int,
            nargs=2,
            metavar=("U", "V"),
            help="pixel (default: nearest obstacle)",
        )
        parser.set_defaults(handler=run_measure)
    else:
        parser.add_argument("--config", type=Path, help="fit the ground seen by this config's head")
        parser.add_argument("--head", help="head name (default: the first)")
        parser.add_argument("--input", type=Path, help="read this folder or video instead")
        parser.add_argument("--frames", type=int, default=3, help="frames to fit (default 3)")
        parser.add_argument("--height-m", type=float, help="measured camera height h")
        parser.add_argument(
            "--op-m", type=float, help="measured distance OP to where the axis meets the ground"
        )
        parser.set_defaults(handler=run_calibrate_mount)


def run_measure(args: argparse.Namespace) -> int:
    """Range a pixel (default: the nearest obstacle's ground contact) both ways and print."""
    config, calibrations = load_all(args.config, input_given=args.input is not None)
    head = select_head(config, args.head)
    pipeline, results = process_frames(
        config, head, calibrations[head.name], args.input, args.frame, 1
    )
    result = results[0]
    geometry = camera_geometry(pipeline.mount, pipeline.rectified_from_raw, result.pose)
    if args.pixel is not None:
        u, v = args.pixel
        print(f"head '{head.name}', frame {result.seq}, pixel given")
    else:
        found = None
        if result.obstacles and result.pose is not None:
            found = nearest_obstacle_pixel(
                result.depth_m,
                pipeline.work_rig,
                level_pose(pipeline.mount, pipeline.rectified_from_raw, result.pose),
                result.obstacles[0],
                result.pose.height_m,
                config.perception.ground.margin_m,
            )
        if found is None:
            print(f"head '{head.name}', frame {result.seq}: no obstacle in view")
            return EXIT_FAILURE
        u, v = found
        nearest = result.obstacles[0]
        print(
            f"head '{head.name}', frame {result.seq}: nearest obstacle "
            f"{nearest.distance_m:.2f} m at {nearest.bearing_deg:+.1f} deg, "
            f"its ground contact at pixel ({u}, {v})"
        )
    measurement = measure_pixel(result.depth_m, pipeline.work_rig, geometry, u, v)
    print(format_measurement(measurement, geometry))
    return EXIT_OK


def run_calibrate_mount(args: argparse.Namespace) -> int:
    """Fit the mount to flat ground, or compute the paper's tilt from h and OP, and print."""
    if args.height_m is not None or args.op_m is not None:
        if args.height_m is None or args.op_m is None:
            raise ConfigError(["--height-m and --op-m go together (camera height and OP)"])
        print(format_manual_mount(args.height_m, args.op_m))
        return EXIT_OK
    if args.config is None:
        raise ConfigError(["give --config (fit flat ground) or --height-m and --op-m"])
    config, calibrations = load_all(args.config, input_given=args.input is not None)
    head = select_head(config, args.head)
    # Refine disparity to subpixel whatever the config says: without it SGBM reads sloping ground
    # 0.1-0.25 px low, enough to tilt the fitted plane by half a degree (0.58 deg on the demo).
    measuring = head.model_copy(
        update={"postprocess": head.postprocess.model_copy(update={"subpixel_refine": True})}
    )
    pipeline, results = process_frames(
        config, measuring, calibrations[head.name], args.input, 0, args.frames
    )
    rig = pipeline.work_rig
    # Within 0.1 f B one pixel of disparity is at most 10% of depth.
    fit = fit_mount([r.depth_m for r in results], rig, 0.1 * rig.fx * rig.baseline_m)
    print(format_mount_fit(fit, head, config.perception.ground.margin_m))
    return EXIT_OK


def process_frames(
    config: AppConfig,
    head: HeadConfig,
    calibration: Calibration,
    input_path: Path | None,
    first: int,
    count: int,
) -> tuple[HeadPipeline, list[HeadResult]]:
    """Process ``count`` frames of a head's source from frame number ``first`` (with obstacles).

    Raises:
        MeasureError: The source ends before that.
    """
    od = config.mavlink.obstacle_distance
    pipeline = HeadPipeline(head, calibration, od.max_distance_cm / 100.0, config.perception)
    source = open_source(
        head.source, calibration.rig, head.name, paced=False, input_path=input_path
    )
    results: list[HeadResult] = []
    try:
        seen = 0
        while len(results) < count:
            try:
                frame = source.read()
            except SourceExhausted:
                raise MeasureError(
                    f"the source ended after {seen} frames; need frames {first} to "
                    f"{first + count - 1}"
                ) from None
            except BrokenFrame:
                continue
            if seen >= first:
                results.append(pipeline.process(frame, with_obstacles=True))
            seen += 1
    finally:
        source.close()
    return pipeline, results


def format_measurement(m: Measurement, geometry: CameraGeometry) -> str:
    """The measurement as the lines ``avoidd measure`` prints."""
    lines = [
        f"camera: height {geometry.height_m:.3f} m, tilt {math.degrees(geometry.tilt_rad):.2f} "
        f"deg down, roll {geometry.roll_deg:+.2f} deg",
        f"pixel ({m.u}, {m.v}): alpha {math.degrees(m.ground.alpha_rad):+.2f} deg",
        f"  stereo:       depth {m.stereo_depth_m:7.3f} m, range {m.stereo_range_m:7.3f} m, "
        f"lateral {m.stereo_lateral_m:+.3f} m",
        f"  ground plane: depth {m.ground.depth_m:7.3f} m, range {m.ground.range_m:7.3f} m, "
        f"lateral {m.ground.lateral_m:+.3f} m (OY {m.ground.forward_m:.3f} m)",
        f"  difference:   {m.difference_pct:+.2f}% (ground plane vs stereo depth)",
    ]
    if abs(geometry.roll_deg) > _ROLL_WARN_DEG:
        lines.append(
            f"  note: the camera is rolled {geometry.roll_deg:+.1f} deg; the ground-plane "
            "formulas assume no roll"
        )
    return "\n".join(lines)


def format_optical_axis(height_m: float, pitch_deg: float) -> str:
    """Where the optical axis meets the ground (the paper's OP), in words when it does not."""
    tilt = math.radians(-pitch_deg)
    if tilt <= 0.0:
        return (
            f"paper's check: the optical axis points {pitch_deg:+.2f} deg, level or above the "
            "horizon, so it never meets the ground: there is no OP to measure (tilt the camera "
            "down to use the h/OP check)"
        )
    op_m = height_m / math.tan(tilt)
    if op_m > _OP_FAR_M:
        return (
            f"paper's check: the optical axis is only {-pitch_deg:.2f} deg below the horizon and "
            f"meets the ground about {op_m:.0f} m away, too far to measure OP with a tape"
        )
    return f"paper's check: the optical axis meets the ground at OP = {op_m:.2f} m"


def format_mount_fit(fit: MountFit, head: HeadConfig, margin_m: float) -> str:
    """The lines ``avoidd calibrate-mount`` prints for a ground-plane fit.

    The suggested config lines are whole mappings (yaw and position kept from ``head``) that can
    replace the head's ``mount`` and ``perception.ground``. A synthetic source renders its camera
    at the scene's pitch and no roll, and the loader holds the mount to that, so for one the fit
    is compared with the scene and the mount line keeps the scene's pitch.
    """
    mount = head.mount
    position = ", ".join(f"{value:g}" for value in mount.position_m)
    body_height_m = fit.height_m + mount.position_m[2]
    lines = [
        f"ground plane: {fit.points} points, {fit.plane.inlier_fraction:.0%} inliers, "
        f"RMS {fit.plane.rms_m * 100:.1f} cm",
        f"camera height {fit.height_m:.3f} m, pitch {fit.pitch_deg:+.2f} deg, "
        f"roll {fit.roll_deg:+.2f} deg (vehicle assumed level)",
        format_optical_axis(fit.height_m, fit.pitch_deg),
    ]
    pitch_deg, roll_deg = fit.pitch_deg, fit.roll_deg
    if head.source.kind == "synthetic":
        scene = head.source
        lines.append(
            f"synthetic scene: camera height {scene.camera_height_m:.3f} m, pitch "
            f"{scene.camera_pitch_deg:+.2f} deg; the fit is off by "
            f"{fit.height_m - scene.camera_height_m:+.3f} m and "
            f"{fit.pitch_deg - scene.camera_pitch_deg:+.2f} deg (the mount must keep the scene's "
            "pitch and no roll)"
        )
        pitch_deg, roll_deg = scene.camera_pitch_deg, 0.0
    lines += [
        f"config (heads.{head.name}.mount and perception.ground):",
        f"  mount: {{yaw_deg: {mount.yaw_deg:g}, pitch_deg: {pitch_deg:.2f}, "
        f"roll_deg: {roll_deg:.2f}, position_m: [{position}]}}",
        f"  ground: {{height_m: {body_height_m:.3f}, margin_m: {margin_m:g}}}",
    ]
    return "\n".join(lines)


def format_manual_mount(height_m: float, op_m: float) -> str:
    """The lines ``avoidd calibrate-mount --height-m H --op-m OP`` prints."""
    tilt = tilt_from_ground_point(height_m, op_m)
    return "\n".join(
        [
            f"tilt delta = atan(h / OP) = atan({height_m:.3f} / {op_m:.3f}) = "
            f"{math.degrees(tilt):.2f} deg down",
            "config:",
            f"  mount: {{pitch_deg: {-math.degrees(tilt):.2f}}}",
        ]
    )
