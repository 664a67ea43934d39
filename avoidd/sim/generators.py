"""Seeded world generators: pole forests, walls, walls with a gap, L-corridors, boxes, dead ends.

The vehicle starts at the origin facing north; the goal lies ``length_m`` north (offset east by
``goal_east_m``; around the corner for an L-corridor, inside a closed room for a dead end).
Gaps, spacings and corridor widths are drawn no narrower than 2.2 times the vehicle's radius
plus margin (``clearance_m``), the narrowest gap the planner must pass. Bars at flight height
and poles that cross the course can be added to the open kinds. A generator's own draws come
first and in a fixed order, so a world drawn before an option existed is drawn the same.
"""

from __future__ import annotations

import math

import numpy as np

from avoidd.config.sim import (
    BoxConfig,
    CylinderConfig,
    GeneratedWorldConfig,
    MotionConfig,
    PlacementConfig,
    WallConfig,
    WorldConfig,
)
from avoidd.config.sim_world import GapSpan, OffsetSpan, RoomSpan, TextureLevel

_KEEP_CLEAR_M = 3.0
"""No obstacle within this distance of the start or the goal."""
NARROWEST = 2.2
"""The narrowest gap drawn, in multiples of the vehicle's radius plus margin."""

Obstacles = list[BoxConfig | WallConfig | CylinderConfig]


def _wall(
    a: tuple[float, float],
    b: tuple[float, float],
    texture: TextureLevel = "full",
    thickness: float = 0.3,
) -> WallConfig:
    return WallConfig(
        shape="wall",
        start_ne_m=a,
        end_ne_m=b,
        thickness_m=thickness,
        height_m=4.0,
        textured=texture,
    )


def _draw(rng: np.random.Generator, span: GapSpan | OffsetSpan | RoomSpan) -> float:
    """A span's value: itself, or drawn from its range."""
    if isinstance(span, tuple):
        return float(rng.uniform(span[0], span[1]))
    return float(span)


def generate(
    config: GeneratedWorldConfig, clearance_m: float
) -> tuple[WorldConfig, PlacementConfig]:
    """The world and the goal a generator draws.

    Args:
        config: The generator and its parameters.
        clearance_m: The vehicle's radius plus margin: gaps between obstacles are at least 2.2
            times that wide, so a reachable goal can be reached.

    Returns:
        The world, and the goal (altitude 2 m).
    """
    rng = np.random.default_rng(config.seed)
    length = config.length_m
    kind = config.kind
    obstacles: Obstacles = []
    if kind == "wall":
        half = float(rng.uniform(5.0, 12.0))
        offset = float(rng.uniform(-3.0, 3.0))
        obstacles.append(
            _wall((length / 2, offset - half), (length / 2, offset + half), config.texture)
        )
    elif kind == "wall_gap":
        obstacles += _wall_gap(rng, config, clearance_m)
    elif kind == "l_corridor":
        return _finish(rng, config, *_l_corridor(rng, config, clearance_m), clearance_m)
    elif kind == "dead_end":
        return _finish(rng, config, *_dead_end(rng, config), clearance_m)
    elif kind in ("pole_forest", "boxes"):
        obstacles += _field(rng, config, clearance_m)
    east = _draw(rng, config.goal_east_m)
    goal = PlacementConfig(north_m=length, east_m=east, altitude_m=2.0)
    return _finish(rng, config, obstacles, goal, clearance_m)


def _finish(
    rng: np.random.Generator,
    config: GeneratedWorldConfig,
    obstacles: Obstacles,
    goal: PlacementConfig,
    clearance_m: float,
) -> tuple[WorldConfig, PlacementConfig]:
    """Add the bars and the crossing poles, then draw the texture seed."""
    if config.bars:
        obstacles += _bars(rng, config, obstacles, clearance_m)
    if config.movers:
        obstacles += _movers(rng, config)
    world = WorldConfig(version=1, seed=int(rng.integers(1, 1_000_000)), obstacles=obstacles)
    return world, goal


def _wall_gap(
    rng: np.random.Generator, config: GeneratedWorldConfig, clearance_m: float
) -> Obstacles:
    """A wall 50 m wide across the course with one gap, its middle up to 3 m off the axis."""
    centre = float(rng.uniform(-3.0, 3.0))
    gap = max(_draw(rng, config.gap_m), NARROWEST * clearance_m)
    north = config.length_m / 2
    return [
        _wall((north, -25.0), (north, centre - gap / 2), config.texture),
        _wall((north, centre + gap / 2), (north, 25.0), config.texture),
    ]


def _l_corridor(
    rng: np.random.Generator, config: GeneratedWorldConfig, clearance_m: float
) -> tuple[Obstacles, PlacementConfig]:
    """Up a corridor to a turn, then along it sideways to the goal."""
    if config.width_m is None:
        width = max(float(rng.uniform(4.0, 6.0)), 2.0 * clearance_m + 1.0)
    else:
        width = max(_draw(rng, config.width_m), NARROWEST * clearance_m)
    length = config.length_m
    turn = length * 0.6
    side = 1.0 if rng.random() < 0.5 else -1.0
    far_east = side * (length * 0.6)
    goal = PlacementConfig(north_m=turn, east_m=far_east, altitude_m=2.0)
    texture = config.texture
    walls: Obstacles = [
        _wall((-3.0, -side * width / 2), (turn + width / 2, -side * width / 2), texture),  # outer
        _wall(
            (turn + width / 2, -side * width / 2),
            (turn + width / 2, far_east + side * 3),
            texture,
        ),
        _wall((-3.0, side * width / 2), (turn - width / 2, side * width / 2), texture),  # inner
        _wall(
            (turn - width / 2, side * width / 2), (turn - width / 2, far_east + side * 3), texture
        ),
    ]
    return walls, goal


def _dead_end(
    rng: np.random.Generator, config: GeneratedWorldConfig
) -> tuple[Obstacles, PlacementConfig]:
    """A closed room round the goal: no path exists."""
    room = _draw(rng, config.room_m)
    north, east = config.length_m, _draw(rng, config.goal_east_m)
    corners = [
        (north - room / 2, east - room / 2),
        (north - room / 2, east + room / 2),
        (north + room / 2, east + room / 2),
        (north + room / 2, east - room / 2),
    ]
    walls: Obstacles = [_wall(corners[i], corners[(i + 1) % 4], config.texture) for i in range(4)]
    return walls, PlacementConfig(north_m=north, east_m=east, altitude_m=2.0)


def _spacing(config: GeneratedWorldConfig, clearance_m: float) -> float:
    """The least free gap between the obstacles of a field."""
    if config.spacing_m is None:
        return 2.0 * clearance_m + 0.3
    return max(config.spacing_m, NARROWEST * clearance_m)


def _field(rng: np.random.Generator, config: GeneratedWorldConfig, clearance_m: float) -> Obstacles:
    """Poles (10-40 cm) or yawed boxes over 16 m either side of the course."""
    length, kind = config.length_m, config.kind
    area = (length - 2 * _KEEP_CLEAR_M) * 16.0
    count = round(config.density * area / 100.0)
    spacing = _spacing(config, clearance_m)
    placed: list[tuple[float, float, float]] = []  # north, east, radius
    for _ in range(count * 20):
        if len(placed) >= count:
            break
        north = float(rng.uniform(_KEEP_CLEAR_M + 1.0, length - _KEEP_CLEAR_M - 1.0))
        east = float(rng.uniform(-8.0, 8.0))
        radius = (
            float(rng.uniform(0.05, 0.2)) if kind == "pole_forest" else float(rng.uniform(0.3, 1.0))
        )
        if all(math.hypot(north - n, east - e) - radius - r >= spacing for n, e, r in placed):
            placed.append((north, east, radius))
    obstacles: Obstacles = []
    for north, east, radius in placed:
        if kind == "pole_forest":
            obstacles.append(
                CylinderConfig(
                    shape="pole",
                    north_m=north,
                    east_m=east,
                    diameter_m=2 * radius,
                    height_m=float(rng.uniform(3.0, 6.0)),
                    textured=config.texture,
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
                    textured=config.texture,
                )
            )
    return obstacles


def _footprint_points(item: BoxConfig | WallConfig | CylinderConfig) -> list[tuple[float, float]]:
    """Points along an obstacle's footprint's axis, 0.5 m apart, with its half width."""
    if isinstance(item, WallConfig):
        (n0, e0), (n1, e1) = item.start_ne_m, item.end_ne_m
        steps = max(1, math.ceil(math.hypot(n1 - n0, e1 - e0) / 0.5))
        return [(n0 + (n1 - n0) * k / steps, e0 + (e1 - e0) * k / steps) for k in range(steps + 1)]
    return [(item.north_m, item.east_m)]


def _half_width(item: BoxConfig | WallConfig | CylinderConfig) -> float:
    if isinstance(item, WallConfig):
        return item.thickness_m / 2
    if isinstance(item, BoxConfig):
        return math.hypot(item.length_m, item.width_m) / 2
    return item.diameter_m / 2


def _apart(new: WallConfig, others: Obstacles, spacing_m: float) -> bool:
    """Whether a bar keeps the spacing from every other obstacle (at any height)."""
    for other in others:
        reach = spacing_m + _half_width(new) + _half_width(other)
        for n, e in _footprint_points(new):
            for on, oe in _footprint_points(other):
                if math.hypot(n - on, e - oe) < reach:
                    return False
    return True


def _bars(
    rng: np.random.Generator,
    config: GeneratedWorldConfig,
    obstacles: Obstacles,
    clearance_m: float,
) -> list[WallConfig]:
    """Bars 3-8 m long at flight height (1.7-1.95 m up to 0.3 m above that), roughly across.

    Each keeps the field's spacing from everything else; one that cannot is left out.
    """
    length, spacing = config.length_m, _spacing(config, clearance_m)
    bars: list[WallConfig] = []
    for _ in range(config.bars * 20):
        if len(bars) >= config.bars:
            break
        north = float(rng.uniform(_KEEP_CLEAR_M + 2.0, length - _KEEP_CLEAR_M - 2.0))
        east = float(rng.uniform(-6.0, 6.0))
        half = float(rng.uniform(1.5, 4.0))
        yaw = math.radians(90.0 + float(rng.uniform(-30.0, 30.0)))
        bottom = float(rng.uniform(1.7, 1.95))
        dn, de = half * math.cos(yaw), half * math.sin(yaw)
        bar = WallConfig(
            shape="wall",
            start_ne_m=(north - dn, east - de),
            end_ne_m=(north + dn, east + de),
            thickness_m=0.3,
            height_m=bottom + 0.3,
            bottom_m=bottom,
            textured=config.texture,
        )
        if _apart(bar, [*obstacles, *bars], spacing):
            bars.append(bar)
    return bars


def _movers(rng: np.random.Generator, config: GeneratedWorldConfig) -> list[CylinderConfig]:
    """Poles 0.3 m across that cross the course, 4-8 m each way and back at 0.3-1 m/s.

    They keep 5 m from the start and the goal along the course, so none runs into a vehicle
    waiting there.
    """
    length = config.length_m
    movers = []
    for _ in range(config.movers):
        north = float(rng.uniform(_KEEP_CLEAR_M + 2.0, length - _KEEP_CLEAR_M - 2.0))
        east = float(rng.uniform(-6.0, 6.0))
        by = float(rng.uniform(4.0, 8.0)) * (1.0 if east < 0.0 else -1.0)
        movers.append(
            CylinderConfig(
                shape="pole",
                north_m=north,
                east_m=east,
                diameter_m=0.3,
                height_m=4.0,
                textured=config.texture,
                motion=MotionConfig(by_ne_m=(0.0, by), speed_m_s=float(rng.uniform(0.3, 1.0))),
            )
        )
    return movers
