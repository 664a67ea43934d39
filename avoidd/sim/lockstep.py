"""The closed loop in one process, in lockstep: camera, pipeline, planner, autopilot, vehicle.

Simulated time advances in fixed steps; nothing depends on the wall clock, so the same
scenario and seed give the same trace. Each camera frame is rendered (or, with ``oracle``
perception, measured exactly) from the vehicle's pose at its capture time, run through the
head pipeline and its temporal filter, and becomes available to avoidd a fixed latency later.
avoidd's parts are the daemon's own: the gate, the planner, the scan merge; the autopilot is
:class:`~avoidd.sim.flight.SimAutopilot` and the vehicle :class:`~avoidd.sim.vehicle.Multirotor`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from avoidd.config.sim import ScenarioConfig
from avoidd.mavlink.messages import sectors_to_cm
from avoidd.mavlink.track_history import TrackHistory
from avoidd.perception.sectors import covered_bins
from avoidd.planner.core import Decision, Goal
from avoidd.planner.cycle import AutopilotState, CycleInput, PlanningCycle
from avoidd.planner.gating import Gate
from avoidd.sim.flight import SimAutopilot
from avoidd.sim.perception import StereoPerception
from avoidd.sim.vehicle import Multirotor, VehicleState
from avoidd.sim.world import World
from avoidd.types import LocalPosition, Mount, RectifiedRig, SectorScan

STEP_S = 0.01
LATENCY_S = 0.1
"""From capture to avoidd having the scan (the pipeline's time, fixed so runs repeat)."""
MAX_AGE_NS = 300_000_000
OBSTACLE_DISTANCE_HZ = 15.0
MAX_RANGE_M = 20.0
TRACE_HZ = 10.0

RIGS = {
    "320x240": RectifiedRig(320, 240, 200.0, 200.0, 159.5, 119.5, 0.12),
    "640x480": RectifiedRig(640, 480, 400.0, 400.0, 319.5, 239.5, 0.12),
}
"""The simulated head's rectified rig (a 77 degree field of view, 12 cm baseline)."""

Perceive = Callable[[VehicleState, int], SectorScan]
"""Produces the head's (filtered) scan for the vehicle's state at a capture time."""


@dataclass
class Summary:
    """The outcome of one run (JSON-ready; rounded so that repeated runs compare equal)."""

    name: str
    seed: int
    perception: str
    collided: bool = False
    collision_t_s: float | None = None
    min_clearance_m: float = math.inf
    clearance_p01_m: float = math.inf
    reached: bool = False
    time_to_goal_s: float | None = None
    end_state: str = ""
    mean_speed_m_s: float = 0.0
    max_speed_m_s: float = 0.0
    side_changes: int = 0
    detour_side_changes: int = 0
    reachable: bool = True
    clearance_target_m: float = 0.0
    stale_to_hold_ms: float | None = None
    stale_holds: int = 0
    passed: bool = False
    failures: list[str] = field(default_factory=list)
    sim_time_s: float = 0.0
    wall_time_s: float = 0.0

    def as_json(self) -> dict[str, Any]:
        """The summary with floats rounded (the wall time is left out: it never repeats)."""
        out: dict[str, Any] = {}
        for key, value in self.__dict__.items():
            if key == "wall_time_s":
                continue
            if isinstance(value, float):
                out[key] = None if not math.isfinite(value) else round(value, 4)
            else:
                out[key] = value
        return out


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
        seed: Seed of the sensor noise.
        perceive: Makes the head's scan; by default the exact (oracle) distances.
    """

    def __init__(
        self,
        scenario: ScenarioConfig,
        world: World,
        goal: Goal,
        seed: int = 0,
        perceive: Perceive | None = None,
    ) -> None:
        self.scenario = scenario
        self.world = world
        self.goal: Goal | None = goal
        self.seed = seed
        avoidance = scenario.avoidance
        self.rig = RIGS[scenario.resolution]
        self.mount = Mount()
        self.covered = covered_bins(self.rig, self.mount)
        self.cycle = PlanningCycle(avoidance, MAX_RANGE_M)
        self.planner = self.cycle.planner
        self.cycle.new_goal()  # the goal is given before the first cycle
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
        if perceive is None and scenario.perception == "stereo":
            perceive = StereoPerception(world, self.rig, self.mount, MAX_RANGE_M, seed)
        self.perceive = perceive or self._oracle
        self.camera_on = True
        self.rows: list[Row] = []
        self._pending: list[tuple[int, SectorScan, float]] = []
        self._latest: tuple[SectorScan, float] | None = None
        """The newest scan avoidd has, with the yaw at its capture."""
        self._track = TrackHistory()
        self.inputs: list[CycleInput] = []
        """Every planning cycle's input, when ``record_inputs``."""
        self.record_inputs = False

    # --- perception ------------------------------------------------------------------------

    def _oracle(self, state: VehicleState, t_ns: int) -> SectorScan:
        north, east, _ = (float(v) for v in state.position_m)
        distance = self.world.oracle_scan(
            north, east, state.altitude_m, state.yaw_rad, self.covered, MAX_RANGE_M
        )
        return SectorScan(t_ns, distance)

    def _position(self, t_ns: int) -> LocalPosition:
        """The vehicle's position report now (also kept for the track velocity)."""
        state = self.vehicle.state
        north, east, down = (float(v) for v in state.position_m)
        vn, ve = float(state.velocity_m_s[0]), float(state.velocity_m_s[1])
        self._track.add(t_ns, north, east, vn, ve)
        return LocalPosition(t_ns, north, east, down, vn, ve, float(state.velocity_m_s[2]))

    def fresh_scan(self, now_ns: int) -> SectorScan | None:
        """The newest scan avoidd has, if it is younger than the age limit."""
        if self._latest is None:
            return None
        scan, _ = self._latest
        return scan if now_ns - scan.t_capture_ns <= MAX_AGE_NS else None

    # --- the loop --------------------------------------------------------------------------

    def run(self) -> Summary:
        """Run the scenario to its end (or a collision) and score it."""
        started = time.perf_counter()
        scenario = self.scenario
        avoidance = scenario.avoidance
        summary = Summary(scenario.name, self.seed, scenario.perception)
        # The target: radius + margin - 0.1 m in 99 % of steps (edge clearance: margin
        # - 0.1 m, as clearance here is measured from the vehicle's edge).
        summary.clearance_target_m = round(scenario.avoidance.margin_m - 0.1, 4)
        steps = round(scenario.duration_s / STEP_S)
        frame_every = round(1.0 / (scenario.fps * STEP_S))
        plan_every = round(1.0 / (avoidance.setpoint_rate_hz * STEP_S))
        send_every = round(1.0 / (OBSTACLE_DISTANCE_HZ * STEP_S))
        trace_every = round(1.0 / (TRACE_HZ * STEP_S))
        timeline = sorted(scenario.timeline, key=lambda a: a.t_s)
        clearances: list[float] = []
        speeds: list[float] = []
        decision = Decision((0.0, 0.0, 0.0), 0.0, "waiting")
        gate_now = Gate.SILENT
        setpoint: list[float] | None = None
        last_side = 0
        detour_changes = 0
        stale_since_ns: int | None = None
        was_fresh = False
        radius = avoidance.vehicle_radius_m
        for step in range(steps + 1):
            t_s = step * STEP_S
            now_ns = round(t_s * 1e9)
            while timeline and timeline[0].t_s <= t_s + 1e-9:
                self._act(timeline.pop(0), now_ns)
            state = self.vehicle.state
            if step % frame_every == 0 and self.camera_on:
                scan = self.perceive(state, now_ns)
                available = now_ns + round(LATENCY_S * 1e9)
                self._position(now_ns)
                self._pending.append((available, scan, state.yaw_rad))
            while self._pending and self._pending[0][0] <= now_ns:
                _, scan, yaw_then = self._pending.pop(0)
                self._latest = (scan, yaw_then)
            fresh = self.fresh_scan(now_ns)
            if fresh is None and was_fresh:
                stale_since_ns = now_ns  # perception just went stale
            was_fresh = fresh is not None
            if step % send_every == 0:
                self._send_obstacle_distance(fresh, now_ns)
            if step % plan_every == 0:
                gate_now, decision, setpoint = self._plan(now_ns, fresh)
                if decision.direction_deg is not None and self.goal is not None:
                    side = self._side(decision.direction_deg)
                    if side and last_side and side != last_side:
                        summary.side_changes += 1
                        detour_changes += 1
                        summary.detour_side_changes = max(
                            summary.detour_side_changes, detour_changes
                        )
                    if not side:
                        detour_changes = 0  # heading for the goal again: that detour is over
                    last_side = side
                if gate_now is Gate.HOLD:
                    summary.stale_holds += 1
                    if stale_since_ns is not None and decision.state == "stale":
                        # Stale perception to a hold setpoint (the worst of the run).
                        waited_ms = (now_ns - stale_since_ns) / 1e6
                        summary.stale_to_hold_ms = max(summary.stale_to_hold_ms or 0.0, waited_ms)
                        stale_since_ns = None
            velocity, yaw_rate = self.autopilot.command(now_ns, state.yaw_rad)
            self.vehicle.step(STEP_S, velocity, yaw_rate)
            state = self.vehicle.state
            north, east, _ = (float(v) for v in state.position_m)
            clearance = self.world.clearance_m(north, east, state.altitude_m) - radius
            clearances.append(clearance)
            speed = float(np.hypot(state.velocity_m_s[0], state.velocity_m_s[1]))
            speeds.append(speed)
            if clearance < 0.0 and not summary.collided:
                summary.collided = True
                summary.collision_t_s = t_s
            if decision.state == "arrived" and not summary.reached:
                summary.reached = True
                summary.time_to_goal_s = t_s
            if step % trace_every == 0:
                self.rows.append(self._row(t_s, gate_now, decision, setpoint, clearance, fresh))
            if summary.collided:
                break
        summary.end_state = decision.state
        summary.min_clearance_m = float(min(clearances))
        finite = [c for c in clearances if math.isfinite(c)]
        summary.clearance_p01_m = float(np.percentile(finite, 1)) if finite else math.inf
        summary.mean_speed_m_s = float(np.mean(speeds))
        summary.max_speed_m_s = float(max(speeds))
        summary.sim_time_s = len(clearances) * STEP_S
        summary.wall_time_s = time.perf_counter() - started
        self._judge(summary)
        return summary

    def _act(self, action: Any, now_ns: int) -> None:
        if action.action == "mode":
            self.autopilot.set_mode(action.mode, now_ns)
        elif action.action == "goal":
            g = action.goal
            self.goal = Goal(g.north_m, g.east_m, g.altitude_m)
            self.cycle.new_goal()
        elif action.action == "camera_unplug":
            self.camera_on = False
        elif action.action == "camera_replug":
            self.camera_on = True
        elif action.action == "disarm":
            self.autopilot.armed = False

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
            None if fresh is None or self._latest is None else self._latest[1],
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

    def _judge(self, summary: Summary) -> None:
        passing = self.scenario.passing
        summary.reachable = passing.end_state != "no path"
        if passing.no_collision and summary.collided:
            summary.failures.append(f"collision at {summary.collision_t_s:.2f} s")
        needed = passing.min_clearance_m
        if needed is not None and summary.clearance_p01_m < needed:
            summary.failures.append(
                f"clearance {summary.clearance_p01_m:.2f} m in 1% of steps, below {needed} m"
            )
        if passing.reach_goal_s is not None and (
            not summary.reached or (summary.time_to_goal_s or math.inf) > passing.reach_goal_s
        ):
            summary.failures.append(f"goal not reached within {passing.reach_goal_s} s")
        if passing.end_state is not None and summary.end_state != passing.end_state:
            summary.failures.append(f"ended '{summary.end_state}', not '{passing.end_state}'")
        if passing.closest_approach_m is not None:
            low, high = passing.closest_approach_m
            if not low <= summary.min_clearance_m <= high:
                summary.failures.append(
                    f"closest approach {summary.min_clearance_m:.2f} m, not {low}..{high} m"
                )
        summary.passed = not summary.failures


def _finite(value: float | None) -> float | None:
    return None if value is None or not math.isfinite(value) else round(value, 3)
