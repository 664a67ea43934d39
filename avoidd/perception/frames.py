"""Reference frames: camera optical, body FRD through the mount, and the gravity-levelled frame.

Frames (all right-handed, metres):

- optical: x right, y down, z forward along the optical axis (OpenCV's camera frame);
- body FRD: forward, right, down of the vehicle; a head's mount rotates its camera by yaw
  (about down), pitch (about right, positive up) and roll (about forward, positive right side
  down), in that order, and places the left camera centre at ``position_m``;
- level: the body frame turned back by the vehicle's roll and pitch (not its yaw), so that its
  forward and right axes are horizontal (heading-aligned) and its down axis follows gravity.
  Heights and ground rejection work in this frame.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from avoidd.types import FloatArray, Mount, RectifiedRig

Matrix = npt.NDArray[np.float64]
"""A 3x3 rotation or a 3-vector, float64."""

OPTICAL_TO_FRD: Matrix = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
"""Rotation from the optical frame to a forward-right-down frame with the same origin."""


def rotation_zyx(yaw_deg: float, pitch_deg: float, roll_deg: float) -> Matrix:
    """Rotation of a frame turned by yaw, then pitch, then roll (aerospace ZYX order).

    Args:
        yaw_deg: About the down axis, positive to the right.
        pitch_deg: About the right axis, positive nose up.
        roll_deg: About the forward axis, positive right side down.

    Returns:
        The 3x3 matrix taking coordinates in the turned frame to the parent frame.
    """
    y, p, r = (math.radians(a) for a in (yaw_deg, pitch_deg, roll_deg))
    cy, sy, cp, sp, cr, sr = (
        math.cos(y),
        math.sin(y),
        math.cos(p),
        math.sin(p),
        math.cos(r),
        math.sin(r),
    )
    rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    return np.asarray(rz @ ry @ rx, dtype=np.float64)


class Pose(NamedTuple):
    """A rigid transform ``parent = rotation @ child + translation``."""

    rotation: Matrix
    translation: Matrix

    def apply(self, points: npt.ArrayLike) -> Matrix:
        """Transform (N, 3) points (or one 3-vector) into the parent frame."""
        array = np.asarray(points, dtype=np.float64)
        return np.asarray(array @ self.rotation.T + self.translation, dtype=np.float64)


def camera_to_body(mount: Mount) -> Pose:
    """Pose of a head's left camera (optical frame) in body FRD."""
    rotation = rotation_zyx(mount.yaw_deg, mount.pitch_deg, mount.roll_deg) @ OPTICAL_TO_FRD
    return Pose(rotation, np.asarray(mount.position_m, dtype=np.float64))


def body_to_level(roll_deg: float, pitch_deg: float) -> Pose:
    """Pose of the body frame in the level frame, given the vehicle's roll and pitch."""
    return Pose(rotation_zyx(0.0, pitch_deg, roll_deg), np.zeros(3))


def camera_to_level(mount: Mount, roll_deg: float, pitch_deg: float) -> Pose:
    """Pose of a head's left camera in the level frame (mount, then vehicle attitude)."""
    body = camera_to_body(mount)
    level = body_to_level(roll_deg, pitch_deg)
    return Pose(level.rotation @ body.rotation, level.rotation @ body.translation)


def mount_quaternion(mount: Mount) -> tuple[float, float, float, float]:
    """The mount's rotation (camera forward axis in body FRD) as a (w, x, y, z) quaternion."""
    r = rotation_zyx(mount.yaw_deg, mount.pitch_deg, mount.roll_deg)
    w = math.sqrt(max(0.0, 1.0 + r[0, 0] + r[1, 1] + r[2, 2])) / 2.0
    x = math.copysign(
        math.sqrt(max(0.0, 1.0 + r[0, 0] - r[1, 1] - r[2, 2])) / 2.0, r[2, 1] - r[1, 2]
    )
    y = math.copysign(
        math.sqrt(max(0.0, 1.0 - r[0, 0] + r[1, 1] - r[2, 2])) / 2.0, r[0, 2] - r[2, 0]
    )
    z = math.copysign(
        math.sqrt(max(0.0, 1.0 - r[0, 0] - r[1, 1] + r[2, 2])) / 2.0, r[1, 0] - r[0, 1]
    )
    return (w, x, y, z)


class Components(NamedTuple):
    """Per-pixel coordinates of a depth map in some frame; NaN where depth is not finite."""

    forward_m: FloatArray
    right_m: FloatArray
    down_m: FloatArray


def _normalised(rig: RectifiedRig, height: int, width: int) -> tuple[FloatArray, FloatArray]:
    """``xn = (u - cx) / fx`` of every column and ``yn = (v - cy) / fy`` of every row."""
    xn = (np.arange(width, dtype=np.float32) - np.float32(rig.cx)) / np.float32(rig.fx)
    yn = (np.arange(height, dtype=np.float32) - np.float32(rig.cy)) / np.float32(rig.fy)
    return xn, yn


def depth_to_frame(depth_m: FloatArray, rig: RectifiedRig, pose: Pose) -> Components:
    """Every pixel's 3D point in the frame of ``pose`` (camera optical frame to that frame).

    A pixel's optical point is ``Z * (xn, yn, 1)`` with ``xn = (u - cx) / fx`` and
    ``yn = (v - cy) / fy``, so each output coordinate is ``Z * (a * xn + b * yn + c) + t``: a
    row vector plus a column vector times the depth, which costs three broadcasts per
    coordinate instead of a matrix product per pixel.

    Args:
        depth_m: (H, W) depth along the optical axis; NaN and ``inf`` become NaN.
        rig: The rig of the depth map (its size must match).
        pose: Camera-to-frame pose.

    Returns:
        Forward, right and down coordinates, (H, W) float32 each.
    """
    z = np.where(np.isfinite(depth_m), depth_m, np.float32(np.nan))
    out = []
    for axis, offset in enumerate(pose.translation):
        coordinate = z * axis_per_depth(rig, depth_m.shape, pose, axis)
        if offset:
            coordinate += np.float32(offset)
        out.append(coordinate.astype(np.float32, copy=False))
    return Components(out[0], out[1], out[2])


def axis_per_depth(
    rig: RectifiedRig,
    shape: tuple[int, ...],
    pose: Pose,
    axis: int,
    out: FloatArray | None = None,
) -> FloatArray:
    """How much one output coordinate grows per metre of optical depth, at every pixel.

    Coordinate ``axis`` of a pixel's point is ``Z * map[v, u] + pose.translation[axis]``.

    Args:
        rig: The rig of the depth map.
        shape: (H, W) of the depth map.
        pose: Camera-to-frame pose.
        axis: 0 forward, 1 right, 2 down.
        out: (H, W) float32 array to write the map into (a new one when None).

    Returns:
        (H, W) float32.
    """
    xn, yn = _normalised(rig, shape[0], shape[1])
    a, b, c = (np.float32(value) for value in pose.rotation[axis])
    if out is None:
        out = np.empty((shape[0], shape[1]), dtype=np.float32)
    np.add((a * xn)[None, :], (b * yn + c)[:, None], out=out)
    return out
