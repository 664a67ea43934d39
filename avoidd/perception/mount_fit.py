"""A head's height, pitch and roll from a robust plane fit to stereo points of flat ground."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from avoidd.errors import MeasureError
from avoidd.perception.frames import Pose, depth_to_frame
from avoidd.perception.ground import Plane, fit_plane
from avoidd.types import FloatArray, RectifiedRig


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
