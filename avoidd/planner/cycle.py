"""One planning cycle: what is known now to the setpoint to send, for daemon and simulators.

The daemon's setpoint loop (:mod:`avoidd.daemon.avoidance`) and the simulator's lockstep run
gather the same facts each cycle (the autopilot's state, the fresh merged scan, the vehicle's
position report and yaw, the goal) and hand them to :meth:`PlanningCycle.step`, which applies
the gate (:func:`~avoidd.planner.gating.gate`), feeds the scan to the planner's memory and
decides or holds. So what a simulated flight proves is what the daemon flies.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from avoidd.config import AvoidanceConfig
from avoidd.planner.core import Decision, Goal, Planner, Pose
from avoidd.planner.gating import Facts, Gate, Handover, gate
from avoidd.planner.speed import effective_latency_s, perception_speed_m_s
from avoidd.planner.track import track_velocity_ne
from avoidd.types import LocalPosition, SectorScan, TrackPoint

SWITCH_OFF_HOLD_NS = 1_000_000_000
"""Switched off in flight, avoidd holds this long (ArduPilot flies a velocity for 3 s)."""

REASONS = {
    "link": "no autopilot heard",
    "armed": "disarmed",
    "goal": "no goal",
    "mode": "mode does not take setpoints",
    "enabled": "avoidance off",
    "taken_over": "pilot flies; waiting for a new goal",
    "failsafe": "autopilot failsafe; waiting for the pilot to pick a mode",
}
"""Why a cycle sends nothing, as its state reads."""


@dataclass(frozen=True)
class AutopilotState:
    """What the link says of the autopilot this cycle.

    Attributes:
        link_up: Its heartbeat is fresh.
        mode_known: A heartbeat has said its mode.
        armed: The vehicle is armed.
        setpoint_mode: Its mode flies velocity setpoints (GUIDED, OFFBOARD).
        px4: It is PX4.
        failsafe: Its heartbeat says a failsafe is in effect.
    """

    link_up: bool
    mode_known: bool
    armed: bool
    setpoint_mode: bool
    px4: bool
    failsafe: bool = False


@dataclass(frozen=True)
class CycleInput:
    """Everything one cycle decides on.

    Attributes:
        now_ns: The time now (the clock of scan and position times).
        autopilot: The autopilot's state.
        scan: The fresh merged scan (body bins), None when perception is stale.
        position: The newest fresh position report (None: none recent).
        yaw_now_rad: The heading now (None: unknown).
        yaw_at_capture_rad: The heading when the scan was captured (None: unknown).
        track: The recent position reports, for the track velocity.
        goal: Where to go (None: no goal).
    """

    now_ns: int
    autopilot: AutopilotState
    scan: SectorScan | None
    position: LocalPosition | None
    yaw_now_rad: float | None
    yaw_at_capture_rad: float | None
    track: Sequence[TrackPoint]
    goal: Goal | None


@dataclass(frozen=True)
class CycleResult:
    """What a cycle came to.

    Attributes:
        verdict: The gate's verdict.
        state: The state it leaves the loop in (a reason for silence, or the decision's).
        decision: The setpoint to send (None: send nothing).
        pose: The vehicle's state the decision was made with (None: not known).
    """

    verdict: Gate
    state: str
    decision: Decision | None
    pose: Pose | None


def pose_at(
    t_ns: int, position: LocalPosition, yaw_rad: float, track: Sequence[TrackPoint]
) -> Pose:
    """The vehicle's state at ``t_ns``: the position report carried there with its velocity."""
    dt_s = (t_ns - position.t_ns) / 1e9
    return Pose(
        t_ns,
        position.north_m + position.vn_m_s * dt_s,
        position.east_m + position.ve_m_s * dt_s,
        position.down_m,
        yaw_rad,
        position.vn_m_s,
        position.ve_m_s,
        track_velocity_ne(track),
    )


def within_sight(config: AvoidanceConfig, thin_range_m: float | None) -> AvoidanceConfig:
    """The settings with the top speed cut to what the cameras can stop for.

    Args:
        config: The ``avoidance`` section.
        thin_range_m: Where the heads first read their smallest obstacle; None: no cut
            (exact distances, or no cameras to judge).

    Returns:
        ``config``, or a copy whose ``max_speed_m_s`` is
        :func:`~avoidd.planner.speed.perception_speed_m_s` when that is lower (after the
        delay :func:`~avoidd.planner.speed.effective_latency_s` counts at the least).
    """
    if thin_range_m is None:
        return config
    # The delay the speed law counts at the least: the configured latency, or one setpoint
    # period plus the autopilot's response if that is longer.
    latency_s = effective_latency_s(config.latency_ms / 1000.0, 0.0, config.setpoint_rate_hz)
    limit = perception_speed_m_s(
        thin_range_m, config.vehicle_radius_m + config.margin_m, config.max_accel_m_s2, latency_s
    )
    if limit >= config.max_speed_m_s:
        return config
    # Never zero: the speed law still stops short of whatever is read.
    return config.model_copy(update={"max_speed_m_s": max(limit, MIN_TOP_SPEED_M_S)})


MIN_TOP_SPEED_M_S = 0.5
"""The cut never goes below this (heads that read nothing thin beyond the clearance)."""


class PlanningCycle:
    """The planner with its gate and the pilot's handover, stepped once per setpoint.

    Args:
        config: The ``avoidance`` section.
        max_range_m: The range a clear bin vouches for.
        thin_range_m: Where the heads first read their smallest obstacle: the top speed is
            cut to what can stop within it (:func:`within_sight`); None: no cut.
    """

    def __init__(
        self, config: AvoidanceConfig, max_range_m: float, thin_range_m: float | None = None
    ) -> None:
        self.config = config
        self.thin_range_m = thin_range_m
        self.planner = Planner(within_sight(config, thin_range_m), max_range_m)
        self.handover = Handover()
        self._flying = False
        self._switched_off_ns = -(10**18)

    def reconfigure(self, config: AvoidanceConfig) -> None:
        """Take new settings (parameters set in flight)."""
        self.config = config
        self.planner.reconfigure(within_sight(config, self.thin_range_m))

    def new_goal(self) -> None:
        """A new goal: the pilot's takeover is forgotten, the planner starts over."""
        self.handover.new_goal()
        self.planner.reset()

    def step(self, cycle: CycleInput) -> CycleResult:
        """One cycle: gate, memory, then the planner's decision or a hold."""
        now_ns = cycle.now_ns
        pose = None
        if cycle.position is not None and cycle.yaw_now_rad is not None:
            pose = pose_at(now_ns, cycle.position, cycle.yaw_now_rad, cycle.track)
        if not self.config.enabled:
            return self._switched_off(now_ns, cycle.autopilot, pose)
        scan = cycle.scan
        if scan is not None and cycle.position is not None and cycle.yaw_at_capture_rad is not None:
            at_capture = pose_at(
                scan.t_capture_ns, cycle.position, cycle.yaw_at_capture_rad, cycle.track
            )
            self.planner.observe_scan(
                scan.distance_m,
                scan.t_capture_ns,
                at_capture,
                scan.points_frd_m,
                scan.reading_t_ns,
            )
        facts = self.facts(
            cycle.autopilot, cycle.goal is not None, scan is not None and pose is not None
        )
        verdict = gate(facts)
        if verdict is Gate.SILENT or cycle.goal is None:
            self._flying = False
            return CycleResult(Gate.SILENT, silent_reason(facts), None, pose)
        if verdict is Gate.PLAN and pose is not None:
            decision = self.planner.decide(now_ns, pose, cycle.goal, fresh=True)
        else:
            why = "prestream" if verdict is Gate.PRESTREAM else "stale"
            if verdict is Gate.HOLD and pose is None:
                why = "no position"
            decision = self.planner.hold(why, pose=pose if verdict is Gate.HOLD else None)
        self._flying = True
        return CycleResult(verdict, decision.state, decision, pose)

    def facts(self, autopilot: AutopilotState, goal: bool, fresh: bool) -> Facts:
        """The gate's facts this cycle (the handover is updated here)."""
        taken_over = self.handover.update(
            autopilot.mode_known, autopilot.armed, autopilot.setpoint_mode, autopilot.link_up
        )
        return Facts(
            enabled=self.config.enabled,
            link_up=autopilot.link_up,
            armed=autopilot.armed,
            setpoint_mode=autopilot.setpoint_mode,
            px4=autopilot.px4,
            goal=goal,
            fresh=fresh,
            prestream=self.config.px4_prestream,
            taken_over=taken_over,
            autopilot_failsafe=autopilot.failsafe,
        )

    def _switched_off(
        self, now_ns: int, autopilot: AutopilotState, pose: Pose | None
    ) -> CycleResult:
        """Avoidance off: switched off in flight, hold for a second, then send nothing.

        Silence would leave ArduPilot flying the last velocity for 3 s.
        """
        if self._flying:
            self._switched_off_ns = now_ns
            self._flying = False
        in_setpoint_mode = autopilot.link_up and autopilot.armed and autopilot.setpoint_mode
        state = REASONS["enabled"]
        if now_ns - self._switched_off_ns < SWITCH_OFF_HOLD_NS and in_setpoint_mode:
            return CycleResult(Gate.HOLD, state, self.planner.hold("avoidance off"), pose)
        return CycleResult(Gate.SILENT, state, None, pose)


def silent_reason(facts: Facts) -> str:
    """Why the gate is silent, in words (the first fact that closes it)."""
    for name in ("enabled", "link", "armed", "goal"):
        value = facts.link_up if name == "link" else getattr(facts, name)
        if not value:
            return REASONS[name]
    if facts.taken_over and facts.px4:
        return REASONS["taken_over"]
    if facts.autopilot_failsafe and facts.px4 and facts.prestream:
        return REASONS["failsafe"]
    return REASONS["mode"]
