"""Simulated worlds: obstacles (how textured, how high above the ground, moving), generators.

A world file (``sitl/worlds/*.yaml``) lists its obstacles; a scenario may instead name a
generator that draws a seeded world. Validated like every config: errors name the file,
line and key.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BeforeValidator, Field, model_validator

from avoidd.config.base import Lax, Strict, WholeNumber

Metres = Annotated[float, Field(ge=-1000.0, le=1000.0)]

TextureLevel = Literal["full", "low", "partial", "flat"]
"""How textured a surface is: ``full`` (the pattern at full contrast), ``low`` (a tenth of the
contrast: a painted wall), ``partial`` (textured in patches 1.5 m across, flat between),
``flat`` (one shade: nothing for stereo to match)."""


def _texture_level(value: object) -> object:
    # ``textured: true/false`` from before the levels: full or flat.
    if value is True:
        return "full"
    if value is False:
        return "flat"
    return value


Texture = Annotated[TextureLevel, BeforeValidator(_texture_level)]


class MotionConfig(Strict):
    """An obstacle that moves: from where it stands by ``by_ne_m`` and back, again and again.

    Attributes:
        by_ne_m: How far it goes (north, east), metres.
        speed_m_s: How fast.
    """

    by_ne_m: Annotated[tuple[Metres, Metres], Lax]
    speed_m_s: float = Field(gt=0.0, le=20.0)

    @model_validator(mode="after")
    def _moves(self) -> MotionConfig:
        if self.by_ne_m == (0.0, 0.0):
            raise ValueError("a motion goes somewhere: by_ne_m is not [0, 0]")
        return self


class _Solid(Strict):
    """What every obstacle has: its top, its bottom, its texture, its motion."""

    height_m: float = Field(3.0, gt=0.0, le=200.0)
    """Its top above the ground."""
    bottom_m: float = Field(0.0, ge=0.0, le=200.0)
    """Its underside above the ground (0: it stands on the ground; a bar or a branch at
    flight height has one above it)."""
    textured: Texture = "full"
    motion: MotionConfig | None = None

    @model_validator(mode="after")
    def _extent(self) -> _Solid:
        if self.bottom_m >= self.height_m:
            raise ValueError(
                f"bottom_m {self.bottom_m} must be below height_m {self.height_m} (its top)"
            )
        return self


class BoxConfig(_Solid):
    """A box: centre of its footprint, size, yaw (degrees from north)."""

    shape: Literal["box"]
    north_m: Metres
    east_m: Metres
    length_m: float = Field(1.0, gt=0.0, le=500.0)
    """Along its yaw direction."""
    width_m: float = Field(1.0, gt=0.0, le=500.0)
    yaw_deg: float = Field(0.0, ge=-360.0, le=360.0)


class WallConfig(_Solid):
    """A wall between two points (a thin box)."""

    shape: Literal["wall"]
    start_ne_m: Annotated[tuple[Metres, Metres], Lax]
    end_ne_m: Annotated[tuple[Metres, Metres], Lax]
    thickness_m: float = Field(0.3, gt=0.0, le=20.0)
    height_m: float = Field(4.0, gt=0.0, le=200.0)

    @model_validator(mode="after")
    def _length(self) -> WallConfig:
        if self.start_ne_m == self.end_ne_m:
            raise ValueError("a wall needs two different end points")
        return self


class CylinderConfig(_Solid):
    """A pole or a tree trunk: a vertical cylinder."""

    shape: Literal["pole", "tree"]
    north_m: Metres
    east_m: Metres
    diameter_m: float = Field(0.3, gt=0.0, le=50.0)
    height_m: float = Field(5.0, gt=0.0, le=200.0)


ObstacleConfig = Annotated[BoxConfig | WallConfig | CylinderConfig, Field(discriminator="shape")]


class WorldConfig(Strict):
    """A world: textured ground, obstacles, a tree line far around, sky.

    Attributes:
        seed: Seed of every surface's texture.
        obstacles: The obstacles.
        treeline_m: Radius of a textured tree line around the origin (None: open horizon).
    """

    version: Annotated[Literal[1], WholeNumber]
    seed: int = Field(1, ge=0)
    obstacles: list[ObstacleConfig] = Field(default_factory=list)
    treeline_m: float | None = Field(60.0, gt=5.0, le=2000.0)


GapLength = Annotated[float, Field(ge=0.5, le=50.0)]
GapSpan = GapLength | Annotated[tuple[GapLength, GapLength], Lax]
"""A gap's width, or a range ``[low, high]`` to draw it from."""
Offset = Annotated[float, Field(ge=-50.0, le=50.0)]
OffsetSpan = Offset | Annotated[tuple[Offset, Offset], Lax]
RoomLength = Annotated[float, Field(ge=3.0, le=50.0)]
RoomSpan = RoomLength | Annotated[tuple[RoomLength, RoomLength], Lax]


class GeneratedWorldConfig(Strict):
    """A world drawn by a seeded generator (see ``avoidd.sim.generators``).

    A length given as ``[low, high]`` is drawn from that range for each seed. Gaps, spacings
    and corridor widths are never drawn narrower than 2.2 times the vehicle's radius plus
    margin (the planner must pass a gap that wide).

    Attributes:
        kind: The generator.
        seed: Its seed.
        density: Obstacles per 100 square metres (pole forest, boxes).
        gap_m: Width of the gap in a wall (wall with a gap).
        length_m: Length of the course along the way to the goal.
        spacing_m: The least free gap between poles or boxes (None: twice the radius plus
            margin, and 0.3 m).
        width_m: The L-corridor's width (None: drawn from 4 to 6 m).
        room_m: The side of a dead end's closed room.
        goal_east_m: The goal's offset to the east of the course's axis (the L-corridor's
            goal is round its corner and takes none).
        texture: How textured the drawn obstacles are.
        bars: Bars to add across the course at flight height (1.6-1.9 m up, 0.3 m deep).
        movers: Poles to add that cross the course, back and forth at 0.3-1 m/s.
    """

    kind: Literal["pole_forest", "wall_gap", "l_corridor", "dead_end", "boxes", "wall", "open"]
    seed: int = Field(1, ge=0)
    density: float = Field(3.0, gt=0.0, le=50.0)
    gap_m: GapSpan = 4.0
    length_m: float = Field(30.0, gt=5.0, le=500.0)
    spacing_m: float | None = Field(None, gt=0.0, le=50.0)
    width_m: GapSpan | None = None
    room_m: RoomSpan = 6.0
    goal_east_m: OffsetSpan = 0.0
    texture: Texture = "full"
    bars: int = Field(0, ge=0, le=20)
    movers: int = Field(0, ge=0, le=20)

    @model_validator(mode="after")
    def _spans(self) -> GeneratedWorldConfig:
        for name in ("gap_m", "width_m", "room_m", "goal_east_m"):
            value = getattr(self, name)
            if isinstance(value, tuple) and value[0] > value[1]:
                raise ValueError(f"{name}: a range goes from low to high, not {list(value)}")
        if self.kind == "l_corridor" and self.goal_east_m != 0.0:
            raise ValueError("goal_east_m: an L-corridor's goal is round its corner; remove it")
        if (self.bars or self.movers) and self.kind not in ("open", "pole_forest", "boxes"):
            raise ValueError(
                f"bars and movers go into open, pole_forest and boxes courses, not {self.kind}"
            )
        return self
