"""A simulated world: obstacles on flat ground, and its exact geometry at any time.

The frame is the autopilot's local frame: north, east, down, the ground at down = 0. The
obstacles (:mod:`avoidd.sim.obstacles`) are upright prisms with a bottom and a top; moving ones
are wherever they are at the time asked. Collisions and clearance are measured in 3-D between
the vehicle (an upright cylinder of its radius, ``VEHICLE_HEIGHT_M`` tall) and each obstacle;
the oracle perception (exact distance per scan bin) takes the obstacles within a height band
round the vehicle, as the daemon's perception does.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from avoidd.config.sim import WorldConfig
from avoidd.sim.obstacles import (
    Obstacle,
    SimBox,
    SimCylinder,
    footprint_distance_m,
    from_config,
    placed,
    ray_hits,
    vertical_gap_m,
)
from avoidd.types import SECTOR_COUNT, SECTOR_WIDTH_DEG

__all__ = ["VEHICLE_HEIGHT_M", "Obstacle", "SimBox", "SimCylinder", "World"]

Array = npt.NDArray[np.float64]

VEHICLE_HEIGHT_M = 0.3
"""The vehicle's height, centred on its altitude, for 3-D collisions."""


@dataclass(frozen=True)
class World:
    """Obstacles on flat ground, a tree line around, and the seed of their textures."""

    obstacles: tuple[Obstacle, ...]
    seed: int = 1
    treeline_m: float | None = 60.0

    @classmethod
    def from_config(cls, config: WorldConfig) -> World:
        """The world a world file describes."""
        return cls(tuple(from_config(o) for o in config.obstacles), config.seed, config.treeline_m)

    @property
    def moves(self) -> bool:
        """Whether any obstacle moves."""
        return any(o.motion is not None for o in self.obstacles)

    def at(self, t_s: float) -> tuple[Obstacle, ...]:
        """The obstacles where they are at ``t_s`` (in the same order)."""
        if not self.moves:
            return self.obstacles
        return tuple(placed(o, t_s) for o in self.obstacles)

    def _within(self, low_m: float, high_m: float, t_s: float) -> list[Obstacle]:
        """The obstacles at ``t_s`` reaching into the heights ``low_m``..``high_m``."""
        return [o for o in self.at(t_s) if o.height_m > low_m and o.bottom_m <= high_m]

    def clearance_m(
        self, north_m: float, east_m: float, altitude_m: float, t_s: float = 0.0
    ) -> float:
        """Horizontal distance from a point to the nearest obstacle reaching its altitude."""
        nearest = math.inf
        for obstacle in self._within(altitude_m, altitude_m, t_s):
            nearest = min(nearest, footprint_distance_m(obstacle, north_m, east_m))
        return nearest

    def edge_clearance_m(
        self,
        north_m: float,
        east_m: float,
        altitude_m: float,
        radius_m: float,
        t_s: float = 0.0,
        height_m: float = VEHICLE_HEIGHT_M,
    ) -> float:
        """Distance in 3-D from the vehicle's edge to the nearest obstacle (negative: inside).

        The vehicle is an upright cylinder of ``radius_m`` and ``height_m`` centred at the
        point; an obstacle above or below it is as far as its vertical and horizontal gaps
        together make (a bar 0.2 m above the vehicle's top is 0.2 m away, whatever its
        footprint).
        """
        low, high = altitude_m - height_m / 2, altitude_m + height_m / 2
        nearest = math.inf
        for obstacle in self.at(t_s):
            across = footprint_distance_m(obstacle, north_m, east_m) - radius_m
            up = vertical_gap_m(obstacle, low, high)
            if up == 0.0:
                distance = across
            elif across <= 0.0:
                distance = up
            else:
                distance = math.hypot(across, up)
            nearest = min(nearest, distance)
        return nearest

    def ray_distances(
        self,
        north_m: float,
        east_m: float,
        altitude_m: float,
        headings_rad: Array,
        t_s: float = 0.0,
        band_m: tuple[float, float] = (0.0, 0.0),
    ) -> Array:
        """Distance along each horizontal ray to the first obstacle (``inf`` if none).

        Args:
            north_m: Ray origin.
            east_m: Ray origin.
            altitude_m: Height of the rays.
            headings_rad: (K,) ray directions, from north, clockwise.
            t_s: The time (where moving obstacles are).
            band_m: How far below and above the rays an obstacle may reach into and count
                (its horizontal distance is the reading; (0, 0): only obstacles the rays meet).

        Returns:
            (K,) distances.
        """
        best = np.full(headings_rad.shape, np.inf)
        dn_ray, de_ray = np.cos(headings_rad), np.sin(headings_rad)
        below, above = band_m
        for obstacle in self._within(altitude_m - below, altitude_m + above, t_s):
            hit, t = ray_hits(obstacle, north_m, east_m, dn_ray, de_ray)
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
        t_s: float = 0.0,
        band_m: tuple[float, float] = (0.0, 0.0),
    ) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]:
        """Exact 72-bin scan (body bins): nearest obstacle per bin, ``inf`` clear, NaN unseen.

        Args:
            north_m: Vehicle position.
            east_m: Vehicle position.
            altitude_m: Vehicle altitude.
            yaw_rad: Vehicle heading.
            covered: (72,) bins the cameras see.
            max_range_m: Beyond this a bin is clear.
            rays_per_bin: Rays cast across each bin.
            t_s: The time (where moving obstacles are).
            band_m: Heights below and above the vehicle within which obstacles count (the
                perception's height band).

        Returns:
            The distances, and (72, 3) the body point (FRD, level) of each finite bin's
            nearest ray, NaN elsewhere, as a head's scan reports them (the planner's memory
            places each reading at its point's bearing).
        """
        offsets = (np.arange(rays_per_bin) + 0.5) / rays_per_bin - 0.5
        body = (np.arange(SECTOR_COUNT)[:, None] + offsets[None, :]) * SECTOR_WIDTH_DEG
        headings = yaw_rad + np.radians(body.ravel())
        distance = self.ray_distances(north_m, east_m, altitude_m, headings, t_s, band_m)
        per_ray = distance.reshape(SECTOR_COUNT, rays_per_bin)
        nearest_ray = np.argmin(per_ray, axis=1)
        rows = np.arange(SECTOR_COUNT)
        nearest = per_ray[rows, nearest_ray]
        scan = np.where(nearest < max_range_m, nearest, np.inf).astype(np.float32)
        scan[~covered] = np.nan
        bearing = np.radians(body[rows, nearest_ray])
        finite = np.isfinite(scan)
        points = np.full((SECTOR_COUNT, 3), np.nan, dtype=np.float32)
        points[finite, 0] = scan[finite] * np.cos(bearing[finite])
        points[finite, 1] = scan[finite] * np.sin(bearing[finite])
        points[finite, 2] = 0.0
        return scan, points
