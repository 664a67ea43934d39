"""The attitude and height a frame is interpreted with, from the best source that has them."""

from __future__ import annotations

import math

from avoidd.config import PerceptionConfig
from avoidd.mavlink.attitude import Attitude
from avoidd.perception.ground import height_from_rangefinder
from avoidd.types import FramePose, LocalPosition, Rangefinder


def resolve_pose(
    t_capture_ns: int,
    recorded: FramePose | None,
    attitude: Attitude | None,
    rangefinder: Rangefinder | None,
    position: LocalPosition | None,
    config: PerceptionConfig,
) -> FramePose:
    """Choose the attitude and height of a frame.

    A frame that carries its own pose (a recording, a rendered scene) was taken in that pose,
    not in the one the autopilot reports now: its attitude (and its height, when it has one)
    come first. The demo's mock autopilot sways while the synthetic scene is rendered level;
    interpreted with the sway, the ground rose into view as phantom obstacles.

    Attitude: the frame's own (a frame may carry only its height: NaN roll and pitch); else
    the autopilot's, interpolated at the capture time; else the configured one. Height: the
    frame's own; else a downward rangefinder reading taken within
    ``ground.rangefinder_max_age_ms`` of capture (corrected for the tilt); else the height
    above home when ``ground.use_altitude`` is on and the position is as fresh; else
    ``ground.height_m``.

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
    if recorded is not None and math.isfinite(recorded.roll_deg + recorded.pitch_deg):
        roll_deg, pitch_deg, source = recorded.roll_deg, recorded.pitch_deg, recorded.source
    elif attitude is not None:
        roll_deg = math.degrees(attitude.roll_rad)
        pitch_deg = math.degrees(attitude.pitch_rad)
        source = "mavlink"
    else:
        roll_deg, pitch_deg = config.attitude.roll_deg, config.attitude.pitch_deg
        source = "config"
    max_age_ns = config.ground.rangefinder_max_age_ms * 1_000_000
    if recorded is not None and math.isfinite(recorded.height_m):
        height_m, height_source = recorded.height_m, recorded.height_source
    elif rangefinder is not None and abs(t_capture_ns - rangefinder.t_ns) <= max_age_ns:
        height_m = height_from_rangefinder(rangefinder.distance_m, roll_deg, pitch_deg)
        height_source = "rangefinder"
    elif (
        config.ground.use_altitude
        and position is not None
        and abs(t_capture_ns - position.t_ns) <= max_age_ns
        and position.down_m < 0.0
    ):
        height_m, height_source = -position.down_m, "altitude"
    else:
        height_m, height_source = config.ground.height_m, "config"
    return FramePose(roll_deg, pitch_deg, height_m, source, height_source)
