"""A simulated world: boxes, walls and cylinders on flat ground, with exact 2-D geometry.

The frame is the autopilot's local frame: north, east, down, the ground at down = 0. Obstacles
stand on the ground. Collisions, clearance and the oracle perception (exact distance per scan
bin) are computed on their footprints at the vehicle's altitude.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from avoidd.config.sim import BoxConfig, CylinderConfig, WallConfig, WorldConfig
from avoidd.types import SECTOR_COUNT, SECTOR_WIDTH_DEG

Array = npt.NDArray[np.float64]


@dataclass(frozen=True)
class SimBox:
    """A (possibly yawed) box standing on the ground.

    Attributes:
        north_m: Centre of its footprint.
        east_m: Centre of its footprint.
        half_length_m: Half its size along ``yaw_rad``.
        half_width_m: Half its size across.
        height_m: Its top above the ground.
        yaw_rad: Direction of its length, from north, clockwise.
        textured: Whether its faces carry texture (else a flat colour).
    """

    north_m: float
    east_m: float
    half_length_m: float
    half_width_m: float
    height_m: float
    yaw_rad: float
    textured: bool = True


@dataclass(frozen=True)
class SimCylinder:
    """A vertical cylinder standing on the ground."""

    north_m: float
    east_m: float
    radius_m: float
    height_m: float
    textured: bool = True


Obstacle = SimBox | SimCylinder


def _from_config(item: BoxConfig | WallConfig | CylinderConfig) -> Obstacle:
    if isinstance(item, BoxConfig):
        return SimBox(
            item.north_m,
            item.east_m,
            item.length_m / 2,
            item.width_m / 2,
            item.height_m,
            math.radians(item.yaw_deg),
            item.textured,
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
        )
    return SimCylinder(item.north_m, item.east_m, item.diameter_m / 2, item.height_m, item.textured)


@dataclass(frozen=True)
class World:
    """Obstacles on flat ground, a tree line around, and the seed of their textures."""

    obstacles: tuple[Obstacle, ...]
    seed: int = 1
    treeline_m: float | None = 60.0

    @classmethod
    def from_config(cls, config: WorldConfig) -> World:
        """The world a world file describes."""
        return cls(tuple(_from_config(o) for o in config.obstacles), config.seed, config.treeline_m)

    def _relevant(self, altitude_m: float) -> list[Obstacle]:
        return [o for o in self.obstacles if o.height_m > altitude_m]

    def clearance_m(self, north_m: float, east_m: float, altitude_m: float) -> float:
        """Horizontal distance from a point to the nearest obstacle reaching its altitude."""
        nearest = math.inf
        for obstacle in self._relevant(altitude_m):
            dn, de = north_m - obstacle.north_m, east_m - obstacle.east_m
            if isinstance(obstacle, SimCylinder):
                distance = math.hypot(dn, de) - obstacle.radius_m
            else:
                c, s = math.cos(obstacle.yaw_rad), math.sin(obstacle.yaw_rad)
                along, across = dn * c + de * s, -dn * s + de * c
                out_a = max(abs(along) - obstacle.half_length_m, 0.0)
                out_c = max(abs(across) - obstacle.half_width_m, 0.0)
                distance = math.hypot(out_a, out_c)
                if out_a == 0.0 and out_c == 0.0:  # inside: negative depth
                    distance = -min(
                        obstacle.half_length_m - abs(along), obstacle.half_width_m - abs(across)
                    )
            nearest = min(nearest, distance)
        return nearest

    def ray_distances(
        self, north_m: float, east_m: float, altitude_m: float, headings_rad: Array
    ) -> Array:
        """Distance along each horizontal ray to the first obstacle (``inf`` if none).

        Args:
            north_m: Ray origin.
            east_m: Ray origin.
            altitude_m: Height of the rays; only obstacles reaching it count.
            headings_rad: (K,) ray directions, from north, clockwise.

        Returns:
            (K,) distances.
        """
        best = np.full(headings_rad.shape, np.inf)
        dn_ray, de_ray = np.cos(headings_rad), np.sin(headings_rad)
        for obstacle in self._relevant(altitude_m):
            on, oe = north_m - obstacle.north_m, east_m - obstacle.east_m
            if isinstance(obstacle, SimCylinder):
                b = on * dn_ray + oe * de_ray
                c = on * on + oe * oe - obstacle.radius_m**2
                disc = b * b - c
                with np.errstate(invalid="ignore"):
                    t = -b - np.sqrt(disc)
                hit = (disc >= 0) & (t >= 0)
                t = np.where(c < 0, 0.0, t)  # inside: at once
                hit |= c < 0
            else:
                co, si = math.cos(obstacle.yaw_rad), math.sin(obstacle.yaw_rad)
                pa, pc = on * co + oe * si, -on * si + oe * co
                da, dc = dn_ray * co + de_ray * si, -dn_ray * si + de_ray * co
                with np.errstate(divide="ignore", invalid="ignore"):
                    ta = np.stack(
                        [(-obstacle.half_length_m - pa) / da, (obstacle.half_length_m - pa) / da]
                    )
                    tc = np.stack(
                        [(-obstacle.half_width_m - pc) / dc, (obstacle.half_width_m - pc) / dc]
                    )
                # A ray parallel to a slab is inside it (or never) whatever t.
                inside_a = abs(pa) <= obstacle.half_length_m
                inside_c = abs(pc) <= obstacle.half_width_m
                low_a = np.where(da == 0, -np.inf if inside_a else np.inf, ta.min(axis=0))
                high_a = np.where(da == 0, np.inf if inside_a else -np.inf, ta.max(axis=0))
                low_c = np.where(dc == 0, -np.inf if inside_c else np.inf, tc.min(axis=0))
                high_c = np.where(dc == 0, np.inf if inside_c else -np.inf, tc.max(axis=0))
                t_in = np.maximum(low_a, low_c)
                t_out = np.minimum(high_a, high_c)
                hit = (t_in <= t_out) & (t_out >= 0)
                t = np.maximum(t_in, 0.0)
            best = np.where(hit, np.minimum(best, t), best)
        return best

    def oracle_scan(
        self,
        north_m: float,
        east_m: float,
        altitude_m: float,
        yaw_rad: float,
        covered: npt.NDArray[np.bool_],
        max_range_m: float,
        rays_per_bin: int = 5,
    ) -> npt.NDArray[np.float32]:
        """Exact 72-bin scan (body bins): nearest obstacle per bin, ``inf`` clear, NaN unseen.

        Args:
            north_m: Vehicle position.
            east_m: Vehicle position.
            altitude_m: Vehicle altitude (the obstacles reaching it count).
            yaw_rad: Vehicle heading.
            covered: (72,) bins the cameras see.
            max_range_m: Beyond this a bin is clear.
            rays_per_bin: Rays cast across each bin.
        """
        offsets = (np.arange(rays_per_bin) + 0.5) / rays_per_bin - 0.5
        body = (np.arange(SECTOR_COUNT)[:, None] + offsets[None, :]) * SECTOR_WIDTH_DEG
        headings = yaw_rad + np.radians(body.ravel())
        distance = self.ray_distances(north_m, east_m, altitude_m, headings)
        nearest = distance.reshape(SECTOR_COUNT, rays_per_bin).min(axis=1)
        scan = np.where(nearest < max_range_m, nearest, np.inf).astype(np.float32)
        scan[~covered] = np.nan
        return scan
