"""A point-mass multirotor: velocity control with acceleration, jerk and tilt limits, wind.

The vehicle follows a velocity and yaw-rate command through a PI velocity loop (as an
autopilot's position controller does); the acceleration it asks for is limited in size (by the
maximum acceleration and by the tilt limit) and in how fast it may change (jerk). Its attitude
is what producing that acceleration takes: the thrust tilts toward it. Wind pushes through
drag. Reported position and attitude can carry noise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

GRAVITY_M_S2 = 9.81


@dataclass(frozen=True)
class VehicleLimits:
    """How hard the vehicle can manoeuvre.

    Attributes:
        max_accel_m_s2: Horizontal acceleration limit.
        max_jerk_m_s3: How fast the acceleration may change.
        max_tilt_deg: Tilt limit (also bounds the horizontal acceleration).
        max_climb_m_s2: Vertical acceleration limit.
        velocity_gain: P gain of the velocity loop (1/s).
        integral_gain: I gain of the velocity loop (1/s^2).
        drag_per_s: Air drag, acceleration per m/s of airspeed.
    """

    max_accel_m_s2: float = 4.0
    max_jerk_m_s3: float = 20.0
    max_tilt_deg: float = 30.0
    max_climb_m_s2: float = 3.0
    velocity_gain: float = 2.5
    integral_gain: float = 0.8
    drag_per_s: float = 0.3


@dataclass
class VehicleState:
    """Where the vehicle is and how it moves (local NED)."""

    position_m: np.ndarray = field(default_factory=lambda: np.zeros(3))
    velocity_m_s: np.ndarray = field(default_factory=lambda: np.zeros(3))
    accel_m_s2: np.ndarray = field(default_factory=lambda: np.zeros(3))
    yaw_rad: float = 0.0
    yaw_rate_rad_s: float = 0.0

    @property
    def altitude_m(self) -> float:
        """Height above the origin."""
        return -float(self.position_m[2])

    def roll_pitch_rad(self) -> tuple[float, float]:
        """The attitude that produces the current acceleration (thrust tilted toward it)."""
        an, ae, ad = (float(v) for v in self.accel_m_s2)
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        forward, right = an * c + ae * s, -an * s + ae * c
        lift = GRAVITY_M_S2 - ad
        pitch = math.atan2(-forward, lift)
        roll = math.atan2(right * math.cos(pitch), lift)
        return roll, pitch


@dataclass
class Multirotor:
    """The simulated vehicle.

    Args:
        limits: Its limits and loop gains.
        state: Its initial state.
        wind_m_s: Steady wind, north and east.
    """

    limits: VehicleLimits = field(default_factory=VehicleLimits)
    state: VehicleState = field(default_factory=VehicleState)
    wind_m_s: tuple[float, float] = (0.0, 0.0)
    _integral: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def step(self, dt_s: float, velocity_cmd: np.ndarray, yaw_rate_cmd: float) -> None:
        """Advance by ``dt_s`` following a velocity (NED) and yaw-rate command."""
        limits, state = self.limits, self.state
        error = np.asarray(velocity_cmd, dtype=np.float64) - state.velocity_m_s
        self._integral = np.clip(self._integral + error * dt_s, -2.0, 2.0)
        wanted = limits.velocity_gain * error + limits.integral_gain * self._integral
        wind = np.array([self.wind_m_s[0], self.wind_m_s[1], 0.0])
        drag = limits.drag_per_s * (wind - state.velocity_m_s)
        horizontal_limit = min(
            limits.max_accel_m_s2, GRAVITY_M_S2 * math.tan(math.radians(limits.max_tilt_deg))
        )
        size = math.hypot(wanted[0], wanted[1])
        if size > horizontal_limit:
            wanted[:2] *= horizontal_limit / size
        wanted[2] = max(-limits.max_climb_m_s2, min(limits.max_climb_m_s2, wanted[2]))
        change = wanted - state.accel_m_s2
        step = limits.max_jerk_m_s3 * dt_s
        length = float(np.linalg.norm(change))
        if length > step:
            change *= step / length
        state.accel_m_s2 = state.accel_m_s2 + change
        acceleration = state.accel_m_s2 + drag
        state.position_m = (
            state.position_m + state.velocity_m_s * dt_s + 0.5 * acceleration * dt_s**2
        )
        state.velocity_m_s = state.velocity_m_s + acceleration * dt_s
        if state.position_m[2] > 0.0:  # on the ground
            state.position_m[2] = 0.0
            state.velocity_m_s[2] = min(state.velocity_m_s[2], 0.0)
        state.yaw_rate_rad_s = yaw_rate_cmd
        state.yaw_rad = math.remainder(state.yaw_rad + yaw_rate_cmd * dt_s, 2 * math.pi)
