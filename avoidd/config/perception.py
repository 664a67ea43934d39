"""The vehicle-wide perception section: ground, height band, attitude, temporal, obstacles."""

from __future__ import annotations

from pydantic import Field, model_validator

from avoidd.config.base import Strict


class GroundConfig(Strict):
    """The ground-plane model that keeps the ground from looking like an obstacle.

    The ground is a horizontal plane ``height_m`` below the body origin (in the level frame,
    which follows the vehicle attitude). The height comes from the first of these that is
    known: a fresh downward rangefinder (DISTANCE_SENSOR, PITCH_270) corrected for the tilt,
    the height above home (LOCAL_POSITION_NED) when ``use_altitude`` is on (flat ground only),
    the height recorded with the frame, and finally ``height_m``.

    Attributes:
        height_m: Height of the body origin above the ground when nothing better is known.
        use_altitude: Trust the height above home as height above ground.
        margin_m: Points less than this above the ground plane are ground.
        disparity_tolerance_px: A point must stay above the margin with its disparity this
            much smaller (farther along its ray): far ground measured a pixel too near would
            otherwise stand up as an obstacle.
        rangefinder_max_age_ms: A rangefinder reading older than this is not used.
        match_band_px: Obstacle points at most this much disparity nearer than the ground
            behind them are checked against the ground: where the images match the ground
            plane's disparity as well as the measured one, the point is ground read too near
            and dropped (semi-global matching smooths weakly textured far ground under open
            sky 2 to 5 px too near; see ``avoidd.perception.ground_match``). 0: no check.
    """

    height_m: float = Field(1.5, gt=0.0, le=500.0)
    use_altitude: bool = False
    margin_m: float = Field(0.3, ge=0.0, le=5.0)
    disparity_tolerance_px: float = Field(1.0, ge=0.0, le=16.0)
    rangefinder_max_age_ms: int = Field(500, ge=10, le=5000)
    match_band_px: float = Field(6.0, ge=0.0, le=64.0)


class BandConfig(Strict):
    """Points more than ``above_m`` above or ``below_m`` below the body origin are ignored.

    Attributes:
        above_m: Ignore points higher than this above the body origin.
        below_m: Ignore points lower than this below the body origin (the ground model removes the
            ground first).
    """

    above_m: float = Field(2.0, gt=0.0, le=100.0)
    below_m: float = Field(2.0, gt=0.0, le=100.0)


class AttitudeConfig(Strict):
    """Attitude assumed when neither the autopilot nor the recording gives one.

    Attributes:
        roll_deg: Roll assumed without an autopilot or recorded attitude (right wing down
            positive).
        pitch_deg: Pitch assumed likewise (nose up positive).
    """

    roll_deg: float = Field(0.0, ge=-90.0, le=90.0)
    pitch_deg: float = Field(0.0, ge=-90.0, le=90.0)


class TemporalConfig(Strict):
    """Per-bin filter between frames (see ``avoidd.perception.temporal``).

    Attributes:
        confirm_frames: A new obstacle is reported once it was seen in this many ...
        window_frames: ... of the last this many frames (k of n); until then its bin is
            unknown, neither clear nor an obstacle.
        hold_ms: A confirmed obstacle that vanishes keeps its distance this long at most
            (and never beyond ``pipeline.max_age_ms``: every bin carries its reading's capture
            time, and the sender makes older bins unknown).
    """

    confirm_frames: int = Field(2, ge=1, le=10)
    window_frames: int = Field(3, ge=1, le=10)
    hold_ms: int = Field(200, ge=0, le=2000)

    @model_validator(mode="after")
    def _k_of_n(self) -> TemporalConfig:
        if self.confirm_frames > self.window_frames:
            raise ValueError("confirm_frames cannot exceed window_frames (k of n needs k <= n)")
        return self


class ObstaclesConfig(Strict):
    """Clustering of obstacle points into obstacles (per head and frame).

    Attributes:
        bearing_cell_deg: Angular cell of the clustering grid.
        disparity_cell_px: Range cell of the grid, in disparity pixels (range noise is about
            constant in disparity).
        min_points: Points an obstacle needs.
        max_count: Obstacles listed per head and frame, nearest first.
    """

    bearing_cell_deg: float = Field(1.0, gt=0.05, le=10.0)
    disparity_cell_px: float = Field(1.0, gt=0.05, le=16.0)
    min_points: int = Field(30, ge=1)
    max_count: int = Field(16, ge=1, le=256)


class PerceptionConfig(Strict):
    """Vehicle-wide perception: ground model, height band, attitude fallback, filtering."""

    ground: GroundConfig = GroundConfig()
    band: BandConfig = BandConfig()
    attitude: AttitudeConfig = AttitudeConfig()
    temporal: TemporalConfig = TemporalConfig()
    obstacles: ObstaclesConfig = ObstaclesConfig()
