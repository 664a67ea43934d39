"""Simulation files: worlds (``sitl/worlds/*.yaml``) and scenarios (``sitl/scenarios/*.yaml``).

Validated like the daemon's configuration: unknown keys, impossible values and missing keys are
refused with the file, line and key path.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Literal

from pydantic import AfterValidator, Field, ValidationInfo, field_validator, model_validator

from avoidd.config.avoidance import AvoidanceConfig
from avoidd.config.base import ConfigPath, Lax, Strict, WholeNumber, _existing_file
from avoidd.config.sim_world import (
    BoxConfig,
    CylinderConfig,
    GeneratedWorldConfig,
    Metres,
    MotionConfig,
    ObstacleConfig,
    WallConfig,
    WorldConfig,
)
from avoidd.yamlfile import load_yaml, validate_document

__all__ = [
    "ActionConfig",
    "BoxConfig",
    "CameraConfig",
    "CylinderConfig",
    "GeneratedWorldConfig",
    "MotionConfig",
    "ObstacleConfig",
    "PassConfig",
    "PlacementConfig",
    "ScenarioConfig",
    "WallConfig",
    "WorldConfig",
    "load_scenario",
    "load_world",
]


class PlacementConfig(Strict):
    """A place in the local frame, altitude above the origin, heading from north."""

    north_m: Metres = 0.0
    east_m: Metres = 0.0
    altitude_m: float = Field(2.0, ge=0.0, le=500.0)
    yaw_deg: float = Field(0.0, ge=-360.0, le=360.0)


Offset = Annotated[float, Field(ge=-2.0, le=2.0)]


class CameraConfig(Strict):
    """One simulated stereo head: where it sits on the vehicle, where it looks, how wide.

    Attributes:
        name: For the timeline (``camera_unplug`` of one head).
        yaw_deg: Turned to the right of the nose.
        pitch_deg: Tilted up.
        roll_deg: Rolled right side down.
        position_m: Forward, right, down of the body origin.
        hfov_deg: Horizontal field of view (None: the rig's 77 degrees); the focal length
            follows, the image size and baseline stay.
    """

    name: str = Field("front", min_length=1, max_length=40, pattern=r"^[A-Za-z0-9_-]+$")
    yaw_deg: float = Field(0.0, ge=-180.0, le=180.0)
    pitch_deg: float = Field(0.0, ge=-60.0, le=60.0)
    roll_deg: float = Field(0.0, ge=-45.0, le=45.0)
    position_m: Annotated[tuple[Offset, Offset, Offset], Lax] = (0.0, 0.0, 0.0)
    hfov_deg: float | None = Field(None, ge=30.0, le=120.0)


class ActionConfig(Strict):
    """Something that happens during a scenario, at a time or at a distance.

    Attributes:
        t_s: When (seconds from the start).
        flown_m: Or once the vehicle has flown this far (horizontally, from the start).
        goal_within_m: Or once the vehicle is this near the goal in force.
        action: ``mode`` (switch to ``mode``), ``goal`` (fly to ``goal``), ``camera_unplug``,
            ``camera_replug``, ``disarm``.
        mode: The flight mode (for ``mode``).
        goal: The new goal (for ``goal``).
        camera: The head a camera action is for (None: every head).
    """

    t_s: float | None = Field(None, ge=0.0, le=3600.0)
    flown_m: float | None = Field(None, gt=0.0, le=100_000.0)
    goal_within_m: float | None = Field(None, gt=0.0, le=10_000.0)
    action: Literal["mode", "goal", "camera_unplug", "camera_replug", "disarm"]
    mode: str | None = None
    goal: PlacementConfig | None = None
    camera: str | None = None

    @property
    def time_s(self) -> float:
        """When a timed action happens (a distance-triggered one: never by the clock)."""
        return math.inf if self.t_s is None else self.t_s

    @model_validator(mode="after")
    def _arguments(self) -> ActionConfig:
        triggers = [self.t_s, self.flown_m, self.goal_within_m]
        if sum(trigger is not None for trigger in triggers) != 1:
            raise ValueError("an action happens at t_s, after flown_m or at goal_within_m: one")
        if self.action == "mode" and not self.mode:
            raise ValueError("a mode action names the mode, e.g. mode: GUIDED")
        if self.action == "goal" and self.goal is None:
            raise ValueError("a goal action gives the goal: {north_m, east_m, altitude_m}")
        if self.camera is not None and not self.action.startswith("camera_"):
            raise ValueError(f"only camera actions name a camera, not {self.action}")
        return self


class PassConfig(Strict):
    """What a run must show to pass.

    Attributes:
        no_collision: The vehicle never comes within its radius of an obstacle.
        min_clearance_m: Smallest allowed distance between the vehicle's edge and an obstacle
            in 99 % of the time steps (None: not checked).
        reach_goal_s: The goal must be reached within this time (None: not required).
        end_state: The planner state the run must end in (``no path`` for a dead end).
        closest_approach_m: The smallest edge clearance of the run must lie within these
            bounds (a head-on wall: the vehicle comes up to its margin, not nearer, not far
            short of it).
        max_side_changes: At most this many side changes within one detour (None: not
            checked).
        start_delay_s: The vehicle must be moving (faster than 0.3 m/s) within this time of
            the start (None: not checked).
        no_path_within_s: The planner must say "no path" within this time of the goal
            (None: not checked).
    """

    no_collision: bool = True
    min_clearance_m: float | None = Field(None, ge=0.0, le=100.0)
    reach_goal_s: float | None = Field(None, gt=0.0, le=3600.0)
    end_state: Literal["arrived", "no path", "moving", "stale"] | None = None
    closest_approach_m: Annotated[tuple[float, float], Lax] | None = None
    max_side_changes: int | None = Field(None, ge=0, le=1000)
    start_delay_s: float | None = Field(None, gt=0.0, le=3600.0)
    no_path_within_s: float | None = Field(None, gt=0.0, le=3600.0)


class ScenarioConfig(Strict):
    """A closed-loop scenario.

    Attributes:
        name: For reports.
        world: A world file, or a generator.
        autopilot: The simulated autopilot's flavour.
        start: Where the vehicle starts (flying: the scenario begins in the air).
        goal: Where avoidd is to fly it (a generated world brings its own; this replaces it).
        duration_s: Length of the run.
        end_after_s: The run ends this long after the goal is reached or the planner first
            says "no path" (None: it runs for ``duration_s``; a batch spends less time
            hovering).
        fps: Camera frames per second.
        resolution: Camera size (``320x240`` or ``640x480``).
        perception: ``stereo`` (render both views and run the pipeline) or ``oracle`` (exact
            distances per bin: to tell planner from perception errors).
        avoidance: The planner's settings (``enabled`` is implied).
        wind_m_s: Steady wind (north, east).
        cameras: The stereo heads (their merged scans are avoidd's).
        timeline: What happens when.
        passing: The pass criteria.
    """

    version: Annotated[Literal[1], WholeNumber]
    name: str = Field(min_length=1, max_length=80)
    world: Annotated[ConfigPath, AfterValidator(_existing_file)] | GeneratedWorldConfig
    autopilot: Literal["ardupilot", "px4"] = "ardupilot"
    start: PlacementConfig = PlacementConfig()
    goal: PlacementConfig | None = None
    duration_s: float = Field(60.0, gt=0.0, le=3600.0)
    end_after_s: float | None = Field(None, ge=0.0, le=3600.0)
    fps: float = Field(15.0, ge=0.1, le=60.0)
    resolution: Literal["320x240", "640x480"] = "320x240"
    perception: Literal["stereo", "oracle"] = "stereo"
    avoidance: AvoidanceConfig = AvoidanceConfig(enabled=True)
    wind_m_s: Annotated[tuple[float, float], Lax] = (0.0, 0.0)
    cameras: list[CameraConfig] = Field(
        default_factory=lambda: [CameraConfig()], min_length=1, max_length=4
    )
    timeline: list[ActionConfig] = Field(default_factory=list)
    passing: PassConfig = Field(default_factory=PassConfig, alias="pass")

    model_config = Strict.model_config | {"populate_by_name": True}

    @model_validator(mode="after")
    def _goal(self) -> ScenarioConfig:
        if self.goal is None and not isinstance(self.world, GeneratedWorldConfig):
            raise ValueError("a scenario on a world file needs a goal: {north_m, east_m}")
        return self

    @field_validator("cameras")
    @classmethod
    def _names(cls, cameras: list[CameraConfig]) -> list[CameraConfig]:
        names = [camera.name for camera in cameras]
        if len(set(names)) != len(names):
            raise ValueError(f"cameras need different names, not {', '.join(names)}")
        return cameras

    @field_validator("timeline")
    @classmethod
    def _cameras_named(
        cls, timeline: list[ActionConfig], info: ValidationInfo
    ) -> list[ActionConfig]:
        cameras = info.data.get("cameras")
        names = [camera.name for camera in cameras or []]
        for action in timeline:
            if cameras is not None and action.camera is not None and action.camera not in names:
                raise ValueError(f"no camera '{action.camera}'; the cameras are {', '.join(names)}")
        return timeline


def load_world(path: Path) -> WorldConfig:
    """Load and validate a world file (errors name the file, line and key path)."""
    return validate_document(load_yaml(path), WorldConfig, {"base_dir": path.parent.resolve()})


def load_scenario(path: Path) -> ScenarioConfig:
    """Load and validate a scenario file (errors name the file, line and key path)."""
    return validate_document(load_yaml(path), ScenarioConfig, {"base_dir": path.parent.resolve()})
