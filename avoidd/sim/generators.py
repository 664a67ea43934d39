"""Seeded world generators: pole forests, walls, walls with a gap, L-corridors, boxes, dead ends.

The vehicle starts at the origin facing north; the goal lies ``length_m`` north (around the
corner for an L-corridor, inside a closed room for a dead end).
"""

from __future__ import annotations

import math

import numpy as np

from avoidd.config.sim import (
    BoxConfig,
    CylinderConfig,
    GeneratedWorldConfig,
    PlacementConfig,
    WallConfig,
    WorldConfig,
)

_KEEP_CLEAR_M = 3.0
"""No obstacle within this distance of the start or the goal."""


def _wall(a: tuple[float, float], b: tuple[float, float], thickness: float = 0.3) -> WallConfig:
    return WallConfig(shape="wall", start_ne_m=a, end_ne_m=b, thickness_m=thickness, height_m=4.0)


def generate(
    config: GeneratedWorldConfig, clearance_m: float
) -> tuple[WorldConfig, PlacementConfig]:
    """The world and the goal a generator draws.

    Args:
        config: The generator and its parameters.
        clearance_m: The vehicle's radius plus margin: gaps between obstacles are at least
            twice that wide, so a reachable goal can be reached.

    Returns:
        The world, and the goal (altitude 2 m).
    """
    rng = np.random.default_rng(config.seed)
    length = config.length_m
    goal = PlacementConfig(north_m=length, east_m=0.0, altitude_m=2.0)
    obstacles: list[BoxConfig | WallConfig | CylinderConfig] = []
    kind = config.kind
    if kind == "wall":
        half = float(rng.uniform(5.0, 12.0))
        offset = float(rng.uniform(-3.0, 3.0))
        obstacles.append(_wall((length / 2, offset - half), (length / 2, offset + half)))
    elif kind == "wall_gap":
        gap = max(config.gap_m, 2.0 * clearance_m + 0.5)
        centre = float(rng.uniform(-3.0, 3.0))
        north = length / 2
        obstacles.append(_wall((north, -25.0), (north, centre - gap / 2)))
        obstacles.append(_wall((north, centre + gap / 2), (north, 25.0)))
    elif kind == "l_corridor":
        width = max(float(rng.uniform(4.0, 6.0)), 2.0 * clearance_m + 1.0)
        turn = length * 0.6
        side = 1.0 if rng.random() < 0.5 else -1.0
        # Up the corridor to the turn, then along it sideways to the goal.
        far_east = side * (length * 0.6)
        goal = PlacementConfig(north_m=turn, east_m=far_east, altitude_m=2.0)
        obstacles += [
            _wall((-3.0, -side * width / 2), (turn + width / 2, -side * width / 2)),  # outer
            _wall((turn + width / 2, -side * width / 2), (turn + width / 2, far_east + side * 3)),
            _wall((-3.0, side * width / 2), (turn - width / 2, side * width / 2)),  # inner
            _wall((turn - width / 2, side * width / 2), (turn - width / 2, far_east + side * 3)),
        ]
    elif kind == "dead_end":
        # The goal is inside a closed room: no path exists.
        room = 6.0
        north, east = length, 0.0
        corners = [
            (north - room / 2, east - room / 2),
            (north - room / 2, east + room / 2),
            (north + room / 2, east + room / 2),
            (north + room / 2, east - room / 2),
        ]
        obstacles += [_wall(corners[i], corners[(i + 1) % 4]) for i in range(4)]
    elif kind in ("pole_forest", "boxes"):
        area = (length - 2 * _KEEP_CLEAR_M) * 16.0
        count = round(config.density * area / 100.0)
        placed: list[tuple[float, float, float]] = []  # north, east, radius
        for _ in range(count * 20):
            if len(placed) >= count:
                break
            north = float(rng.uniform(_KEEP_CLEAR_M + 1.0, length - _KEEP_CLEAR_M - 1.0))
            east = float(rng.uniform(-8.0, 8.0))
            radius = (
                float(rng.uniform(0.05, 0.2))
                if kind == "pole_forest"
                else float(rng.uniform(0.3, 1.0))
            )
            spacing = 2.0 * clearance_m + 0.3
            if all(math.hypot(north - n, east - e) - radius - r >= spacing for n, e, r in placed):
                placed.append((north, east, radius))
        for north, east, radius in placed:
            if kind == "pole_forest":
                obstacles.append(
                    CylinderConfig(
                        shape="pole",
                        north_m=north,
                        east_m=east,
                        diameter_m=2 * radius,
                        height_m=float(rng.uniform(3.0, 6.0)),
                    )
                )
            else:
                obstacles.append(
                    BoxConfig(
                        shape="box",
                        north_m=north,
                        east_m=east,
                        length_m=radius * 1.4,
                        width_m=radius * 1.4,
                        height_m=float(rng.uniform(2.5, 4.0)),
                        yaw_deg=float(rng.uniform(0.0, 90.0)),
                    )
                )
    world = WorldConfig(version=1, seed=int(rng.integers(1, 1_000_000)), obstacles=obstacles)
    return world, goal
