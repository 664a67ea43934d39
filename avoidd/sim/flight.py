"""The simulated autopilot's rules: modes, GUIDED and OFFBOARD velocity, simple avoidance.

The rules that matter to avoidd are the real autopilots' (see docs/mavlink.md):

- ArduPilot GUIDED takes velocity setpoints and, after ``GUID_TIMEOUT`` (3 s) without one,
  stops and holds; simple avoidance (``AVOID_ENABLE``, ``AVOID_MARGIN``) limits the velocity
  toward every proximity reading with the square-root law of ``AC_Avoid``
  (``sqrt_controller``: ``kP d`` near, ``sqrt(2 a (d - a / 2 kP^2))`` beyond, with
  ``d = distance - margin``, kP 1, a 1 m/s^2), in LOITER and GUIDED alike;
- PX4 OFFBOARD engages only after a setpoint stream above 2 Hz for more than a second, and
  falls back to holding in Position mode after ``COM_OF_LOSS_T`` (1 s) without one;
- modes that do not take setpoints fly the pilot's sticks (here: hold still).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from avoidd.types import SECTOR_WIDTH_DEG

GUIDED_TIMEOUT_NS = 3_000_000_000
OFFBOARD_LOSS_NS = 1_000_000_000
OFFBOARD_PRESTREAM_NS = 1_000_000_000
OFFBOARD_MIN_RATE_HZ = 2.0
PROXIMITY_TIMEOUT_NS = 500_000_000
AVOID_KP = 1.0
AVOID_ACCEL_M_S2 = 1.0

_TAKES_SETPOINTS = {"ardupilot": {"GUIDED"}, "px4": {"OFFBOARD"}}
_HOLD_MODE = {"ardupilot": "LOITER", "px4": "POSCTL"}


def avoid_speed_m_s(distance_m: float) -> float:
    """ArduPilot's largest speed toward an obstacle ``distance_m`` beyond the margin."""
    if distance_m <= 0.0:
        return 0.0
    knee = AVOID_ACCEL_M_S2 / (AVOID_KP * AVOID_KP)
    if distance_m <= knee:
        return AVOID_KP * distance_m
    return math.sqrt(2.0 * AVOID_ACCEL_M_S2 * (distance_m - knee / 2.0))


def simple_avoidance(
    velocity_ne: np.ndarray, obstacles_ne: np.ndarray, margin_m: float
) -> np.ndarray:
    """Limit a horizontal velocity toward each obstacle point, as ArduPilot's AC_Avoid does.

    Args:
        velocity_ne: Desired velocity, north and east.
        obstacles_ne: (N, 2) obstacle points relative to the vehicle.
        margin_m: ``AVOID_MARGIN``.

    Returns:
        The limited velocity.
    """
    velocity = np.asarray(velocity_ne, dtype=np.float64).copy()
    for point in obstacles_ne:
        distance = float(np.hypot(point[0], point[1]))
        if distance <= 1e-6:
            continue
        toward = point / distance
        speed_toward = float(velocity @ toward)
        limit = avoid_speed_m_s(distance - margin_m)
        if speed_toward > limit:
            velocity += toward * (limit - speed_toward)
    return velocity


@dataclass
class SimAutopilot:
    """The simulated autopilot's state and rules.

    Attributes:
        flavour: ``ardupilot`` or ``px4``.
        mode: Current flight mode.
        armed: Whether the motors run.
        avoid_margin_m: ArduPilot's ``AVOID_MARGIN`` (0: simple avoidance off).
    """

    flavour: str = "ardupilot"
    mode: str = "GUIDED"
    armed: bool = True
    avoid_margin_m: float = 0.0
    _setpoint: tuple[np.ndarray, float] | None = None
    _setpoint_ns: int = -(10**18)
    _setpoint_times: deque[int] = field(default_factory=lambda: deque(maxlen=64))
    _proximity: np.ndarray | None = None
    _proximity_ns: int = -(10**18)
    mode_changes: list[tuple[int, str]] = field(default_factory=list)

    @property
    def takes_setpoints(self) -> bool:
        """Whether the current mode flies external setpoints."""
        return self.mode in _TAKES_SETPOINTS[self.flavour]

    def set_mode(self, mode: str, now_ns: int) -> bool:
        """Switch mode; PX4 refuses OFFBOARD without a setpoint stream first."""
        if self.flavour == "px4" and mode == "OFFBOARD" and not self._streaming(now_ns):
            return False
        self.mode = mode
        self.mode_changes.append((now_ns, mode))
        return True

    def _streaming(self, now_ns: int) -> bool:
        """More than 2 Hz of setpoints for more than a second, up to now."""
        times = [t for t in self._setpoint_times if now_ns - t <= 2 * OFFBOARD_PRESTREAM_NS]
        if not times or now_ns - times[-1] > OFFBOARD_LOSS_NS / 2:
            return False
        span = times[-1] - times[0]
        if span < OFFBOARD_PRESTREAM_NS:
            return False
        return (len(times) - 1) / (span / 1e9) > OFFBOARD_MIN_RATE_HZ

    def setpoint(self, velocity_ned: np.ndarray, yaw_rate_rad_s: float, now_ns: int) -> None:
        """A velocity setpoint arrives (SET_POSITION_TARGET_LOCAL_NED)."""
        self._setpoint = (np.asarray(velocity_ned, dtype=np.float64), float(yaw_rate_rad_s))
        self._setpoint_ns = now_ns
        self._setpoint_times.append(now_ns)

    def proximity(self, scan_cm: np.ndarray | None, now_ns: int) -> None:
        """An OBSTACLE_DISTANCE arrives (72 body bins in cm, avoidd's order), or none."""
        if scan_cm is not None:
            self._proximity = scan_cm
            self._proximity_ns = now_ns

    def command(self, now_ns: int, yaw_rad: float, max_cm: int = 2000) -> tuple[np.ndarray, float]:
        """The velocity (NED) and yaw rate the autopilot flies now."""
        hold = (np.zeros(3), 0.0)
        if not self.armed:
            return hold
        lost = now_ns - self._setpoint_ns > OFFBOARD_LOSS_NS
        if self.flavour == "px4" and self.mode == "OFFBOARD" and lost:
            self.set_mode(_HOLD_MODE["px4"], now_ns)  # failsafe: hold in Position mode
            return hold
        if not self.takes_setpoints or self._setpoint is None:
            return hold
        if self.flavour == "ardupilot" and now_ns - self._setpoint_ns > GUIDED_TIMEOUT_NS:
            return hold
        velocity, yaw_rate = self._setpoint
        velocity = velocity.copy()
        if self.flavour == "ardupilot" and self.avoid_margin_m > 0:
            velocity[:2] = simple_avoidance(
                velocity[:2], self._proximity_points(now_ns, yaw_rad, max_cm), self.avoid_margin_m
            )
        return velocity, yaw_rate

    def _proximity_points(self, now_ns: int, yaw_rad: float, max_cm: int) -> np.ndarray:
        scan = self._proximity
        if scan is None or now_ns - self._proximity_ns > PROXIMITY_TIMEOUT_NS:
            return np.empty((0, 2))
        valid = (scan > 0) & (scan <= max_cm)
        index = np.flatnonzero(valid)
        bearing = yaw_rad + np.radians(index * SECTOR_WIDTH_DEG)
        distance = scan[index] / 100.0
        return np.stack([distance * np.cos(bearing), distance * np.sin(bearing)], axis=1)
