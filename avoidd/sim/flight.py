"""The simulated autopilot's rules: modes, GUIDED and OFFBOARD velocity, simple avoidance.

The rules that matter to avoidd are the real autopilots' (see docs/mavlink.md):

- ArduPilot GUIDED takes velocity setpoints and, after ``GUID_TIMEOUT`` (3 s) without one,
  stops and holds; simple avoidance (``AVOID_ENABLE``, ``AVOID_MARGIN``) limits the velocity
  toward every proximity reading with the square-root law of ``AC_Avoid``
  (``sqrt_controller``: ``kP d`` near, ``sqrt(2 a (d - a / 2 kP^2))`` beyond, with
  ``d = distance - margin``, kP 1, a 1 m/s^2), in LOITER and GUIDED alike;
- PX4 OFFBOARD engages only after a setpoint stream above 2 Hz for more than a second, and
  falls back to holding in Position mode after ``COM_OF_LOSS_T`` (1 s) without one;
- modes that do not take setpoints fly the pilot's sticks, and nobody is at the sticks: LOITER
  and PX4's Position mode hold still, STABILIZE levels the vehicle without braking (it coasts),
  LAND descends at 0.5 m/s and disarms on the ground;
- arming (ArduPilot: in STABILIZE, ALT_HOLD, LOITER or GUIDED; PX4: not in OFFBOARD) and
  ``MAV_CMD_NAV_TAKEOFF`` in GUIDED (climb at 1 m/s to the altitude, then hold), and GUIDED
  position targets (flown at up to 5 m/s, slowing in the last metres).
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
_ARMABLE = {
    "ardupilot": {"STABILIZE", "ALT_HOLD", "LOITER", "GUIDED"},
    "px4": {"POSCTL", "ALTCTL", "MANUAL", "STABILIZED"},
}
_LAND_MODES = {"LAND", "AUTO.LAND"}
LAND_SPEED_M_S = 0.5
TAKEOFF_CLIMB_M_S = 1.0
POSITION_SPEED_M_S = 5.0
LANDED_BELOW_M = 0.05


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
        failsafe: PX4's offboard-loss fallback is in effect (its HEARTBEAT says CRITICAL
            until the pilot picks a mode).
    """

    flavour: str = "ardupilot"
    mode: str = "GUIDED"
    armed: bool = True
    avoid_margin_m: float = 0.0
    failsafe: bool = False
    _setpoint: tuple[np.ndarray, float] | None = None
    _setpoint_ns: int = -(10**18)
    _setpoint_times: deque[int] = field(default_factory=lambda: deque(maxlen=64))
    _proximity: np.ndarray | None = None
    _proximity_ns: int = -(10**18)
    _takeoff_alt_m: float | None = None
    _position_target: np.ndarray | None = None
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
        self.failsafe = False
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

    def arm(self, arm: bool, now_ns: int) -> bool:
        """Arm or disarm (``MAV_CMD_COMPONENT_ARM_DISARM``); False when the mode refuses."""
        if arm and self.mode not in _ARMABLE[self.flavour]:
            return False
        self.armed = arm
        if not arm:
            self._takeoff_alt_m = None
        return True

    def takeoff(self, altitude_m: float, now_ns: int) -> bool:
        """``MAV_CMD_NAV_TAKEOFF``: in ArduPilot's GUIDED, armed; climb to ``altitude_m``."""
        if not (self.armed and self.mode == "GUIDED" and 0.5 <= altitude_m <= 500.0):
            return False
        self._takeoff_alt_m = altitude_m
        self._position_target = None
        return True

    def setpoint(self, velocity_ned: np.ndarray, yaw_rate_rad_s: float, now_ns: int) -> None:
        """A velocity setpoint arrives (SET_POSITION_TARGET_LOCAL_NED)."""
        self._setpoint = (np.asarray(velocity_ned, dtype=np.float64), float(yaw_rate_rad_s))
        self._setpoint_ns = now_ns
        self._setpoint_times.append(now_ns)
        self._position_target = None
        self._takeoff_alt_m = None

    def position_setpoint(self, position_ned: np.ndarray, now_ns: int) -> None:
        """A position target arrives (SET_POSITION_TARGET_LOCAL_NED with a position)."""
        self._position_target = np.asarray(position_ned, dtype=np.float64)
        self._setpoint_ns = now_ns
        self._setpoint_times.append(now_ns)
        self._takeoff_alt_m = None

    def proximity(self, scan_cm: np.ndarray | None, now_ns: int) -> None:
        """An OBSTACLE_DISTANCE arrives (72 body bins in cm, avoidd's order), or none."""
        if scan_cm is not None:
            self._proximity = scan_cm
            self._proximity_ns = now_ns

    def command(
        self,
        now_ns: int,
        yaw_rad: float,
        max_cm: int = 2000,
        position_ned: np.ndarray | None = None,
        velocity_ned: np.ndarray | None = None,
    ) -> tuple[np.ndarray, float]:
        """The velocity (NED) and yaw rate the autopilot flies now.

        ``position_ned`` and ``velocity_ned`` (the vehicle's) are needed by take-off, landing,
        position targets and STABILIZE; without them those hold.
        """
        hold = (np.zeros(3), 0.0)
        if not self.armed:
            return hold
        if position_ned is not None:
            flown = self._own_flight(now_ns, position_ned, velocity_ned)
            if flown is not None:
                return flown
        lost = now_ns - self._setpoint_ns > OFFBOARD_LOSS_NS
        if self.flavour == "px4" and self.mode == "OFFBOARD" and lost:
            self.set_mode(_HOLD_MODE["px4"], now_ns)  # failsafe: hold in Position mode
            self.failsafe = True
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

    def _own_flight(
        self, now_ns: int, position_ned: np.ndarray, velocity_ned: np.ndarray | None
    ) -> tuple[np.ndarray, float] | None:
        """Landing, take-off, a position target or STABILIZE's coasting; None: the usual rules."""
        altitude_m = -float(position_ned[2])
        if self.mode in _LAND_MODES:
            if altitude_m <= LANDED_BELOW_M:
                self.armed = False  # both autopilots disarm once landed
                return np.zeros(3), 0.0
            return np.array([0.0, 0.0, LAND_SPEED_M_S]), 0.0
        if self.mode == "STABILIZE" and velocity_ned is not None:
            # Level, no braking: the horizontal velocity is left as it is; height held.
            return np.array([float(velocity_ned[0]), float(velocity_ned[1]), 0.0]), 0.0
        if self.mode != "GUIDED":
            return None
        if self._takeoff_alt_m is not None:
            if altitude_m >= self._takeoff_alt_m - 0.1:
                self._takeoff_alt_m = None
                self._position_target = np.array(
                    [position_ned[0], position_ned[1], position_ned[2]]
                )
            else:
                return np.array([0.0, 0.0, -TAKEOFF_CLIMB_M_S]), 0.0
        if self._position_target is not None:
            error = self._position_target - np.asarray(position_ned, dtype=np.float64)
            distance = float(np.linalg.norm(error))
            speed = min(POSITION_SPEED_M_S, distance)  # P gain 1/s: slows in the last metres
            velocity = error / distance * speed if distance > 1e-3 else np.zeros(3)
            return velocity, 0.0
        return None

    def _proximity_points(self, now_ns: int, yaw_rad: float, max_cm: int) -> np.ndarray:
        scan = self._proximity
        if scan is None or now_ns - self._proximity_ns > PROXIMITY_TIMEOUT_NS:
            return np.empty((0, 2))
        valid = (scan > 0) & (scan <= max_cm)
        index = np.flatnonzero(valid)
        bearing = yaw_rad + np.radians(index * SECTOR_WIDTH_DEG)
        distance = scan[index] / 100.0
        return np.stack([distance * np.cos(bearing), distance * np.sin(bearing)], axis=1)
