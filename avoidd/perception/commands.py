"""``avoidd measure`` and ``avoidd calibrate-mount``: the paper's geometry next to stereo."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from avoidd.config import AppConfig, HeadConfig
from avoidd.errors import AvoiddError, BrokenFrame, SourceExhausted
from avoidd.perception.frames import Matrix, Pose, camera_to_level, depth_to_frame
from avoidd.perception.geometry import GroundRange, ground_range, tilt_from_ground_point
from avoidd.perception.ground import Plane, fit_plane
from avoidd.pipeline import HeadPipeline, HeadResult
from avoidd.sources import open_source
from avoidd.types import FloatArray, FramePose, RectifiedRig
from avoidd.vision.calibration import Calibration

_ROLL_WARN_DEG = 2.0


class MeasureError(AvoiddError):
    """The measurement cannot be made (no frame, pixel unmeasured, ray above the horizon)."""


@dataclass(frozen=True)
class CameraGeometry:
    """The paper's parameters of a head for one frame.

    Attributes:
        height_m: Camera centre above the ground.
        tilt_rad: Depression of the optical axis below the horizon (positive down).
        roll_deg: Roll of the camera about its axis relative to gravity (the paper assumes 0).
        to_level: Rotation from the optical frame to the level frame.
    """

    height_m: float
    tilt_rad: float
    roll_deg: float
    to_level: Matrix


def level_pose(pipeline: HeadPipeline, pose: FramePose) -> Pose:
    """Rectified camera frame to the level frame for a head and a frame's pose."""
    to_level = camera_to_level(pipeline.mount, pose.roll_deg, pose.pitch_deg)
    return Pose(to_level.rotation @ pipeline.rectified_from_raw.T, to_level.translation)


def camera_geometry(pipeline: HeadPipeline, result: HeadResult) -> CameraGeometry:
    """Height, tilt and roll of a head's camera for a processed frame (its pose and mount)."""
    pose = result.pose
    if pose is None:
        raise MeasureError("the frame was processed without a pose")
    to_level = level_pose(pipeline, pose)
    axis_down = float(to_level.rotation[2, 2])
    x_down = float(to_level.rotation[2, 0])
    return CameraGeometry(
        height_m=pose.height_m - float(to_level.translation[2]),
        tilt_rad=math.asin(max(-1.0, min(1.0, axis_down))),
        roll_deg=math.degrees(math.asin(max(-1.0, min(1.0, x_down)))),
        to_level=to_level.rotation,
    )


@dataclass(frozen=True)
class Measurement:
    """Stereo and ground-plane ranges of one pixel (distances from the camera centre).

    Attributes:
        u: Pixel column (in the matcher's image).
        v: Pixel row.
        stereo_depth_m: Optical depth from stereo.
        stereo_range_m: Horizontal range from stereo.
        stereo_lateral_m: Offset to the right of the optical axis from stereo.
        ground: The paper's ground-plane result.
    """

    u: int
    v: int
    stereo_depth_m: float
    stereo_range_m: float
    stereo_lateral_m: float
    ground: GroundRange

    @property
    def difference_pct(self) -> float:
        """Ground-plane depth relative to stereo depth, percent."""
        return 100.0 * (self.ground.depth_m / self.stereo_depth_m - 1.0)


def local_depth_m(depth_m: FloatArray, u: int, v: int, radius_px: int = 2) -> float:
    """Median of the measured depths within ``radius_px`` of a pixel (NaN if none)."""
    window = depth_m[
        max(v - radius_px, 0) : v + radius_px + 1, max(u - radius_px, 0) : u + radius_px + 1
    ]
    finite = window[np.isfinite(window)]
    return float(np.median(finite)) if finite.size else math.nan


def measure_pixel(
    depth_m: FloatArray, rig: RectifiedRig, geometry: CameraGeometry, u: int, v: int
) -> Measurement:
    """Measure one pixel by stereo and by the ground-plane geometry.

    Raises:
        MeasureError: The pixel is outside the image, unmeasured, or above the horizon.
    """
    if not (0 <= u < rig.width and 0 <= v < rig.height):
        raise MeasureError(f"pixel ({u}, {v}) is outside the {rig.width}x{rig.height} image")
    depth = local_depth_m(depth_m, u, v)
    if not math.isfinite(depth):
        raise MeasureError(f"pixel ({u}, {v}) has no stereo measurement; pick a textured one")
    ground = ground_range(geometry.height_m, geometry.tilt_rad, u - rig.cx, rig.cy - v, rig.fx)
    if ground is None:
        raise MeasureError(
            f"pixel ({u}, {v}) looks at or above the horizon: the ground-plane model has no range"
        )
    lateral = (u - rig.cx) / rig.fx * depth
    optical = np.array([lateral, (v - rig.cy) / rig.fy * depth, depth])
    forward, right, _ = geometry.to_level @ optical
    return Measurement(u, v, depth, math.hypot(float(forward), float(right)), lateral, ground)


def ground_contact_row(
    depth_m: FloatArray, u: int, v: int, relative_tolerance: float = 0.05
) -> int:
    """The lowest row below ``(u, v)`` on the same surface: where an obstacle meets the ground.

    Walks down the column while the measured depth stays within ``relative_tolerance`` of the
    depth at the start (unmeasured pixels are stepped over, at most 3 in a row).
    """
    reference = local_depth_m(depth_m, u, v)
    if not math.isfinite(reference):
        return v
    last, gap = v, 0
    for row in range(v + 1, depth_m.shape[0]):
        value = float(depth_m[row, u])
        if not math.isfinite(value):
            gap += 1
            if gap > 3:
                break
            continue
        if abs(value / reference - 1.0) > relative_tolerance:
            break
        last, gap = row, 0
    return last


def nearest_obstacle_pixel(pipeline: HeadPipeline, result: HeadResult) -> tuple[int, int] | None:
    """The ground-contact pixel of the nearest obstacle of a processed frame, or None."""
    if not result.obstacles or result.pose is None:
        return None
    nearest = result.obstacles[0]
    pose = result.pose
    rig = pipeline.work_rig
    level = depth_to_frame(result.depth_m, rig, level_pose(pipeline, pose))
    with np.errstate(invalid="ignore"):
        ranges = np.hypot(level.forward_m, level.right_m)
        bearings = np.degrees(np.arctan2(level.right_m, level.forward_m))
        near = np.abs(ranges - nearest.distance_m) <= max(0.05 * nearest.distance_m, 0.1)
        near &= np.abs(bearings - nearest.bearing_deg) <= 2.0
        near &= level.down_m <= pose.height_m - pipeline.perception.ground.margin_m
    rows, columns = np.nonzero(near)
    if rows.size == 0:
        return None
    u = int(np.median(columns))
    in_column = rows[columns == u]
    if in_column.size == 0:
        return None
    v = int(in_column.max())
    return u, ground_contact_row(result.depth_m, u, v)


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


@dataclass(frozen=True)
class MountFit:
    """A head's height and tilt fitted to a view of flat ground.

    Attributes:
        plane: The fitted plane in the optical frame.
        height_m: Camera centre above the plane.
        pitch_deg: Camera pitch relative to the plane (positive up; looking down is negative).
        roll_deg: Camera roll relative to the plane (positive right side down).
        points: Points the fit used.
    """

    plane: Plane
    height_m: float
    pitch_deg: float
    roll_deg: float
    points: int


def fit_mount(depths_m: list[FloatArray], rig: RectifiedRig, max_depth_m: float) -> MountFit:
    """Fit the ground plane to stereo points of flat ground and read the camera's pose off it.

    Args:
        depths_m: Depth maps of views of flat ground.
        rig: Their rig.
        max_depth_m: Farther points are left out (their noise is large).

    Returns:
        The fit.

    Raises:
        MeasureError: Too few points, or no dominant plane.
    """
    identity = Pose(np.eye(3), np.zeros(3))
    chunks = []
    for depth in depths_m:
        x, y, z = depth_to_frame(depth, rig, identity)
        # Every 3rd pixel both ways: plenty of points, a ninth of the work.
        points = np.stack([x[::3, ::3], y[::3, ::3], z[::3, ::3]], axis=-1).reshape(-1, 3)
        keep = np.all(np.isfinite(points), axis=1) & (points[:, 2] < max_depth_m)
        chunks.append(points[keep])
    points = np.concatenate(chunks) if chunks else np.empty((0, 3), dtype=np.float32)
    if points.shape[0] < 500:
        raise MeasureError(
            f"only {points.shape[0]} stereo points within {max_depth_m} m; point the head at "
            "textured flat ground"
        )
    plane = fit_plane(points, threshold_m=0.03)
    if plane.inlier_fraction < 0.5:
        raise MeasureError(
            f"only {plane.inlier_fraction:.0%} of the points lie on one plane; the view needs "
            "mostly flat ground"
        )
    n = plane.normal  # optical frame, pointing from the camera down to the ground
    return MountFit(
        plane,
        plane.offset_m,
        pitch_deg=-math.degrees(math.asin(max(-1.0, min(1.0, float(n[2]))))),
        roll_deg=math.degrees(math.atan2(float(n[0]), float(n[1]))),
        points=int(points.shape[0]),
    )


def format_mount_fit(fit: MountFit, position_down_m: float) -> str:
    """The lines ``avoidd calibrate-mount`` prints for a ground-plane fit."""
    tilt = math.radians(-fit.pitch_deg)
    op = fit.height_m / math.tan(tilt) if tilt > 1e-6 else math.inf
    return "\n".join(
        [
            f"ground plane: {fit.points} points, {fit.plane.inlier_fraction:.0%} inliers, "
            f"RMS {fit.plane.rms_m * 100:.1f} cm",
            f"camera height {fit.height_m:.3f} m, pitch {fit.pitch_deg:+.2f} deg, "
            f"roll {fit.roll_deg:+.2f} deg (vehicle assumed level)",
            f"paper's check: the optical axis meets the ground at OP = {op:.2f} m",
            "config:",
            f"  mount: {{pitch_deg: {fit.pitch_deg:.2f}, roll_deg: {fit.roll_deg:.2f}}}",
            f"  perception: {{ground: {{height_m: {fit.height_m + position_down_m:.3f}}}}}",
        ]
    )


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
