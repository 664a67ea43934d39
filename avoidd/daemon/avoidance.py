"""The daemon's setpoint loop: the planner's velocity to the autopilot, only when it may fly.

Each cycle (``avoidance.setpoint_rate_hz``) gathers what the link and perception know (link
up, armed, mode, autopilot, the fresh merged scan, the position and yaw) and hands it to the
planning cycle (:mod:`avoidd.planner.cycle`, the one every simulator runs too), which applies
the gate (:func:`avoidd.planner.gating.gate`); the loop sends at most one
``SET_POSITION_TARGET_LOCAL_NED``
(``MAV_FRAME_LOCAL_NED``, velocity and yaw rate, type mask ``0x05C7``) to the autopilot:

- nothing while the pilot or the autopilot flies (mode without setpoints, disarmed, link down,
  no goal): the next cycle after a mode change away sends nothing;
- PX4 armed with a goal outside OFFBOARD: hold-here setpoints, so it can be switched to
  OFFBOARD (it needs a stream above 2 Hz first); but once it leaves OFFBOARD while armed (the
  pilot took over, or PX4's offboard-loss failsafe), or when avoidd starts while it is armed in
  another mode, nothing until a new goal or a new arming (PX4 goes back to OFFBOARD by itself
  when setpoints return after its offboard-loss failsafe); and nothing while its heartbeat
  says a failsafe is in effect (``system_status`` CRITICAL or worse, as throughout that
  fallback in PX4 1.15), new goal or not, until the pilot picks a mode;
- perception stale, or no local position: an explicit hold (ArduPilot drops a velocity
  command after 3 s, so silence is no hold): zero velocity, or with a known position the
  back-away from what the vehicle is inside the clearance of and the drift correction
  (:meth:`avoidd.planner.core.Planner.hold`);
- otherwise the planner's decision.

Each fresh merged scan goes into the planner's memory with the vehicle's position and the yaw
at its capture time. Planner state changes are logged and sent as STATUSTEXT.
"""

from __future__ import annotations

import logging
import time
from collections import deque
from collections.abc import Callable

from avoidd.config import AvoidanceConfig
from avoidd.daemon import goals
from avoidd.daemon.mission_follow import MissionFollower
from avoidd.daemon.outputs import Outputs, every
from avoidd.daemon.params import BY_NAME, PARAMS, Outcome, ParamTable
from avoidd.mavlink import codec as mav
from avoidd.mavlink.codec import Message
from avoidd.mavlink.link import MavLink
from avoidd.mavlink.mission import MissionClient
from avoidd.mavlink.modes import ARDUPILOT, PX4
from avoidd.mavlink.vehicle import Vehicle
from avoidd.planner.core import Decision, Goal, Pose
from avoidd.planner.cycle import MIN_TOP_SPEED_M_S, AutopilotState, CycleInput, PlanningCycle
from avoidd.planner.cycle import REASONS as _REASONS
from avoidd.planner.gating import Gate

logger = logging.getLogger(__name__)

VELOCITY_YAW_RATE_MASK = 0x05C7
"""SET_POSITION_TARGET type_mask: use velocity and yaw rate; ignore position, acceleration
and yaw (bits 0-2, 6-8 and 10 set)."""

_HISTORY = 64
"""State changes kept in :attr:`AvoidanceLoop.history`."""
_MISSION_MESSAGES = frozenset(
    {"MISSION_COUNT", "MISSION_ITEM_INT", "MISSION_ACK", "MISSION_CURRENT"}
)


class AvoidanceLoop:
    """Plans and sends setpoints at the configured rate.

    Args:
        config: The ``avoidance`` section.
        outputs: The obstacle senders (their merged fresh scan is the planner's input).
        vehicle: The autopilot's state.
        link: Where the setpoints go.
        announce: STATUSTEXT reporter (severity, text, de-duplication key).
        max_range_m: A clear bin sees this far.
        thin_range_m: Where the heads first read their smallest obstacle; the top speed is
            cut to what can stop within it (None: no cut).
    """

    def __init__(
        self,
        config: AvoidanceConfig,
        outputs: Outputs,
        vehicle: Vehicle,
        link: MavLink,
        announce: Callable[[int, str, str | None], None],
        max_range_m: float,
        thin_range_m: float | None = None,
    ) -> None:
        self.params = ParamTable(config, config.params_file)
        config = self.params.config
        self.config = config
        self.outputs = outputs
        self.vehicle = vehicle
        self.link = link
        self.announce = announce
        self.cycle = PlanningCycle(config, max_range_m, thin_range_m)
        self.planner = self.cycle.planner
        self._report_speed_cut()
        goal = config.goal
        self.goal = Goal(goal.north_m, goal.east_m, goal.altitude_m) if goal else None
        self.goal_source = "config" if goal else "none"
        """Where the current goal came from: ``config``, ``gcs`` or ``mission``."""
        self.mission: MissionFollower | None = None
        if config.follow_mission:
            self.mission = MissionFollower(MissionClient(link.codec))
            vehicle.on_autopilot = self._from_autopilot
        vehicle.wants_origin = config.enabled
        self._reboots_seen = vehicle.reboots
        self._mission_done = False
        self.state = "starting" if config.enabled else _REASONS["enabled"]
        """What the loop did last cycle: a gate reason or the planner's state."""
        self.history: deque[tuple[int, str]] = deque(maxlen=_HISTORY)
        """The latest state changes, oldest first: (``time.monotonic_ns()``, new state)."""
        self.last_decision: Decision | None = None
        self.last_pose: Pose | None = None
        """The vehicle's state the last decision was made with (None: none known)."""
        self.handover = self.cycle.handover
        """Whether the pilot has taken the vehicle since the goal was set (no prestream)."""
        self.sent = 0
        self.last_sent_ns = 0
        """``time.monotonic_ns()`` when the last setpoint was sent (0: none yet)."""

    def autopilot_state(self) -> AutopilotState:
        """What the link says of the autopilot now."""
        mode = self.vehicle.mode
        return AutopilotState(
            link_up=self.vehicle.link_up,
            mode_known=mode is not None,
            armed=mode is not None and mode.armed,
            setpoint_mode=mode is not None and mode.guided,
            px4=mode is not None and mode.autopilot == PX4,
            failsafe=mode is not None and mode.failsafe,
        )

    def inputs(self, now_ns: int) -> CycleInput:
        """What the link and perception know now, for the planning cycle."""
        vehicle = self.vehicle
        scan = self.outputs.current_scan(now_ns)
        yaw_now = vehicle.attitude_at(now_ns)
        yaw_then = vehicle.attitude_at(scan.t_capture_ns) if scan is not None else None
        return CycleInput(
            now_ns,
            self.autopilot_state(),
            scan,
            vehicle.fresh_position(now_ns),
            None if yaw_now is None else yaw_now.yaw_rad,
            None if yaw_then is None else yaw_then.yaw_rad,
            tuple(vehicle.positions.reports),
            self.goal,
        )

    def step(self, now_ns: int) -> Message | None:
        """One cycle: the setpoint to send now, or None."""
        if self.config.enabled:
            self._follow_mission(now_ns)
        result = self.cycle.step(self.inputs(now_ns))
        self.last_pose = result.pose
        self._transition(result.state)
        decision = result.decision
        if decision is None:
            return None
        if result.verdict is not Gate.SILENT and self.config.enabled:
            self.last_decision = decision
        if decision.state == "arrived" and self.goal_source == "mission" and not self._mission_done:
            assert self.mission is not None
            self.mission.advance()
            self._next_waypoint(now_ns)
        return self._setpoint(now_ns, decision)

    def _from_autopilot(self, message: Message, received_ns: int) -> None:
        if self.mission is not None and message.get_type() in _MISSION_MESSAGES:
            self.mission.client.handle(message, received_ns)

    def _frame(self) -> goals.Frame:
        position = self.vehicle.position
        return goals.Frame(
            self.vehicle.origin,
            self.vehicle.home_up_m,
            -position.down_m if position is not None else None,
        )

    def _follow_mission(self, now_ns: int) -> None:
        """Keep the mission downloaded; a new one replaces the goal from its first waypoint."""
        mission = self.mission
        if mission is None or not self.vehicle.link_up or self.vehicle.system_id is None:
            return
        if self.vehicle.reboots != self._reboots_seen:
            self._reboots_seen = self.vehicle.reboots
            mission.client.reset()
        for message in mission.client.tick(
            now_ns, self.vehicle.system_id, self.vehicle.component_id
        ):
            self.link.send(message)
        mode = self.vehicle.mode
        if mission.new_mission(ardupilot=mode is not None and mode.autopilot == ARDUPILOT):
            self.goal_source = "mission"
            self._mission_done = False
            self.goal = None
            self._next_waypoint(now_ns)
        elif self.goal_source == "mission" and self.goal is None:
            self._next_waypoint(now_ns)  # waiting for the origin

    def _next_waypoint(self, now_ns: int) -> None:
        assert self.mission is not None
        goal = self.mission.goal(self._frame())
        if isinstance(goal, Goal):
            if goal != self.goal:
                self.set_goal(goal)
        elif goal is None:
            # Done (the last waypoint stays the goal: the vehicle holds there), or a mission
            # without waypoints.
            if self.goal is not None and not self._mission_done:
                logger.info("mission: last waypoint reached")
                self.announce(mav.MAV_SEVERITY_INFO, "avoidd: mission done", "mission")
            self._mission_done = True
        else:
            self.goal = None  # until the origin is known

    def summary(self) -> str:
        """The loop's state in a phrase for the periodic log line.

        ``avoidance moving to GCS goal 12.3 m, 45 deg at <=2.1 m/s`` while it flies; else why
        it holds or is silent (``avoidance holds: stale``, ``avoidance silent: disarmed``).
        """
        if not self.config.enabled:
            return "avoidance off"
        decision = self.last_decision
        goal = self.goal
        if self.state in _REASONS.values() or self.state == "starting" or decision is None:
            return f"avoidance silent: {self.state}"
        where = goal.label if goal is not None else "no goal"
        if decision.goal_distance_m is not None:
            where += f" {decision.goal_distance_m:.1f} m"
        if decision.state == "moving" and decision.direction_deg is not None:
            free = f" ({decision.free_m:.1f} m free)" if decision.free_m is not None else ""
            return (
                f"avoidance moving to {where}, {decision.direction_deg:.0f} deg at "
                f"<={decision.speed_limit_m_s:.1f} m/s{free}"
            )
        return f"avoidance holds ({decision.state}): {where}"

    def _setpoint(self, now_ns: int, decision: Decision) -> Message:
        vn, ve, vd = decision.velocity_ned
        return self.link.codec.build(
            "SET_POSITION_TARGET_LOCAL_NED",
            self.vehicle.time_boot_ms(now_ns),
            self.vehicle.system_id or 0,
            self.vehicle.component_id,
            mav.MAV_FRAME_LOCAL_NED,
            VELOCITY_YAW_RATE_MASK,
            0.0,
            0.0,
            0.0,
            vn,
            ve,
            vd,
            0.0,
            0.0,
            0.0,
            0.0,
            decision.yaw_rate_rad_s,
        )

    def _transition(self, state: str) -> None:
        if state == self.state:
            return
        previous, self.state = self.state, state
        self.history.append((time.monotonic_ns(), state))
        # "no path" ends the flight toward the goal: an operator reading the log must see it.
        level = logging.WARNING if state == "no path" else logging.INFO
        logger.log(level, "avoidance: %s (was %s)", state, previous)
        severity = mav.MAV_SEVERITY_INFO
        text = f"avoidd: {state}" if state.startswith("avoidance") else f"avoidd: avoidance {state}"
        if state == "no path":
            severity, text = mav.MAV_SEVERITY_WARNING, "avoidd: no path to goal"
        elif state == "stale":
            severity = mav.MAV_SEVERITY_CRITICAL
        elif state == "arrived" and self.goal is not None:
            # An event, not a state: never replaced by the next state while it waits.
            self.announce(severity, f"avoidd: reached {self.goal.label}", None)
            return
        self.announce(severity, text, "avoidance")

    def handle_command(self, message: Message) -> None:
        """A goal, command or parameter message addressed to avoidd's component.

        Goals (newest wins): ``SET_POSITION_TARGET_LOCAL_NED`` (``MAV_FRAME_LOCAL_NED``),
        ``SET_POSITION_TARGET_GLOBAL_INT`` and ``COMMAND_INT`` ``MAV_CMD_DO_REPOSITION`` (global
        positions through the autopilot's origin). Commands get a COMMAND_ACK with the result;
        every refusal is logged and sent as STATUSTEXT with its reason. A goal from a ground
        station replaces the mission's until the mission changes.
        """
        kind = message.get_type()
        if kind.startswith("PARAM_"):
            self._param(message)
            return
        goal: Goal | goals.Refusal
        if kind == "SET_POSITION_TARGET_LOCAL_NED":
            goal = goals.local_target(message, self._frame())
        elif kind == "SET_POSITION_TARGET_GLOBAL_INT":
            goal = goals.global_target(message, self._frame())
        elif kind == "COMMAND_INT" and int(message.command) == mav.MAV_CMD_DO_REPOSITION:
            goal = goals.reposition(message, self._frame())
        elif kind in ("COMMAND_LONG", "COMMAND_INT"):
            command = int(message.command)
            why = "use COMMAND_INT"
            if command != mav.MAV_CMD_DO_REPOSITION:
                why = f"command {command} not supported"
            self._refuse(kind, goals.Refusal(mav.MAV_RESULT_UNSUPPORTED, why), message)
            return
        else:
            logger.warning("%s addressed to avoidd: not supported", kind)
            return
        if isinstance(goal, goals.Refusal):
            self._refuse(kind, goal, message)
            return
        if kind == "COMMAND_INT":
            self._ack(message, mav.MAV_RESULT_ACCEPTED)
        self.goal_source = "gcs"
        self.set_goal(goal)

    def _refuse(self, kind: str, refusal: goals.Refusal, message: Message) -> None:
        logger.warning("%s refused: %s", kind, refusal.reason)
        self.announce(mav.MAV_SEVERITY_WARNING, f"avoidd: goal refused: {refusal.reason}", None)
        if kind.startswith("COMMAND_"):
            self._ack(message, refusal.result)

    def _ack(self, message: Message, result: int) -> None:
        self.link.send(
            self.link.codec.build(
                "COMMAND_ACK",
                int(message.command),
                result,
                0,
                0,
                message.get_srcSystem(),
                message.get_srcComponent(),
            )
        )

    def _param(self, message: Message) -> None:
        """Answer the parameter protocol (see :mod:`avoidd.daemon.params`)."""
        kind = message.get_type()
        names: list[str] = []
        if kind == "PARAM_REQUEST_LIST":
            names = [p.name for p in PARAMS]
        elif kind == "PARAM_REQUEST_READ":
            index = int(message.param_index)
            name = _param_name(message.param_id)
            if 0 <= index < len(PARAMS):
                name = PARAMS[index].name
            names = [name] if name in BY_NAME else []
        elif kind == "PARAM_SET":
            name = _param_name(message.param_id)
            if name not in BY_NAME:
                logger.warning("PARAM_SET %s: no such avoidd parameter", name)
                return
            self._param_set(
                name, float(message.param_value), self.vehicle.trust.may_weaken(message)
            )
            names = [name]
        for name in names:
            index = next(i for i, p in enumerate(PARAMS) if p.name == name)
            self.link.send(
                self.link.codec.build(
                    "PARAM_VALUE",
                    name.encode(),
                    self.params.value(name),
                    mav.MAV_PARAM_TYPE_REAL32,
                    len(PARAMS),
                    index,
                )
            )

    def _param_set(self, name: str, value: float, may_weaken: bool) -> None:
        """Set one parameter, or say why not (log and STATUSTEXT, one subject)."""
        outcome = self.params.set(name, value, may_weaken)
        if outcome is Outcome.SET:
            self._apply(self.params.config)
            logger.info("avoidance: %s set to %g", name, value)
            return
        low, high = self.params.bounds(name)
        if outcome is Outcome.WEAKENS:
            why = "refused: unsigned"
            logger.warning(
                "PARAM_SET %s=%g refused: it makes avoidd less cautious and the message is "
                "not signed (sign the link, or set mavlink.control.unsigned_may_weaken)",
                name,
                value,
            )
        else:
            why = f"must be {low:g}..{high:g}"
            logger.warning("PARAM_SET %s=%g refused: outside %g..%g", name, value, low, high)
        self.announce(mav.MAV_SEVERITY_WARNING, f"avoidd: {name} {why}", "param refused")

    def _apply(self, config: AvoidanceConfig) -> None:
        self.config = config
        self.vehicle.wants_origin = config.enabled
        self.cycle.reconfigure(config)
        self._report_speed_cut()

    def _report_speed_cut(self) -> None:
        """Say so when the cameras cannot stop for the configured top speed."""
        flown = self.planner.config.max_speed_m_s
        thin_m = self.cycle.thin_range_m
        if flown < self.config.max_speed_m_s and thin_m is not None and flown <= MIN_TOP_SPEED_M_S:
            logger.warning(
                "avoidance: top speed %.1f m/s cut to its floor of %.1f m/s: the cameras first "
                "read their smallest obstacle at %.1f m, within the %.1f m clearance and a stop "
                '(docs/perception.md, "Thin poles")',
                self.config.max_speed_m_s,
                flown,
                thin_m,
                self.planner.clearance_m,
            )
        elif flown < self.config.max_speed_m_s and thin_m is not None:
            logger.warning(
                "avoidance: top speed %.1f m/s cut to %.1f m/s: the cameras first read their "
                "smallest obstacle at %.1f m, and a stop from %.1f m/s must fit within that "
                'less the %.1f m clearance (docs/perception.md, "Thin poles")',
                self.config.max_speed_m_s,
                flown,
                self.cycle.thin_range_m,
                flown,
                self.planner.clearance_m,
            )

    def set_goal(self, goal: Goal) -> None:
        """Fly to a new goal from now on (the obstacle memory is kept)."""
        self.goal = goal
        # A goal given after avoidd started supersedes the rule about the mode it found at
        # start: without this, a goal that arrives before the first heartbeat is decoded
        # would be followed by "armed in another mode at start" and no prestream (seen).
        self.cycle.new_goal()
        logger.info(
            "avoidance: new %s: %.1f m north, %.1f m east, %.1f m up",
            goal.label,
            goal.north_m,
            goal.east_m,
            goal.altitude_m,
        )
        self.announce(
            mav.MAV_SEVERITY_INFO,
            f"avoidd: goal N{goal.north_m:.1f} E{goal.east_m:.1f} A{goal.altitude_m:.1f}",
            None,
        )

    async def run(self) -> None:
        """Send setpoints at the setpoint rate, forever."""

        def send() -> None:
            message = self.step(time.monotonic_ns())
            if message is not None:
                self.link.send(message)
                self.sent += 1
                self.last_sent_ns = time.monotonic_ns()

        await every(self.config.setpoint_rate_hz, send)


def _param_name(raw: bytes | str) -> str:
    """A PARAM_* message's param_id as text (16 chars, NUL-padded unless full length)."""
    text = raw.decode(errors="replace") if isinstance(raw, bytes) else raw
    return text.split("\x00", 1)[0]
