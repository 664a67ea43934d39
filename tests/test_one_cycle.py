"""One planning cycle: the daemon's setpoint loop and the simulator give the same setpoints."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Any

import pytest

from avoidd.config.sim import ScenarioConfig
from avoidd.daemon.avoidance import AvoidanceLoop
from avoidd.mavlink import codec as mav
from avoidd.mavlink.modes import PX4
from avoidd.planner.cycle import CycleInput
from avoidd.sim.lockstep import MAX_RANGE_M
from avoidd.sim.scenario import prepare
from avoidd.types import LocalPosition, SectorScan, TrackPoint


@dataclass
class Recorded:
    """What the daemon's link and outputs would know at one cycle, replayed from the sim."""

    cycle: CycleInput | None = None
    reports: list[TrackPoint] = field(default_factory=list)


class ReplayedVehicle:
    """The daemon's view of the vehicle, answering from a recorded cycle."""

    def __init__(self, recorded: Recorded, px4: bool) -> None:
        self._recorded = recorded
        self._px4 = px4
        self.reboots = 0
        self.wants_origin = False
        self.system_id = 1
        self.component_id = 1
        self.origin = None
        self.home_up_m = None

    @property
    def _cycle(self) -> CycleInput:
        assert self._recorded.cycle is not None
        return self._recorded.cycle

    @property
    def link_up(self) -> bool:
        return self._cycle.autopilot.link_up

    @property
    def mode(self) -> Any:
        state = self._cycle.autopilot
        return SimpleNamespace(
            armed=state.armed,
            guided=state.setpoint_mode,
            autopilot=PX4 if self._px4 else "ArduPilot",
            failsafe=state.failsafe,
        )

    @property
    def position(self) -> LocalPosition | None:
        return self._cycle.position

    @property
    def positions(self) -> Any:
        return SimpleNamespace(reports=self._recorded.reports)

    def fresh_position(self, now_ns: int) -> LocalPosition | None:
        return self._cycle.position

    def attitude_at(self, t_ns: int) -> Any:
        cycle = self._cycle
        if t_ns == cycle.now_ns:
            yaw = cycle.yaw_now_rad
        else:
            assert cycle.scan is not None and t_ns == cycle.scan.t_capture_ns
            yaw = cycle.yaw_at_capture_rad
        return None if yaw is None else SimpleNamespace(yaw_rad=yaw)

    def time_boot_ms(self, now_ns: int) -> int:
        return now_ns // 1_000_000


class ReplayedOutputs:
    def __init__(self, recorded: Recorded) -> None:
        self._recorded = recorded

    def current_scan(self, now_ns: int) -> SectorScan | None:
        assert self._recorded.cycle is not None
        return self._recorded.cycle.scan


SCENARIOS = {
    "a wall in the way (ArduPilot, stereo)": {
        "world": {"kind": "wall", "seed": 2, "length_m": 16},
        "duration_s": 14,
    },
    "PX4: prestream, OFFBOARD, the pilot takes over": {
        "world": {"kind": "pole_forest", "seed": 4, "length_m": 16},
        "autopilot": "px4",
        "duration_s": 12,
        "timeline": [
            {"t_s": 2.0, "action": "mode", "mode": "OFFBOARD"},
            {"t_s": 9.0, "action": "mode", "mode": "POSCTL"},
        ],
    },
}


@pytest.mark.parametrize("name", list(SCENARIOS))
def test_the_daemons_loop_and_the_lockstep_run_send_the_same_setpoints(name: str) -> None:
    scenario = ScenarioConfig.model_validate({"version": 1, "name": "same", **SCENARIOS[name]})
    run = prepare(scenario)
    run.record_inputs = True
    sent: list[tuple[float, float, float, float] | None] = []
    setpoint = run.autopilot.setpoint

    def keep(velocity: Any, yaw_rate: float, now_ns: int) -> None:
        sent[-1] = (*(float(v) for v in velocity), float(yaw_rate))
        setpoint(velocity, yaw_rate, now_ns)

    run.autopilot.setpoint = keep  # type: ignore[method-assign]
    recorded_cycles = run.inputs

    class Marking(list[CycleInput]):
        def append(self, item: CycleInput) -> None:
            sent.append(None)
            super().append(item)

    run.inputs = Marking()
    recorded_cycles = run.inputs
    summary = run.run()
    assert len(recorded_cycles) > 100 and any(s is not None for s in sent), summary

    recorded = Recorded()
    loop = AvoidanceLoop(
        scenario.avoidance,
        ReplayedOutputs(recorded),  # type: ignore[arg-type]
        ReplayedVehicle(recorded, scenario.autopilot == "px4"),  # type: ignore[arg-type]
        SimpleNamespace(codec=mav.Codec(1, 196)),  # type: ignore[arg-type]
        lambda *args: None,
        MAX_RANGE_M,
    )
    loop.set_goal(run.goal)  # type: ignore[arg-type]
    states = set()
    for cycle, expected in zip(recorded_cycles, sent, strict=True):
        recorded.cycle = cycle
        recorded.reports = list(cycle.track)
        message = loop.step(cycle.now_ns)
        states.add(loop.state)
        if expected is None:
            assert message is None, (cycle.now_ns, loop.state)
            continue
        assert message is not None, (cycle.now_ns, loop.state)
        got = (message.vx, message.vy, message.vz, message.yaw_rate)
        assert got == pytest.approx(expected, abs=1e-5), (cycle.now_ns / 1e9, loop.state)
    assert "moving" in states
    if scenario.autopilot == "px4":
        assert {"pilot flies; waiting for a new goal"} <= states
    assert not math.isnan(summary.min_clearance_m)
