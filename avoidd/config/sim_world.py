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


class GeneratedWorldConfig(Strict):
    """A world drawn by a seeded generator (see ``avoidd.sim.generators``).

    Attributes:
        kind: The generator.
        seed: Its seed.
        density: Obstacles per 100 square metres (pole forest, boxes).
        gap_m: Width of the gap in a wall (wall with a gap).
        length_m: Length of the course along the way to the goal.
    """

    kind: Literal["pole_forest", "wall_gap", "l_corridor", "dead_end", "boxes", "wall", "open"]
    seed: int = Field(1, ge=0)
    density: float = Field(3.0, gt=0.0, le=50.0)
    gap_m: float = Field(4.0, gt=0.5, le=50.0)
    length_m: float = Field(30.0, gt=5.0, le=500.0)
