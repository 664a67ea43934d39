"""The simulated obstacles: boxes and cylinders with a vertical extent, a texture, a motion.

Each is an upright prism (a yawed box or a vertical cylinder) between ``bottom_m`` and
``height_m`` above the ground, in the autopilot's local frame (north, east, down). A moving
one goes from where it stands by a displacement and back at a steady speed, so its place is a
function of time (:func:`placed`). Its exact 2-D geometry is here: the distance from a point to
its footprint and the distance along horizontal rays to it.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from avoidd.config.sim import BoxConfig, CylinderConfig, MotionConfig, WallConfig
from avoidd.config.sim_world import TextureLevel

Array = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Motion:
    """Back and forth along a displacement at a steady speed, starting at time 0.

    Attributes:
        by_north_m: The displacement's north part.
        by_east_m: The displacement's east part.
        speed_m_s: The speed.
    """

    by_north_m: float
    by_east_m: float
    speed_m_s: float

    def offset_ne_m(self, t_s: float) -> tuple[float, float]:
        """Where the obstacle is at ``t_s`` relative to where it stood at 0."""
        length = math.hypot(self.by_north_m, self.by_east_m)
        along = math.fmod(self.speed_m_s * max(t_s, 0.0), 2.0 * length)
        share = (along if along <= length else 2.0 * length - along) / length
        return self.by_north_m * share, self.by_east_m * share


@dataclass(frozen=True)
class SimBox:
    """A (possibly yawed) box.

    Attributes:
        north_m: Centre of its footprint.
        east_m: Centre of its footprint.
        half_length_m: Half its size along ``yaw_rad``.
        half_width_m: Half its size across.
        height_m: Its top above the ground.
        yaw_rad: Direction of its length, from north, clockwise.
        texture: How textured its faces are (see ``TextureLevel``).
        bottom_m: Its underside above the ground.
        motion: How it moves (None: it stands still).
    """

    north_m: float
    east_m: float
    half_length_m: float
    half_width_m: float
    height_m: float
    yaw_rad: float
    texture: TextureLevel = "full"
    bottom_m: float = 0.0
    motion: Motion | None = None


@dataclass(frozen=True)
class SimCylinder:
    """A vertical cylinder (see :class:`SimBox` for the shared attributes)."""

    north_m: float
    east_m: float
    radius_m: float
    height_m: float
    texture: TextureLevel = "full"
    bottom_m: float = 0.0
    motion: Motion | None = None


Obstacle = SimBox | SimCylinder


def _motion(config: MotionConfig | None) -> Motion | None:
    if config is None:
        return None
    return Motion(config.by_ne_m[0], config.by_ne_m[1], config.speed_m_s)


def from_config(item: BoxConfig | WallConfig | CylinderConfig) -> Obstacle:
    """The obstacle a world file's entry describes."""
    motion = _motion(item.motion)
    if isinstance(item, BoxConfig):
        return SimBox(
            item.north_m,
            item.east_m,
            item.length_m / 2,
            item.width_m / 2,
            item.height_m,
            math.radians(item.yaw_deg),
            item.textured,
            item.bottom_m,
            motion,
        )
    if isinstance(item, WallConfig):
        (n0, e0), (n1, e1) = item.start_ne_m, item.end_ne_m
        length = math.hypot(n1 - n0, e1 - e0)
        return SimBox(
            (n0 + n1) / 2,
            (e0 + e1) / 2,
            length / 2,
            item.thickness_m / 2,
            item.height_m,
            math.atan2(e1 - e0, n1 - n0),
            item.textured,
            item.bottom_m,
            motion,
        )
    return SimCylinder(
        item.north_m,
        item.east_m,
        item.diameter_m / 2,
        item.height_m,
        item.textured,
        item.bottom_m,
        motion,
    )


def placed(obstacle: Obstacle, t_s: float) -> Obstacle:
    """The obstacle where it is at ``t_s`` (itself when it stands still)."""
    if obstacle.motion is None:
        return obstacle
    dn, de = obstacle.motion.offset_ne_m(t_s)
    return dataclasses.replace(obstacle, north_m=obstacle.north_m + dn, east_m=obstacle.east_m + de)


def vertical_gap_m(obstacle: Obstacle, low_m: float, high_m: float) -> float:
    """How far the obstacle's vertical extent is from the heights ``low_m``..``high_m``.

    0 where they overlap.
    """
    return max(obstacle.bottom_m - high_m, low_m - obstacle.height_m, 0.0)


def footprint_distance_m(obstacle: Obstacle, north_m: float, east_m: float) -> float:
    """Horizontal distance from a point to the obstacle's footprint (negative inside)."""
    dn, de = north_m - obstacle.north_m, east_m - obstacle.east_m
    if isinstance(obstacle, SimCylinder):
        return math.hypot(dn, de) - obstacle.radius_m
    c, s = math.cos(obstacle.yaw_rad), math.sin(obstacle.yaw_rad)
    along, across = dn * c + de * s, -dn * s + de * c
    out_a = max(abs(along) - obstacle.half_length_m, 0.0)
    out_c = max(abs(across) - obstacle.half_width_m, 0.0)
    if out_a == 0.0 and out_c == 0.0:  # inside: negative depth
        return -min(obstacle.half_length_m - abs(along), obstacle.half_width_m - abs(across))
    return math.hypot(out_a, out_c)


def ray_hits(
    obstacle: Obstacle, north_m: float, east_m: float, dn_ray: Array, de_ray: Array
) -> tuple[npt.NDArray[np.bool_], Array]:
    """Where horizontal rays from a point meet the obstacle's footprint.

    Args:
        obstacle: The obstacle.
        north_m: The rays' origin.
        east_m: The rays' origin.
        dn_ray: (K,) north parts of the unit ray directions.
        de_ray: (K,) east parts.

    Returns:
        Which rays hit, and how far along (0 from inside).
    """
    on, oe = north_m - obstacle.north_m, east_m - obstacle.east_m
    if isinstance(obstacle, SimCylinder):
        b = on * dn_ray + oe * de_ray
        c = on * on + oe * oe - obstacle.radius_m**2
        disc = b * b - c
        with np.errstate(invalid="ignore"):
            t = -b - np.sqrt(disc)
        hit = (disc >= 0) & (t >= 0)
        t = np.where(c < 0, 0.0, t)  # inside: at once
        return hit | (c < 0), t
    co, si = math.cos(obstacle.yaw_rad), math.sin(obstacle.yaw_rad)
    pa, pc = on * co + oe * si, -on * si + oe * co
    da, dc = dn_ray * co + de_ray * si, -dn_ray * si + de_ray * co
    half_a, half_c = obstacle.half_length_m, obstacle.half_width_m
    with np.errstate(divide="ignore", invalid="ignore"):
        ta = np.stack([(-half_a - pa) / da, (half_a - pa) / da])
        tc = np.stack([(-half_c - pc) / dc, (half_c - pc) / dc])
    # A ray parallel to a slab is inside it (or never) whatever t.
    inside_a = abs(pa) <= half_a
    inside_c = abs(pc) <= half_c
    low_a = np.where(da == 0, -np.inf if inside_a else np.inf, ta.min(axis=0))
    high_a = np.where(da == 0, np.inf if inside_a else -np.inf, ta.max(axis=0))
    low_c = np.where(dc == 0, -np.inf if inside_c else np.inf, tc.min(axis=0))
    high_c = np.where(dc == 0, np.inf if inside_c else -np.inf, tc.max(axis=0))
    t_in = np.maximum(low_a, low_c)
    t_out = np.minimum(high_a, high_c)
    return (t_in <= t_out) & (t_out >= 0), np.maximum(t_in, 0.0)
