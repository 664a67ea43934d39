"""The simulated vehicle as an autopilot on a MAVLink link, in real time.

:class:`SimulatedAutopilot` is the mock autopilot (:mod:`avoidd.mavlink.mock_autopilot`: real
MAVLink bytes, heartbeats, requested streams, command acknowledgements, signing) whose vehicle
flies: a :class:`~avoidd.sim.vehicle.Multirotor` stepped at 100 Hz on the wall clock under the
rules of :class:`~avoidd.sim.flight.SimAutopilot` (modes, arming, take-off, landing, GUIDED and
OFFBOARD setpoints, ArduPilot's simple avoidance on the OBSTACLE_DISTANCE it hears). What it
streams (ATTITUDE, LOCAL_POSITION_NED, a downward DISTANCE_SENSOR) is the simulated state, all
stamped with one boot clock. avoidd's daemon talks to it exactly as to ArduPilot or PX4.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from pymavlink import mavutil

from avoidd.mavlink import codec as mav
from avoidd.mavlink.geo import GlobalPoint, offset_lat_lon
from avoidd.mavlink.mock_autopilot import MockAutopilot, Recorded
from avoidd.sim.flight import SimAutopilot
from avoidd.sim.vehicle import Multirotor
from avoidd.types import SECTOR_COUNT, SECTOR_WIDTH_DEG

PHYSICS_STEP_S = 0.01
"""Simulation step: 100 Hz, paced by the wall clock."""

_DO_SET_MODE = 176
_ARM_DISARM = 400
_NAV_TAKEOFF = 22
_NAV_LAND = 21
_POSITION_IGNORED = 0x0007
_VELOCITY_IGNORED = 0x0038


def scan_from_message(message: mav.Message) -> np.ndarray:
    """An OBSTACLE_DISTANCE in avoidd's 72 body bins (cm; 65535 where nothing was said).

    Each message bin lands on the five-degree bins its angle covers (``angle_offset`` and
    ``increment_f`` as the message definition has them), so both autopilot layouts read back.
    """
    scan = np.full(SECTOR_COUNT, 65535, dtype=np.int64)
    increment = float(message.increment_f) or float(message.increment)
    if increment <= 0.0:
        return scan
    offset = float(message.angle_offset)
    for j, distance in enumerate(message.distances):
        if distance == 65535 or distance == 0:
            continue
        covered = max(1, round(increment / SECTOR_WIDTH_DEG))
        first = round((offset + j * increment) / SECTOR_WIDTH_DEG)
        for k in range(covered):
            index = (first + k) % SECTOR_COUNT
            scan[index] = min(int(scan[index]), int(distance))
    return scan


@dataclass
class SimulatedAutopilot(MockAutopilot):
    """A mock autopilot whose vehicle flies (see the module docstring).

    Attributes:
        vehicle: The simulated multirotor (its state is what the autopilot reports).
        rules: The autopilot's rules (modes, setpoints, simple avoidance).
        on_step: Called after every physics step with the time in ns (collision checks).
        position_noise_m: Standard deviation of the noise on the reported position (an
            estimator's jitter; 0: exact).
        attitude_noise_rad: Standard deviation of the noise on the reported roll, pitch, yaw.
        noise_seed: Seed of that noise.
    """

    vehicle: Multirotor = field(default_factory=Multirotor)
    rules: SimAutopilot = field(default_factory=SimAutopilot)
    on_step: Callable[[int], None] | None = None
    position_noise_m: float = 0.0
    attitude_noise_rad: float = 0.0
    noise_seed: int = 0

    def __post_init__(self) -> None:
        self.rules.flavour = self.flavour
        if self.mode:
            self.rules.mode = self.mode
        self.rules.armed = self.armed
        super().__post_init__()
        self.mode = self.rules.mode
        self._physics: asyncio.Task[None] | None = None
        self._noise = np.random.default_rng(self.noise_seed)
        self._attitude_rad = (0.0, 0.0, self.vehicle.state.yaw_rad)

    # --- what it reports ---------------------------------------------------------------------

    def _sync(self) -> None:
        """The heartbeat's mode and armed state follow the rules' (a landing disarms)."""
        self.mode = self.rules.mode
        self.armed = self.rules.armed

    def stream_message(self, msg_id: int) -> mav.Message | None:
        """ATTITUDE, LOCAL_POSITION_NED, GLOBAL_POSITION_INT, DISTANCE_SENSOR of the state."""
        state = self.vehicle.state
        t_ms = self.boot_ms()
        name = mav.message_name(msg_id)
        if name == "ATTITUDE":
            roll, pitch = state.roll_pitch_rad()
            roll, pitch, yaw = self._noisy((roll, pitch, state.yaw_rad), self.attitude_noise_rad)
            yaw = math.remainder(yaw, math.tau)
            rate = state.yaw_rate_rad_s
            return self.codec.build("ATTITUDE", t_ms, roll, pitch, yaw, 0.0, 0.0, rate)
        if name == "LOCAL_POSITION_NED":
            position = (float(v) for v in state.position_m)
            north, east, down = self._noisy(tuple(position), self.position_noise_m)
            vn, ve, vd = (float(v) for v in state.velocity_m_s)
            return self.codec.build("LOCAL_POSITION_NED", t_ms, north, east, down, vn, ve, vd)
        if name == "GLOBAL_POSITION_INT" and self.origin is not None:
            return self._global_position(t_ms)
        if name == "DISTANCE_SENSOR":
            height_cm = max(1, round(state.altitude_m * 100))
            return self.codec.distance_sensor(
                t_ms, 10, 4000, min(height_cm, 4000), mav.MAV_SENSOR_ROTATION_PITCH_270, 100
            )
        return super().stream_message(msg_id)

    def _global_position(self, t_ms: int) -> mav.Message:
        """GLOBAL_POSITION_INT of the simulated state around the origin (what a map shows)."""
        assert self.origin is not None
        state = self.vehicle.state
        north, east = float(state.position_m[0]), float(state.position_m[1])
        lat_deg, lon_deg = offset_lat_lon(GlobalPoint(*self.origin), north, east)
        vn, ve, vd = (round(float(v) * 100) for v in state.velocity_m_s)
        heading_cdeg = round(math.degrees(state.yaw_rad) % 360.0 * 100) % 36000
        return self.codec.build(
            "GLOBAL_POSITION_INT",
            t_ms,
            round(lat_deg * 1e7),
            round(lon_deg * 1e7),
            round((self.origin[2] + state.altitude_m) * 1000),
            round((state.altitude_m - self.home_up_m) * 1000),
            vn,
            ve,
            vd,
            heading_cdeg,
        )

    def _noisy(self, values: tuple[float, ...], std: float) -> tuple[float, ...]:
        if std <= 0.0:
            return values
        return tuple(
            float(v) for v in np.asarray(values) + self._noise.normal(0.0, std, len(values))
        )

    # --- what it hears -----------------------------------------------------------------------

    def _on_bytes(self, data: bytes) -> None:
        now_ns = time.monotonic_ns()
        for message in self.codec.decode(data):
            kind = message.get_type()
            if kind == "SET_POSITION_TARGET_LOCAL_NED" and self._for_me(message):
                self._on_position_target(message, now_ns)
            elif kind == "OBSTACLE_DISTANCE":
                self.rules.proximity(scan_from_message(message), now_ns)
            self.recorded.append(Recorded(now_ns, message))
            self.counts[kind] += 1
            if kind == "COMMAND_LONG":
                self._on_command(message)
            elif kind in ("MISSION_REQUEST_LIST", "MISSION_REQUEST_INT"):
                self._on_mission_request(message)

    def _for_me(self, message: mav.Message) -> bool:
        return message.target_system in (0, self.system_id) and message.target_component in (
            0,
            mav.MAV_COMP_ID_AUTOPILOT1,
        )

    def _on_position_target(self, message: mav.Message, now_ns: int) -> None:
        if message.coordinate_frame != mav.MAV_FRAME_LOCAL_NED:
            return
        mask = int(message.type_mask)
        if not mask & _POSITION_IGNORED:
            self.rules.position_setpoint(np.array([message.x, message.y, message.z]), now_ns)
        elif not mask & _VELOCITY_IGNORED:
            velocity = np.array([message.vx, message.vy, message.vz])
            yaw_rate = 0.0 if mask & 0x0800 else float(message.yaw_rate)
            self.rules.setpoint(velocity, yaw_rate, now_ns)

    def _on_command(self, message: mav.Message) -> None:
        command = int(message.command)
        if command not in (_DO_SET_MODE, _ARM_DISARM, _NAV_TAKEOFF, _NAV_LAND) or not self._for_me(
            message
        ):
            super()._on_command(message)
            return
        now_ns = time.monotonic_ns()
        accepted = False
        if command == _DO_SET_MODE:
            mode = self._mode_named(message)
            accepted = mode is not None and self.rules.set_mode(mode, now_ns)
        elif command == _ARM_DISARM:
            accepted = self.rules.arm(message.param1 > 0.5, now_ns)
        elif command == _NAV_TAKEOFF:
            accepted = self.rules.takeoff(float(message.param7), now_ns)
        elif command == _NAV_LAND:
            accepted = self.rules.set_mode(
                "LAND" if self.flavour == "ardupilot" else "AUTO.LAND", now_ns
            )
        self._sync()
        result = mav.MAV_RESULT_ACCEPTED if accepted else mav.MAV_RESULT_DENIED
        to = (message.get_srcSystem(), message.get_srcComponent())
        self.send(self.codec.build("COMMAND_ACK", command, result, 0, 0, *to))

    def _mode_named(self, message: mav.Message) -> str | None:
        """The mode a MAV_CMD_DO_SET_MODE asks for, by the autopilot's own numbering."""
        if self.flavour == "px4":
            wanted = (int(message.param1), int(message.param2), int(message.param3))
            for name, (base, main, sub) in mavutil.px4_map.items():
                if (main, sub) == wanted[1:] and base & wanted[0]:
                    return str(name)
            return None
        names = mavutil.mode_mapping_byname(self.vehicle_type) or {}
        return next((str(n) for n, number in names.items() if number == int(message.param2)), None)

    # --- running -----------------------------------------------------------------------------

    async def start(self, connection: str) -> None:
        """Open the link, start streaming and start the physics."""
        await super().start(connection)
        self._physics = asyncio.create_task(self._fly(), name="sim-physics")

    async def _fly(self) -> None:
        next_s = time.monotonic()
        while True:
            now_ns = time.monotonic_ns()
            state = self.vehicle.state
            velocity, yaw_rate = self.rules.command(
                now_ns,
                state.yaw_rad,
                position_ned=state.position_m,
                velocity_ned=state.velocity_m_s,
            )
            self.vehicle.step(PHYSICS_STEP_S, velocity, yaw_rate)
            self._sync()
            if self.on_step is not None:
                self.on_step(now_ns)
            next_s += PHYSICS_STEP_S
            delay_s = next_s - time.monotonic()
            if delay_s < -0.1:
                next_s = time.monotonic()  # far behind (a busy machine): no burst of steps
            await asyncio.sleep(max(0.0, delay_s))

    async def stop(self) -> None:
        """Stop the physics, then the link."""
        if self._physics is not None:
            self._physics.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._physics
            self._physics = None
        await super().stop()
