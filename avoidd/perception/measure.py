"""Ranging one pixel two ways: by stereo, and by the paper's ground-plane geometry."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from avoidd.errors import MeasureError
from avoidd.perception.frames import Matrix, Pose, camera_to_level, depth_to_frame
from avoidd.perception.geometry import GroundRange, ground_range
from avoidd.perception.obstacles import Obstacle
from avoidd.types import FloatArray, FramePose, Mount, RectifiedRig


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


def level_pose(mount: Mount, rectified_from_raw: Matrix, pose: FramePose) -> Pose:
    """Rectified camera frame to the level frame for a head's mount and a frame's pose."""
    to_level = camera_to_level(mount, pose.roll_deg, pose.pitch_deg)
    return Pose(to_level.rotation @ rectified_from_raw.T, to_level.translation)


def camera_geometry(
    mount: Mount, rectified_from_raw: Matrix, pose: FramePose | None
) -> CameraGeometry:
    """Height, tilt and roll of a head's camera for a frame's pose.

    Raises:
        MeasureError: The frame was processed without a pose.
    """
    if pose is None:
        raise MeasureError("the frame was processed without a pose")
    to_level = level_pose(mount, rectified_from_raw, pose)
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


def nearest_obstacle_pixel(
    depth_m: FloatArray,
    rig: RectifiedRig,
    to_level: Pose,
    nearest: Obstacle,
    height_m: float,
    ground_margin_m: float,
) -> tuple[int, int] | None:
    """The ground-contact pixel of an obstacle seen in a depth map, or None.

    Args:
        depth_m: Depth of the frame (NaN unmeasured).
        rig: The rig of that depth map.
        to_level: Rectified camera frame to the level frame (:func:`level_pose`).
        nearest: The obstacle (usually the frame's nearest).
        height_m: Height of the body origin above the ground at capture.
        ground_margin_m: Points less than this above the ground are ground.
    """
    level = depth_to_frame(depth_m, rig, to_level)
    with np.errstate(invalid="ignore"):
        ranges = np.hypot(level.forward_m, level.right_m)
        bearings = np.degrees(np.arctan2(level.right_m, level.forward_m))
        near = np.abs(ranges - nearest.distance_m) <= max(0.05 * nearest.distance_m, 0.1)
        near &= np.abs(bearings - nearest.bearing_deg) <= 2.0
        near &= level.down_m <= height_m - ground_margin_m
    rows, columns = np.nonzero(near)
    if rows.size == 0:
        return None
    u = int(np.median(columns))
    in_column = rows[columns == u]
    if in_column.size == 0:
        return None
    v = int(in_column.max())
    return u, ground_contact_row(depth_m, u, v)
