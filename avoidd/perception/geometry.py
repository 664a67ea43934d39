"""The paper's monocular ground-plane distance measurement (camera height h, tilt delta).

For a camera at height ``h`` above flat ground whose optical axis points ``delta`` below the
horizon, a pixel ``dy`` pixels above the principal point and ``dx`` to its right (focal length
``f`` in pixels) looks ``alpha = atan(dy / f)`` above the axis, so its ray descends at
``delta - alpha``. If the pixel sees the ground:

- ``OY = h / tan(delta - alpha)``: horizontal distance along the camera's heading;
- ``d = OY * cos(alpha) / cos(delta - alpha)``: depth along the optical axis (what stereo
  measures as Z);
- ``YT = dx / f * d``: lateral offset to the right of the optical axis.

The tilt comes from a measured ``h`` and the distance ``OP`` at which the optical axis meets
the ground (``delta = atan(h / OP)``), or from the image row of the horizon
(``delta = atan(dy_horizon / f)``). A target of known height is ranged by replacing ``h`` with
the height difference between the camera and the target point.
"""

from __future__ import annotations

import math
from typing import NamedTuple


class GroundRange(NamedTuple):
    """Where a pixel's ray meets the ground plane.

    Attributes:
        alpha_rad: Angle of the ray above the optical axis.
        forward_m: ``OY``, horizontal distance along the camera heading.
        depth_m: ``d``, depth along the optical axis.
        lateral_m: ``YT``, offset to the right of the optical axis.
        range_m: Horizontal distance from the camera, ``hypot(OY, YT)``.
    """

    alpha_rad: float
    forward_m: float
    depth_m: float
    lateral_m: float
    range_m: float


def ground_range(
    height_m: float, tilt_rad: float, dx_px: float, dy_px: float, focal_px: float
) -> GroundRange | None:
    """Range to the ground point a pixel sees, by the paper's formulas.

    Args:
        height_m: Height of the camera above the plane (or above the target point for a target
            of known height: ``h - target_height``).
        tilt_rad: ``delta``, depression of the optical axis below the horizon (positive down).
        dx_px: Pixel column minus the principal point (positive right).
        dy_px: Principal point row minus the pixel row (positive up).
        focal_px: Focal length in pixels.

    Returns:
        The ranges, or None when the ray does not descend (at or above the horizon).
    """
    alpha = math.atan(dy_px / focal_px)
    descent = tilt_rad - alpha
    if descent <= 0.0 or height_m <= 0.0:
        return None
    forward = height_m / math.tan(descent)
    depth = forward * math.cos(alpha) / math.cos(descent)
    lateral = dx_px / focal_px * depth
    return GroundRange(alpha, forward, depth, lateral, math.hypot(forward, lateral))


def tilt_from_ground_point(height_m: float, op_m: float) -> float:
    """Tilt ``delta = atan(h / OP)`` from the height and where the optical axis meets the ground.

    Args:
        height_m: Camera height above the ground.
        op_m: Horizontal distance from the camera to the point P on the optical axis.

    Returns:
        The tilt in radians, positive down.
    """
    if height_m <= 0.0 or op_m <= 0.0:
        raise ValueError("height and OP must both be positive (metres)")
    return math.atan2(height_m, op_m)


def tilt_from_horizon(dy_horizon_px: float, focal_px: float) -> float:
    """Tilt ``delta = atan(dy / f)`` from how far above the principal point the horizon lies.

    Args:
        dy_horizon_px: Principal point row minus the horizon row: positive when the horizon
            lies above the image centre, i.e. when the camera looks down.
        focal_px: Focal length in pixels.

    Returns:
        The tilt in radians, positive down.
    """
    return math.atan2(dy_horizon_px, focal_px)
