"""The attitude and height a frame is interpreted with, from the best source that has them."""

from __future__ import annotations

import math

from avoidd.config import PerceptionConfig
from avoidd.mavlink.attitude import Attitude
from avoidd.mavlink.vehicle import LocalPosition, Rangefinder
from avoidd.perception.ground import height_from_rangefinder
from avoidd.types import FramePose


def resolve_pose(
    t_capture_ns: int,
    recorded: FramePose | None,
    attitude: Attitude | None,
    rangefinder: Rangefinder | None,
    position: LocalPosition | None,
    config: PerceptionConfig,
) -> FramePose:
    """Choose the attitude and height of a frame.

    Attitude: the autopilot's, interpolated at the capture time; else the one recorded with
    the frame; else the configured one. Height: a downward rangefinder reading taken within
    ``ground.rangefinder_max_age_ms`` of capture (corrected for the tilt); else the height
    above home when ``ground.use_altitude`` is on and the position is as fresh; else the
    recorded height (when the recording has one); else ``ground.height_m``.

    Args:
        t_capture_ns: Capture time of the frame (avoidd's monotonic clock).
        recorded: The pose that came with the frame, if any.
        attitude: The autopilot's attitude at capture, if known.
        rangefinder: The latest downward rangefinder reading, if any.
        position: The latest local position, if any.
        config: Fallbacks and limits.

    Returns:
        The pose, naming where each part came from.
    """
    if attitude is not None:
        roll_deg = math.degrees(attitude.roll_rad)
        pitch_deg = math.degrees(attitude.pitch_rad)
        source = "mavlink"
    elif recorded is not None:
        roll_deg, pitch_deg, source = recorded.roll_deg, recorded.pitch_deg, recorded.source
    else:
        roll_deg, pitch_deg = config.attitude.roll_deg, config.attitude.pitch_deg
        source = "config"
    max_age_ns = config.ground.rangefinder_max_age_ms * 1_000_000
    if rangefinder is not None and abs(t_capture_ns - rangefinder.t_ns) <= max_age_ns:
        height_m = height_from_rangefinder(rangefinder.distance_m, roll_deg, pitch_deg)
        height_source = "rangefinder"
    elif (
        config.ground.use_altitude
        and position is not None
        and abs(t_capture_ns - position.t_ns) <= max_age_ns
        and position.down_m < 0.0
    ):
        height_m, height_source = -position.down_m, "altitude"
    elif recorded is not None and math.isfinite(recorded.height_m):
        height_m, height_source = recorded.height_m, recorded.height_source
    else:
        height_m, height_source = config.ground.height_m, "config"
    return FramePose(roll_deg, pitch_deg, height_m, source, height_source)
