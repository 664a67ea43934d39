"""What avoidd's scans become on the wire: centimetre bins with the MAVLink special values."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from avoidd.mavlink.codec import Codec, Message
from avoidd.perception.frames import mount_quaternion
from avoidd.perception.sectors import covered_bins
from avoidd.types import FloatArray, Mount, RectifiedRig, SectorScan

UNKNOWN_CM = 65535

_ORIENTATION_TOLERANCE_DEG = 2.5
MAX_SENSOR_PITCH_DEG = 30.0
"""Steepest mount pitch a head may have and still be a horizontal DISTANCE_SENSOR."""


def sensor_orientation(mount: Mount) -> int | None:
    """The MAV_SENSOR_ORIENTATION of a head, or None when no enum value fits it.

    A head's DISTANCE_SENSOR reading is a horizontal range (the nearest bin of its sector scan),
    so only the horizontal orientations fit: ``MAV_SENSOR_ROTATION_YAW_45 * k`` (k = 0..7),
    turned 45*k degrees clockwise (to the right) seen from above, for ArduPilot and PX4 alike.
    The yaw must be within 2.5 degrees of a multiple of 45. A head tilted up or down by up to
    ``MAX_SENSOR_PITCH_DEG`` (a forward camera looking slightly down, say) still measures
    horizontal ranges in that direction and keeps its yaw orientation. Steeper heads have
    none: PITCH_270 would make the autopilot take the reading as its height above ground,
    which a horizontal range is not. Roll about the viewing axis does not change where a
    range sensor points.

    Args:
        mount: The head's mount.

    Returns:
        The enum value (0..7), or None.
    """
    if abs(mount.pitch_deg) > MAX_SENSOR_PITCH_DEG:
        return None
    steps = mount.yaw_deg / 45.0
    k = round(steps)
    if abs(steps - k) * 45.0 > _ORIENTATION_TOLERANCE_DEG:
        return None
    return k % 8


def sectors_to_cm(scan: SectorScan, min_cm: int, max_cm: int) -> list[int]:
    """OBSTACLE_DISTANCE values of a scan.

    Unknown bins become 65535, clear bins ``max_cm + 1``, readings are clamped into
    ``[min_cm, max_cm]`` (so a reading is never 0).

    Args:
        scan: The scan in metres (NaN unknown, ``inf`` clear).
        min_cm: The sensor's minimum distance.
        max_cm: The sensor's maximum distance.

    Returns:
        72 integers.
    """
    metres = scan.distance_m.astype(np.float64)
    out = np.full(metres.shape, UNKNOWN_CM, dtype=np.int64)
    finite = np.isfinite(metres)
    out[finite] = np.clip(np.rint(metres[finite] * 100.0), min_cm, max_cm)
    out[np.isposinf(metres)] = max_cm + 1
    return [int(v) for v in out]


def unknown_cm() -> list[int]:
    """72 unknown bins (stale or missing data)."""
    return [UNKNOWN_CM] * 72


@dataclass(frozen=True)
class DistanceSensorHead:
    """A head seen as a DISTANCE_SENSOR: its orientation, field of view and id.

    Args:
        rig: The rig of the head's depth maps.
        mount: The head's mount (its orientation must have an enum value; the config loader
            checks this when DISTANCE_SENSOR is on).
        sensor_id: The sensor id (the head's index).
    """

    rig: RectifiedRig
    mount: Mount
    sensor_id: int

    def reading_cm(self, scan: SectorScan, min_cm: int, max_cm: int) -> int | None:
        """The head's nearest obstacle in its own field of view, in centimetres.

        Returns:
            The nearest finite bin clamped into ``[min_cm, max_cm]``; ``max_cm + 1`` (out of
            range) when every bin of the field of view is clear; None when some bin is
            unknown and none holds an obstacle, because then nothing can be vouched for.
        """
        own = scan.distance_m[covered_bins(self.rig, self.mount)]
        finite = own[np.isfinite(own)]
        if finite.size:
            return int(np.clip(np.rint(float(finite.min()) * 100.0), min_cm, max_cm))
        if own.size and np.isposinf(own).all():
            return max_cm + 1
        return None

    def message(
        self,
        codec: Codec,
        time_boot_ms: int,
        current_cm: int,
        min_cm: int,
        max_cm: int,
        valid_fraction: float,
    ) -> Message:
        """The DISTANCE_SENSOR for a reading.

        The orientation is the enum value of the mount and the quaternion the mount itself;
        the signal quality is the share of pixels with a measurement, as 1 (worst) to 100
        (0 would mean unknown).
        """
        orientation = sensor_orientation(self.mount)
        if orientation is None:
            raise ValueError(f"mount {self.mount} has no MAV_SENSOR_ORIENTATION")
        vertical_fov = 2.0 * math.atan(self.rig.height / (2.0 * self.rig.fy))
        return codec.distance_sensor(
            time_boot_ms,
            min_cm,
            max_cm,
            current_cm,
            orientation,
            horizontal_fov_rad=math.radians(self.rig.hfov_deg),
            vertical_fov_rad=vertical_fov,
            quaternion=mount_quaternion(self.mount),
            signal_quality=max(1, min(100, round(100.0 * valid_fraction))),
            sensor_id=self.sensor_id,
        )


def nearest_points(scan: SectorScan, count: int) -> list[FloatArray]:
    """The body-frame points of the ``count`` nearest finite bins of a scan, nearest first."""
    if scan.points_frd_m is None:
        return []
    distance = np.where(np.isfinite(scan.distance_m), scan.distance_m, np.inf)
    order = np.argsort(distance, kind="stable")[:count]
    return [
        scan.points_frd_m[i]
        for i in order
        if np.isfinite(distance[i]) and np.all(np.isfinite(scan.points_frd_m[i]))
    ]
