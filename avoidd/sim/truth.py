"""Where a simulated autopilot's vehicle really is: its physics' ground truth, not its estimate.

An external simulation renders avoidd's camera and judges collisions against the world. Both
must follow the vehicle the physics moves, as a real camera and a real wall do. The
autopilot's estimate is not that: PX4's SIH estimate was seen holding 2.0 m above home while
the simulated vehicle climbed from 1.0 to 2.6 m above the ground in 15 s (its downward
rangefinder, which measures the truth, saw the climb). A camera rendered from the estimate
then shows the ground 0.5 m nearer than the rangefinder places it, and avoidd's ground model,
rightly trusting the rangefinder, took that ground for an obstacle 2 m ahead (PX4's collision
prevention then held the vehicle still with the wall 12 m away).

PX4 streams the truth of its simulation as HIL_STATE_QUATERNION when asked (message 115):
position (latitude, longitude, altitude AMSL), ground velocity and attitude. avoidd's daemon
keeps reading the estimate on its own link, as it would in flight.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

from avoidd.mavlink.geo import GlobalPoint, north_east_m
from avoidd.sim.gcs import GroundStation
from avoidd.sim.pose_source import VehiclePose

TRUTH_MESSAGE = "HIL_STATE_QUATERNION"


@dataclass(frozen=True)
class TruthSample:
    """The vehicle's true state at a time, in the world's frame.

    Attributes:
        pose: Position (down: negative in the air, 0 on the ground of the start) and attitude.
        speed_m_s: Horizontal ground speed.
    """

    pose: VehiclePose
    speed_m_s: float


def euler_from_quaternion(w: float, x: float, y: float, z: float) -> tuple[float, float, float]:
    """Roll, pitch and yaw (radians, aerospace ZYX order) of a unit quaternion."""
    roll_rad = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch_rad = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
    yaw_rad = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return roll_rad, pitch_rad, yaw_rad


class GroundTruth:
    """The simulated vehicle's true pose from the ground station's HIL_STATE_QUATERNION.

    Args:
        gcs: The ground station on the autopilot's link (it keeps the newest of each message).
        offset_ne_m: The world position of the vehicle's start.
        max_age_ns: Truth received longer ago than this is none (the stream stopped).
    """

    def __init__(
        self,
        gcs: GroundStation,
        offset_ne_m: tuple[float, float] = (0.0, 0.0),
        max_age_ns: int = 500_000_000,
    ) -> None:
        self._gcs = gcs
        self._offset_ne_m = offset_ne_m
        self._max_age_ns = max_age_ns
        self._start: GlobalPoint | None = None
        self._start_ne_m = (0.0, 0.0)

    @property
    def anchored(self) -> bool:
        """Whether the start is known (:meth:`anchor` succeeded)."""
        return self._start is not None

    def anchor(self, estimate_ne_m: tuple[float, float] = (0.0, 0.0)) -> bool:
        """Take where the vehicle is now (on the ground at the scenario's start) as the start.

        Args:
            estimate_ne_m: Where the autopilot believes the vehicle is now in its local frame:
                the truth is placed there (plus the start's offset), so that the world stands
                where the autopilot's frame puts it (its origin need not be where the vehicle
                stands: PX4's estimate wanders while it settles, by metres on a loaded machine).

        Returns:
            False when no fresh truth has come yet.
        """
        heard = self._gcs.newest.get(TRUTH_MESSAGE)
        if heard is None or time.monotonic_ns() - heard.received_ns > self._max_age_ns:
            return False
        message = heard.message
        self._start = GlobalPoint(message.lat / 1e7, message.lon / 1e7, message.alt / 1000.0)
        self._start_ne_m = estimate_ne_m
        return True

    def at(self, t_ns: int) -> TruthSample | None:
        """The true state at monotonic ``t_ns``, carried forward from the newest report.

        Returns:
            None before :meth:`anchor`, or when the newest report is older than the limit.
        """
        start = self._start
        heard = self._gcs.newest.get(TRUTH_MESSAGE)
        if start is None or heard is None:
            return None
        age_ns = t_ns - heard.received_ns
        if age_ns > self._max_age_ns:
            return None
        message = heard.message
        dt_s = max(0.0, age_ns / 1e9)
        vn_m_s, ve_m_s, vd_m_s = message.vx / 100.0, message.vy / 100.0, message.vz / 100.0
        north_m, east_m = north_east_m(start, message.lat / 1e7, message.lon / 1e7)
        north_m, east_m = north_m + self._start_ne_m[0], east_m + self._start_ne_m[1]
        up_m = message.alt / 1000.0 - start.alt_m
        roll_rad, pitch_rad, yaw_rad = euler_from_quaternion(*message.attitude_quaternion)
        pose = VehiclePose(
            north_m + vn_m_s * dt_s + self._offset_ne_m[0],
            east_m + ve_m_s * dt_s + self._offset_ne_m[1],
            -up_m + vd_m_s * dt_s,
            yaw_rad,
            roll_rad,
            pitch_rad,
        )
        return TruthSample(pose, math.hypot(vn_m_s, ve_m_s))

    def pose_at(self, t_ns: int) -> VehiclePose | None:
        """The true pose at ``t_ns`` (a :data:`~avoidd.sim.pose_source.PoseNow`)."""
        sample = self.at(t_ns)
        return None if sample is None else sample.pose
