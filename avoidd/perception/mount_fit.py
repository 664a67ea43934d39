"""A head's height, pitch and roll from a robust plane fit to stereo points of flat ground."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from avoidd.errors import MeasureError
from avoidd.perception.frames import Pose, depth_to_frame
from avoidd.perception.ground import Plane, fit_plane
from avoidd.types import FloatArray, RectifiedRig

# Robust refit in disparity: Tukey weights reach zero at this residual; this many reweightings.
_TUKEY_PX = 1.0
_IRLS_STEPS = 8


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


def _refine_in_disparity(
    depths_m: list[FloatArray], rig: RectifiedRig, max_depth_m: float, plane: Plane
) -> Plane:
    """Refit a ground plane where stereo's noise is even: in disparity, not in metres.

    A plane ``n . p = h`` seen by a rectified rig has disparity (plus ``doffs``) linear in the
    normalised image coordinates: ``fx B / Z = (fx B / h) (nx xn + ny yn + nz)``. Disparity
    errors are about the same number of pixels near and far, whereas their depth errors grow
    with the square of depth, so a least-squares fit in metres lets far points tilt the plane.
    The points near the RANSAC plane are refitted in disparity with robust (Tukey) weights.
    """
    focal_baseline = rig.fx * rig.baseline_m
    rows: list[FloatArray] = []
    for depth in depths_m:
        v, u = np.mgrid[0 : depth.shape[0] : 2, 0 : depth.shape[1] : 2]
        z = depth[::2, ::2].astype(np.float64)
        keep = np.isfinite(z) & (z > 0) & (z < max_depth_m)
        xn = (u[keep] - rig.cx) / rig.fx
        yn = (v[keep] - rig.cy) / rig.fy
        rows.append(np.stack([xn, yn, np.ones_like(xn), focal_baseline / z[keep]], axis=1))
    samples = np.concatenate(rows)
    design, disparity = samples[:, :3], samples[:, 3]
    coefficients = focal_baseline / plane.offset_m * plane.normal.astype(np.float64)
    weights = np.zeros(len(disparity))
    for _ in range(_IRLS_STEPS):
        residual_px = disparity - design @ coefficients
        scaled = residual_px / _TUKEY_PX
        weights = np.where(np.abs(scaled) < 1.0, (1.0 - scaled**2) ** 2, 0.0)
        if np.count_nonzero(weights) < 3:
            return plane
        root = np.sqrt(weights)
        solved = np.linalg.lstsq(design * root[:, None], disparity * root, rcond=None)[0]
        coefficients = np.asarray(solved, np.float64)
    length = float(np.linalg.norm(coefficients))
    normal = coefficients / length
    offset_m = focal_baseline / length
    inliers = weights > 0
    distance_m = design[inliers] @ normal * (focal_baseline / disparity[inliers]) - offset_m
    return Plane(
        normal.astype(plane.normal.dtype),
        offset_m,
        float(np.mean(inliers)) * plane.inlier_fraction,
        float(np.sqrt(np.mean(distance_m**2))),
    )


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
    plane = _refine_in_disparity(depths_m, rig, max_depth_m, plane)
    n = plane.normal  # optical frame, pointing from the camera down to the ground
    return MountFit(
        plane,
        plane.offset_m,
        pitch_deg=-math.degrees(math.asin(max(-1.0, min(1.0, float(n[2]))))),
        roll_deg=math.degrees(math.atan2(float(n[0]), float(n[1]))),
        points=int(points.shape[0]),
    )
