"""When setpoints may go out: never fight the pilot, never fly on stale perception.

A pure rule over the facts the daemon (and the simulator) know each cycle.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum


class Gate(Enum):
    """What to do this cycle."""

    SILENT = "silent"
    """Send nothing: avoidance off, link down, disarmed, no goal, or a mode that does not
    take setpoints (the pilot or the autopilot flies)."""
    PRESTREAM = "prestream"
    """PX4 not yet in OFFBOARD: stream hold-here setpoints so that it can be switched (not
    after the pilot switched away from OFFBOARD: that is silent until a new goal; and not
    while PX4 says a failsafe is in effect: after its offboard-loss fallback, setpoints
    coming back end the failsafe and PX4 returns to OFFBOARD by itself)."""
    HOLD = "hold"
    """In a setpoint mode but perception is stale: an explicit hold, zero velocity or the
    back-away and drift correction of :meth:`avoidd.planner.core.Planner.hold` (ArduPilot
    drops a velocity command after 3 s, so silence is no hold)."""
    PLAN = "plan"
    """Fly the planner's decision."""


@dataclass(frozen=True)
class Facts:
    """What is known this cycle.

    Attributes:
        enabled: Avoidance is on (config, or the AVD_ENABLE parameter).
        link_up: The autopilot's heartbeat is fresh.
        armed: The vehicle is armed.
        setpoint_mode: Its mode flies velocity setpoints (ArduPilot GUIDED, PX4 OFFBOARD).
        px4: The autopilot is PX4.
        goal: A goal is active.
        fresh: Perception is fresh.
        prestream: ``avoidance.px4_prestream``.
        taken_over: The vehicle left the setpoint mode while armed since the goal was set (the
            pilot took over): no prestream until a new goal or a new arming.
        autopilot_failsafe: The autopilot's heartbeat says a failsafe is in effect: no
            prestream (PX4 would take setpoints coming back as the end of an offboard-loss
            failsafe and return to OFFBOARD without anyone asking for it).
    """

    enabled: bool
    link_up: bool
    armed: bool
    setpoint_mode: bool
    px4: bool
    goal: bool
    fresh: bool
    prestream: bool = True
    taken_over: bool = False
    autopilot_failsafe: bool = False


def gate(facts: Facts) -> Gate:
    """The rule: silent unless avoidance may fly; hold on stale perception; else plan."""
    if not (facts.enabled and facts.link_up and facts.armed and facts.goal):
        return Gate.SILENT
    if not facts.setpoint_mode:
        prestream = (
            facts.px4 and facts.prestream and not facts.taken_over and not facts.autopilot_failsafe
        )
        return Gate.PRESTREAM if prestream else Gate.SILENT
    return Gate.PLAN if facts.fresh else Gate.HOLD


@dataclass
class Handover:
    """Whether the pilot has taken the vehicle from avoidd (:attr:`Facts.taken_over`).

    The pilot has it once the armed vehicle leaves the setpoint mode (while the link is up:
    a lost link says nothing about the mode), and also when avoidd first sees the vehicle
    armed in another mode, unless a goal was given before that (someone else flies it, and
    PX4 returns to OFFBOARD by itself when setpoints come back after its offboard-loss
    failsafe). Disarming or a new goal hands it back.
    """

    taken_over: bool = False
    _was_setpoint_mode: bool = field(default=False, init=False, repr=False)
    _mode_seen: bool = field(default=False, init=False, repr=False)

    def update(self, mode_known: bool, armed: bool, setpoint_mode: bool, link_up: bool) -> bool:
        """Take this cycle's mode into account.

        Args:
            mode_known: A heartbeat has said the mode (False: none yet, or the autopilot
                changed; then ``armed`` and ``setpoint_mode`` are False).
            armed: The vehicle is armed.
            setpoint_mode: Its mode flies velocity setpoints.
            link_up: The autopilot's heartbeat is fresh.

        Returns:
            Whether the pilot has the vehicle now.
        """
        if mode_known and not self._mode_seen:
            self._mode_seen = True
            self.taken_over = armed and not setpoint_mode
        if not armed:
            self.taken_over = False
        elif self._was_setpoint_mode and not setpoint_mode and link_up:
            self.taken_over = True
        self._was_setpoint_mode = setpoint_mode and armed
        return self.taken_over

    def new_goal(self) -> None:
        """A goal was given: avoidd may fly again, whatever mode it first saw."""
        self.taken_over = False
        self._mode_seen = True
