"""Ground truth of synthetic frames in the terms avoidd reports (nearest distance and bearing)."""

from __future__ import annotations

import math

import numpy as np

from avoidd.config import PerceptionConfig
from avoidd.perception.frames import body_to_level, rotation_zyx
from avoidd.sources.scene import FIRST_OBSTACLE_ID
from avoidd.types import FloatArray, FramePose, GroundTruth, Mount, Nearest, wrap_deg


def level_points(truth: GroundTruth, mount: Mount, pose: FramePose) -> FloatArray:
    """Truth points (H, W, 3) in avoidd's level frame: from the body origin, heading-aligned.

    The renderer's world frame is the camera's level frame turned by the mount yaw, so a point
    is turned by that yaw and moved by the mount position (itself turned by the attitude).

    Args:
        truth: Ground truth of the left view.
        mount: The head's mount.
        pose: Vehicle attitude of the frame.

    Returns:
        Points as float32, ``inf`` where the view sees sky.
    """
    yaw = rotation_zyx(mount.yaw_deg, 0.0, 0.0)
    offset = body_to_level(pose.roll_deg, pose.pitch_deg).apply(mount.position_m)
    with np.errstate(invalid="ignore"):  # sky points are inf
        points = truth.points_m.reshape(-1, 3).astype(np.float64) @ yaw.T + offset
    return points.reshape(truth.points_m.shape).astype(np.float32)


def nearest_obstacle(
    truth: GroundTruth,
    mount: Mount,
    pose: FramePose,
    perception: PerceptionConfig | None = None,
) -> Nearest | None:
    """The exact nearest obstacle point avoidd should report: above the ground margin, in band.

    Ranges are horizontal, from the body origin, in the level frame.

    Args:
        truth: Ground truth of the left view.
        mount: The head's mount.
        pose: Vehicle attitude and height of the frame (height of the body origin).
        perception: Ground margin and height band (defaults when None).

    Returns:
        Distance and bearing of the nearest obstacle point, or None if none is visible.
    """
    config = perception or PerceptionConfig()
    points = level_points(truth, mount, pose)[truth.object_id >= FIRST_OBSTACLE_ID]
    if points.size == 0:
        return None
    down = points[:, 2]
    lowest = min(pose.height_m - config.ground.margin_m, config.band.below_m)
    points = points[(down >= -config.band.above_m) & (down <= lowest)]
    if points.size == 0:
        return None
    ranges = np.hypot(points[:, 0], points[:, 1])
    index = int(np.argmin(ranges))
    bearing = math.degrees(math.atan2(float(points[index, 1]), float(points[index, 0])))
    return Nearest(float(ranges[index]), wrap_deg(bearing))
