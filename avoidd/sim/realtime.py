"""A scenario in real time: avoidd's daemon against the simulated vehicle on a MAVLink link.

The lockstep loop (:mod:`avoidd.sim.lockstep`) runs avoidd's pipeline and planner as
functions, deterministically. This runs the whole daemon instead, as it runs on a drone: its
UDP link, its vehicle state from the autopilot's streams, its output loops and setpoint loop,
talking to :class:`~avoidd.sim.mav_autopilot.SimulatedAutopilot` over loopback, with the camera
rendered from the pose the autopilot reports. It is not deterministic (the wall clock paces
both sides); it shows that what the lockstep loop measured holds for the real process.
"""

from __future__ import annotations

import asyncio
import math
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from avoidd.config.sim import ActionConfig, ScenarioConfig
from avoidd.config.sources import SourceConfig
from avoidd.daemon import Daemon
from avoidd.mavlink import codec as mav
from avoidd.sim.external import HOME, ExternalRun, ExternalSummary, daemon_config
from avoidd.sim.flight import SimAutopilot
from avoidd.sim.mav_autopilot import SimulatedAutopilot
from avoidd.sim.pose_source import UnpluggableSource
from avoidd.sim.vehicle import Multirotor, VehicleState
from avoidd.sources.base import FrameSource
from avoidd.types import RectifiedRig
from avoidd.vision.calibration import Calibration

_OFFBOARD_TRY_S = 0.5


class RealtimeRun(ExternalRun):
    """One scenario: the daemon against the simulated autopilot, in real time.

    Args:
        scenario: The scenario (world, start, goal, timeline, pass criteria).
    """

    def __init__(self, scenario: ScenarioConfig) -> None:
        super().__init__(scenario, Path("."), mode="planner")
        start = scenario.start
        # The autopilot's local frame is the world's: the vehicle starts where the scenario
        # says, in the air, armed, in the mode that flies setpoints (PX4: Position mode first;
        # OFFBOARD is entered once avoidd streams, as a ground station would).
        self.offset_ne_m = (0.0, 0.0)
        flavour = scenario.autopilot
        avoidance = scenario.avoidance
        self.autopilot = SimulatedAutopilot(
            flavour=flavour,
            mode="GUIDED" if flavour == "ardupilot" else "POSCTL",
            armed=True,
            origin=HOME,
            vehicle=Multirotor(
                state=VehicleState(
                    position_m=np.array([start.north_m, start.east_m, -start.altitude_m]),
                    yaw_rad=math.radians(start.yaw_deg),
                ),
                wind_m_s=scenario.wind_m_s,
            ),
            rules=SimAutopilot(
                flavour=flavour,
                avoid_margin_m=min(avoidance.margin_m, 2.0) if flavour == "ardupilot" else 0.0,
            ),
        )
        self._plugged = [True]

    async def run(self, port: int) -> ExternalSummary:
        """Run the scenario for its duration; the summary (judged by its criteria)."""
        config = daemon_config(port, self.scenario, planner=True)
        daemon = Daemon(
            config, {"front": Calibration(self.rig, None, Path("sim"))}, open_source=self._open
        )
        self.daemon = daemon
        autopilot = self.autopilot
        await autopilot.start(f"udpout:127.0.0.1:{port}")
        task = asyncio.create_task(daemon.run(), name="avoidd")
        try:
            await self._wait_link(10.0)
            # The goal comes over MAVLink once the link is up, as a ground station gives it: a
            # goal avoidd already has when it first sees PX4 armed in another mode does not
            # prestream (someone else flies it; see the avoidance loop).
            self._send_goal(*self.goal)
            if self.autopilot.rules.flavour == "px4":
                # A pilot switches to OFFBOARD once the companion streams (its first scans
                # take longer on a loaded machine): the timeline starts from there.
                await self._wait_setpoints(20.0)
            self._t0_ns = time.monotonic_ns()
            autopilot.on_step = self._on_step
            await self._play()
        finally:
            autopilot.on_step = None
            await daemon.stop_and_wait(task)
            await autopilot.stop()
        self._judge()
        return self.summary

    def _open(
        self,
        config: SourceConfig,
        rig: RectifiedRig,
        head: str,
        paced: bool,
        input_path: Path | None = None,
    ) -> FrameSource:
        return UnpluggableSource(self._camera(config, rig, head, paced, input_path), self._plugged)

    async def _wait_link(self, timeout_s: float) -> None:
        daemon = self.daemon
        assert daemon is not None
        deadline = time.monotonic() + timeout_s
        while not daemon.vehicle.link_up and time.monotonic() < deadline:
            await asyncio.sleep(0.05)

    async def _wait_setpoints(self, timeout_s: float) -> None:
        """Until avoidd sends setpoints (PX4: its prestream), at most ``timeout_s``."""
        daemon = self.daemon
        assert daemon is not None
        deadline = time.monotonic() + timeout_s
        while daemon.sent["SET_POSITION_TARGET_LOCAL_NED"] == 0 and time.monotonic() < deadline:
            await asyncio.sleep(0.05)

    def _on_step(self, now_ns: int) -> None:
        """After every physics step: measure the vehicle against the world (10 Hz samples)."""
        state = self.autopilot.vehicle.state
        samples = self.summary.samples
        if samples and now_ns - self._t0_ns < (samples[-1].t_s + 0.1) * 1e9:
            return
        north, east, down = (float(v) for v in state.position_m)
        vn, ve = float(state.velocity_m_s[0]), float(state.velocity_m_s[1])
        self._measure(SimpleNamespace(x=north, y=east, z=down, vx=vn, vy=ve))

    async def _play(self) -> None:
        """The timeline, and PX4's switch to OFFBOARD once avoidd streams, until the end."""
        timeline = sorted(self.scenario.timeline, key=lambda a: a.time_s)
        rules = self.autopilot.rules
        end_ns = self._t0_ns + int(self.scenario.duration_s * 1e9)
        wants_offboard = rules.flavour == "px4" and not any(a.action == "mode" for a in timeline)
        while time.monotonic_ns() < end_ns:
            now_ns = time.monotonic_ns()
            t_s = (now_ns - self._t0_ns) / 1e9
            while timeline and timeline[0].time_s <= t_s:
                self._act(timeline.pop(0), now_ns)
            if wants_offboard and rules.mode != "OFFBOARD" and rules.set_mode("OFFBOARD", now_ns):
                wants_offboard = False
            if self.summary.collided:
                break
            await asyncio.sleep(_OFFBOARD_TRY_S if wants_offboard else 0.05)

    def _act(self, action: ActionConfig, now_ns: int) -> None:
        rules = self.autopilot.rules
        kind = action.action
        if kind == "mode" and action.mode is not None:
            rules.set_mode(action.mode, now_ns)
        elif kind == "disarm":
            rules.arm(False, now_ns)
        elif kind == "camera_unplug":
            self._plugged[0] = False
        elif kind == "camera_replug":
            self._plugged[0] = True
        elif kind == "goal":
            goal = action.goal
            if goal is not None:
                self.goal = (goal.north_m, goal.east_m, goal.altitude_m)
                self._send_goal(goal.north_m, goal.east_m, goal.altitude_m)

    def _send_goal(self, north_m: float, east_m: float, altitude_m: float) -> None:
        """A new goal for avoidd, as the vehicle's own system sends one (to component 196)."""
        autopilot = self.autopilot
        target = (autopilot.system_id, mav.MAV_COMP_ID_OBSTACLE_AVOIDANCE, mav.MAV_FRAME_LOCAL_NED)
        position = (north_m, east_m, -altitude_m, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        message = autopilot.codec.build(
            "SET_POSITION_TARGET_LOCAL_NED", autopilot.boot_ms(), *target, 0x0FF8, *position
        )
        autopilot.send(message)
