"""Ground truth of synthetic frames in the terms avoidd reports (nearest distance and bearing)."""

from __future__ import annotations

import math

import numpy as np

from avoidd.perception.sectors import band_rows
from avoidd.sources.scene import FIRST_OBSTACLE_ID
from avoidd.types import GroundTruth, Mount, Nearest, wrap_deg


def nearest_obstacle(
    truth: GroundTruth, mount: Mount, row_band: tuple[float, float]
) -> Nearest | None:
    """The exact nearest obstacle point inside the row band the sector grid looks at.

    Ranges are horizontal, from the body origin, through the head's mount (yaw and position).

    Args:
        truth: Ground truth of the left view.
        mount: The head's mount.
        row_band: Top and bottom of the band as fractions of the image height.

    Returns:
        Distance and bearing of the nearest obstacle point, or None if none is in the band.
    """
    top, bottom = band_rows(truth.depth_m.shape[0], row_band)
    ids = truth.object_id[top:bottom]
    points = truth.points_m[top:bottom][ids >= FIRST_OBSTACLE_ID]
    if points.size == 0:
        return None
    yaw = math.radians(mount.yaw_deg)
    forward = math.cos(yaw) * points[:, 0] - math.sin(yaw) * points[:, 1] + mount.position_m[0]
    right = math.sin(yaw) * points[:, 0] + math.cos(yaw) * points[:, 1] + mount.position_m[1]
    ranges = np.hypot(forward, right)
    index = int(np.argmin(ranges))
    bearing = math.degrees(math.atan2(float(right[index]), float(forward[index])))
    return Nearest(float(ranges[index]), wrap_deg(bearing))
