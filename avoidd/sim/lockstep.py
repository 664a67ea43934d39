"""The closed loop in one process, in lockstep: camera, pipeline, planner, autopilot, vehicle.

Simulated time advances in fixed steps; nothing depends on the wall clock, so the same
scenario and seed give the same trace. Each camera frame is rendered (or, with ``oracle``
perception, measured exactly) from the vehicle's pose at its capture time, run through the
head pipeline and its temporal filter, and becomes available to avoidd a fixed latency later.
avoidd's parts are the daemon's own: the gate, the planner, the scan merge; the autopilot is
:class:`~avoidd.sim.flight.SimAutopilot` and the vehicle :class:`~avoidd.sim.vehicle.Multirotor`.
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from avoidd.config import PerceptionConfig
from avoidd.config.sim import ActionConfig, CameraConfig, ScenarioConfig
from avoidd.mavlink.messages import sectors_to_cm
from avoidd.mavlink.track_history import TrackHistory
from avoidd.perception.sectors import covered_bins
from avoidd.planner.core import Decision, Goal
from avoidd.planner.cycle import AutopilotState, CycleInput, PlanningCycle
from avoidd.planner.gating import Gate
from avoidd.sim.flight import SimAutopilot
from avoidd.sim.heads import RIGS, Perceive, SimHead, fresh_merged, mount_of, rig_for
from avoidd.sim.perception import StereoPerception
from avoidd.sim.summary import Summary, Tally, judge
from avoidd.sim.vehicle import Multirotor, VehicleState
from avoidd.sim.world import World
from avoidd.types import LocalPosition, SectorScan

__all__ = ["MAX_RANGE_M", "RIGS", "STEP_S", "LockstepRun", "Row"]

STEP_S = 0.01
LATENCY_S = 0.1
"""From capture to avoidd having the scan (the pipeline's time, fixed so runs repeat)."""
MAX_AGE_NS = 300_000_000
OBSTACLE_DISTANCE_HZ = 15.0
MAX_RANGE_M = 20.0
TRACE_HZ = 10.0
ORACLE_BAND_M = (PerceptionConfig().band.below_m, PerceptionConfig().band.above_m)
"""Below and above the vehicle, the heights the oracle sees obstacles in (the daemon's band)."""


@dataclass
class Row:
    """One line of the trace (every ``1 / TRACE_HZ`` s of simulated time)."""

    t_s: float
    north_m: float
    east_m: float
    altitude_m: float
    yaw_deg: float
    speed_m_s: float
    setpoint: list[float] | None
    gate: str
    state: str
    direction_deg: float | None
    free_m: float | None
    clearance_m: float
    mode: str
    sectors_cm: list[int]


class LockstepRun:
    """One scenario run.

    Args:
        scenario: The scenario.
        world: Its world.
        goal: Where to fly (the scenario's, or the generator's).
        seed: Seed of the sensor noise (a second head's is one more, and so on).
        world_kind: The generator that drew the world (``file``: a world file), for reports.
    """

    def __init__(
        self,
        scenario: ScenarioConfig,
        world: World,
        goal: Goal,
        seed: int = 0,
        world_kind: str = "file",
    ) -> None:
        self.scenario = scenario
        self.world_kind = world_kind
        self.world = world
        self.goal: Goal | None = goal
        self.seed = seed
        avoidance = scenario.avoidance
        self.autopilot = SimAutopilot(
            flavour=scenario.autopilot,
            mode="GUIDED" if scenario.autopilot == "ardupilot" else "POSCTL",
            armed=True,
            avoid_margin_m=min(avoidance.margin_m, 2.0) if scenario.autopilot == "ardupilot" else 0,
        )
        start = scenario.start
        self.vehicle = Multirotor(
            state=VehicleState(
                position_m=np.array([start.north_m, start.east_m, -start.altitude_m]),
                yaw_rad=math.radians(start.yaw_deg),
            ),
            wind_m_s=scenario.wind_m_s,
        )
        self.heads = [self._head(camera, seed + k) for k, camera in enumerate(scenario.cameras)]
        # As the daemon: the top speed is what the rendered cameras can stop for (exact
        # distances see every pole, so they cut nothing).
        thin_m = min(
            (
                head.perceive.pipeline.thin_range_m
                for head in self.heads
                if isinstance(head.perceive, StereoPerception)
            ),
            default=None,
        )
        self.cycle = PlanningCycle(avoidance, MAX_RANGE_M, thin_m)
        self.planner = self.cycle.planner
        self.cycle.new_goal()  # the goal is given before the first cycle
        self.rows: list[Row] = []
        self._latest: tuple[SectorScan, float] | None = None
        """The heads' fresh scans merged, with the yaw at the newest capture (None: stale)."""
        self._track = TrackHistory()
        self.inputs: list[CycleInput] = []
        """Every planning cycle's input, when ``record_inputs``."""
        self.record_inputs = False
        self._decision = Decision((0.0, 0.0, 0.0), 0.0, "waiting")
        self._gate = Gate.SILENT
        self._setpoint: list[float] | None = None
        self._tally = Tally(Summary(scenario.name, seed, scenario.perception), STEP_S)
        self._timeline: list[ActionConfig] = []
        self._triggers: list[ActionConfig] = []
        self._flown_m = 0.0

    # --- perception ------------------------------------------------------------------------

    def _head(self, camera: CameraConfig, seed: int) -> SimHead:
        """A camera's head: its scans rendered and run through the pipeline, or exact."""
        rig, mount = rig_for(self.scenario.resolution, camera.hfov_deg), mount_of(camera)
        perceive: Perceive
        if self.scenario.perception == "stereo":
            perceive = StereoPerception(self.world, rig, mount, MAX_RANGE_M, seed)
        else:
            perceive = functools.partial(self._oracle, covered_bins(rig, mount))
        return SimHead(camera.name, rig, mount, perceive)

    def _oracle(self, covered: npt.NDArray[np.bool_], state: VehicleState, t_ns: int) -> SectorScan:
        north, east, _ = (float(v) for v in state.position_m)
        distance, points = self.world.oracle_scan(
            north,
            east,
            state.altitude_m,
            state.yaw_rad,
            covered,
            MAX_RANGE_M,
            t_s=t_ns / 1e9,
            band_m=ORACLE_BAND_M,
        )
        return SectorScan(t_ns, distance, points)

    def _position(self, t_ns: int) -> LocalPosition:
        """The vehicle's position report now (also kept for the track velocity)."""
        state = self.vehicle.state
        north, east, down = (float(v) for v in state.position_m)
        vn, ve = float(state.velocity_m_s[0]), float(state.velocity_m_s[1])
        self._track.add(t_ns, north, east, vn, ve)
        return LocalPosition(t_ns, north, east, down, vn, ve, float(state.velocity_m_s[2]))

    def fresh_scan(self, now_ns: int) -> SectorScan | None:
        """The fresh heads' newest scans merged (None: no head is fresh)."""
        self._latest = fresh_merged(self.heads, now_ns, MAX_AGE_NS)
        return None if self._latest is None else self._latest[0]

    # --- the loop --------------------------------------------------------------------------

    def run(self) -> Summary:
        """Run the scenario to its end (or a collision) and score it."""
        started = time.perf_counter()
        scenario = self.scenario
        avoidance = scenario.avoidance
        summary = Summary(
            scenario.name,
            self.seed,
            scenario.perception,
            world_kind=self.world_kind,
            speed_limit_m_s=avoidance.max_speed_m_s,
        )
        # The target: radius + margin - 0.1 m in 99 % of steps (edge clearance: margin
        # - 0.1 m, as clearance here is measured from the vehicle's edge).
        summary.clearance_target_m = round(avoidance.margin_m - 0.1, 4)
        self._tally = Tally(summary, STEP_S)
        self._timeline = sorted(
            (a for a in scenario.timeline if a.t_s is not None), key=lambda a: a.time_s
        )
        self._triggers = [a for a in scenario.timeline if a.t_s is None]
        for step in range(round(scenario.duration_s / STEP_S) + 1):
            self._step(step)
            if summary.collided or self._settled(summary, step * STEP_S):
                break
        self._tally.finish(self._decision.state)
        summary.wall_time_s = time.perf_counter() - started
        judge(summary, scenario.passing)
        return summary

    def _settled(self, summary: Summary, t_s: float) -> bool:
        """Whether the run may end: ``end_after_s`` after arrival or the first "no path"."""
        wait_s = self.scenario.end_after_s
        if wait_s is None:
            return False
        if summary.time_to_goal_s is not None:
            return t_s >= summary.time_to_goal_s + wait_s - 1e-9
        no_path_s = self._tally.no_path_t_s
        return no_path_s is not None and t_s >= no_path_s + wait_s - 1e-9

    def _every(self, rate_hz: float) -> int:
        return round(1.0 / (rate_hz * STEP_S))

    def _step(self, step: int) -> None:
        """One time step: timeline, camera, scan delivery, planner, autopilot, vehicle, score."""
        tally = self._tally
        t_s = step * STEP_S
        now_ns = round(t_s * 1e9)
        while self._timeline and self._timeline[0].time_s <= t_s + 1e-9:
            self._act(self._timeline.pop(0), now_ns)
        for action in [a for a in self._triggers if self._reached(a)]:
            self._triggers.remove(action)
            self._act(action, now_ns)
        state = self.vehicle.state
        if step % self._every(self.scenario.fps) == 0 and any(h.on for h in self.heads):
            for head in self.heads:
                head.capture(state, now_ns, round(LATENCY_S * 1e9))
            self._position(now_ns)
        for head in self.heads:
            head.deliver(now_ns)
        fresh = self.fresh_scan(now_ns)
        tally.perception(fresh is not None, now_ns)
        if step % self._every(OBSTACLE_DISTANCE_HZ) == 0:
            self._send_obstacle_distance(fresh, now_ns)
        if step % self._every(self.scenario.avoidance.setpoint_rate_hz) == 0:
            self._gate, self._decision, self._setpoint = self._plan(now_ns, fresh)
            direction = self._decision.direction_deg
            side = None if direction is None or self.goal is None else self._side(direction)
            tally.cycle(t_s, now_ns, self._decision.state, self._gate is Gate.HOLD, side)
        velocity, yaw_rate = self.autopilot.command(now_ns, state.yaw_rad)
        self.vehicle.step(STEP_S, velocity, yaw_rate)
        state = self.vehicle.state
        north, east, _ = (float(v) for v in state.position_m)
        radius = self.scenario.avoidance.vehicle_radius_m
        clearance = self.world.edge_clearance_m(north, east, state.altitude_m, radius, t_s + STEP_S)
        speed = float(np.hypot(state.velocity_m_s[0], state.velocity_m_s[1]))
        self._flown_m += speed * STEP_S
        tally.step(t_s, clearance, speed, self._decision.state)
        if step % self._every(TRACE_HZ) == 0:
            self.rows.append(
                self._row(t_s, self._gate, self._decision, self._setpoint, clearance, fresh)
            )

    def _act(self, action: ActionConfig, now_ns: int) -> None:
        if action.action == "mode":
            assert action.mode is not None  # the model requires it
            self.autopilot.set_mode(action.mode, now_ns)
        elif action.action == "goal":
            g = action.goal
            assert g is not None  # the model requires it
            self.goal = Goal(g.north_m, g.east_m, g.altitude_m)
            self.cycle.new_goal()
            self._tally.goal_given(now_ns / 1e9)
        elif action.action in ("camera_unplug", "camera_replug"):
            for head in self.heads:
                if action.camera in (None, head.name):
                    head.on = action.action == "camera_replug"
        elif action.action == "disarm":
            self.autopilot.armed = False

    def _reached(self, action: ActionConfig) -> bool:
        """Whether a distance-triggered action is due."""
        if action.flown_m is not None:
            return self._flown_m >= action.flown_m
        if action.goal_within_m is None or self.goal is None:
            return False
        north, east, _ = (float(v) for v in self.vehicle.state.position_m)
        away_m = math.hypot(self.goal.north_m - north, self.goal.east_m - east)
        return away_m <= action.goal_within_m

    def _send_obstacle_distance(self, fresh: SectorScan | None, now_ns: int) -> None:
        if fresh is None:
            if self.autopilot.flavour == "px4":
                self.autopilot.proximity(np.full(72, 65535), now_ns)
            return  # ArduPilot hears nothing (and says No Data)
        cm = np.array(sectors_to_cm(fresh, 20, round(MAX_RANGE_M * 100)))
        self.autopilot.proximity(cm, now_ns)

    def _plan(
        self, now_ns: int, fresh: SectorScan | None
    ) -> tuple[Gate, Decision, list[float] | None]:
        """One planning cycle (the daemon's own, :mod:`avoidd.planner.cycle`)."""
        autopilot = self.autopilot
        cycle = CycleInput(
            now_ns,
            AutopilotState(
                link_up=True,
                mode_known=True,
                armed=autopilot.armed,
                setpoint_mode=autopilot.takes_setpoints,
                px4=autopilot.flavour == "px4",
                failsafe=autopilot.failsafe,
            ),
            fresh,
            self._position(now_ns),
            self.vehicle.state.yaw_rad,
            None if self._latest is None else self._latest[1],
            tuple(self._track.reports),
            self.goal,
        )
        if self.record_inputs:
            self.inputs.append(cycle)
        result = self.cycle.step(cycle)
        decision = result.decision
        if decision is None:
            return result.verdict, Decision((0.0, 0.0, 0.0), 0.0, "silent"), None
        self.autopilot.setpoint(np.array(decision.velocity_ned), decision.yaw_rate_rad_s, now_ns)
        return (
            result.verdict,
            decision,
            [round(v, 4) for v in (*decision.velocity_ned, decision.yaw_rate_rad_s)],
        )

    def _side(self, direction_deg: float) -> int:
        assert self.goal is not None
        state = self.vehicle.state
        goal_deg = math.degrees(
            math.atan2(
                self.goal.east_m - state.position_m[1], self.goal.north_m - state.position_m[0]
            )
        )
        delta = math.remainder(direction_deg - goal_deg, 360.0)
        return 0 if abs(delta) < 10.0 else (1 if delta > 0 else -1)

    def _row(
        self,
        t_s: float,
        verdict: Gate,
        decision: Decision,
        setpoint: list[float] | None,
        clearance: float,
        fresh: SectorScan | None,
    ) -> Row:
        state = self.vehicle.state
        north, east, _ = (float(v) for v in state.position_m)
        sectors = sectors_to_cm(fresh, 20, 2000) if fresh is not None else [65535] * 72
        return Row(
            round(t_s, 3),
            round(north, 4),
            round(east, 4),
            round(state.altitude_m, 4),
            round(math.degrees(state.yaw_rad), 3),
            round(float(np.hypot(state.velocity_m_s[0], state.velocity_m_s[1])), 4),
            setpoint,
            verdict.value,
            decision.state,
            None if decision.direction_deg is None else round(decision.direction_deg, 3),
            None
            if decision.free_m is None or not math.isfinite(decision.free_m)
            else round(decision.free_m, 3),
            round(clearance, 4),
            self.autopilot.mode,
            sectors,
        )
