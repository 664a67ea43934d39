"""A stereo head's section: its name, calibration file, mount and per-head pipeline settings."""

from __future__ import annotations

import re
from typing import Annotated

from pydantic import AfterValidator, Field, field_validator

from avoidd.config.base import ConfigPath, Lax, Strict, _existing_file
from avoidd.config.sources import SourceConfig
from avoidd.config.stereo import (
    HistogramConfig,
    MatcherConfig,
    NearFieldConfig,
    PostprocessConfig,
    PreprocessConfig,
    SectorsConfig,
    SgbmConfig,
)


class MountConfig(Strict):
    """Pose of a stereo head in the body FRD frame (see ``avoidd.types.Mount``).

    Attributes:
        yaw_deg: Heading of the head's optical axis from the vehicle's nose, clockwise (90: looks
            right).
        pitch_deg: Tilt of the optical axis, nose up positive.
        roll_deg: Roll of the head about its optical axis.
        position_m: Forward, right and down offset of the left camera from the body origin, each
            within 5 m of it.
    """

    yaw_deg: float = Field(0.0, ge=-180.0, le=360.0)
    pitch_deg: float = Field(0.0, ge=-90.0, le=90.0)
    roll_deg: float = Field(0.0, ge=-180.0, le=180.0)
    position_m: Annotated[
        tuple[
            Annotated[float, Field(ge=-5.0, le=5.0)],
            Annotated[float, Field(ge=-5.0, le=5.0)],
            Annotated[float, Field(ge=-5.0, le=5.0)],
        ],
        Lax,
    ] = (0.0, 0.0, 0.0)
    """Forward, right and down offset of the left camera from the body origin, each within
    5 m of it."""


_HEAD_NAME = re.compile(r"^[a-z][a-z0-9_-]{0,31}$")


class HeadConfig(Strict):
    """One stereo head: its calibration file, its mount, its source and its matcher.

    Attributes:
        name: Lower case, unique: it names the head in logs, STATUSTEXT and stats.
        calibration: The head's calibration file (``avoidd calibrate`` or ``import-calibration``
            writes one).
        disparity_error_px: The disparity error to count on (pixels of the images the matcher
            sees). It sets how far the head resolves: the range where the error is half the
            disparity, ``f * B / (2 * disparity_error_px)`` (a 50 % range error). Nothing
            farther is claimed: OBSTACLE_DISTANCE's maximum, and so the range a clear bin
            vouches for, is at most that of the least resolving head.
    """

    name: str
    calibration: Annotated[ConfigPath, AfterValidator(_existing_file)]
    mount: MountConfig = MountConfig()
    source: SourceConfig
    matcher: MatcherConfig = SgbmConfig()
    near_field: NearFieldConfig = NearFieldConfig()
    preprocess: PreprocessConfig = PreprocessConfig()
    postprocess: PostprocessConfig = PostprocessConfig()
    sectors: SectorsConfig = SectorsConfig()
    histogram: HistogramConfig = HistogramConfig()
    disparity_error_px: float = Field(0.5, ge=0.05, le=8.0)

    @field_validator("name")
    @classmethod
    def _name(cls, value: str) -> str:
        if not _HEAD_NAME.match(value):
            raise ValueError("use lower case letters, digits, '-' or '_', e.g. 'front'")
        return value
