"""The daemon's setpoint loop against the mock autopilot over real UDP, both flavours: gating by
mode, arming and link, PX4 prestream, the message's frame, mask and target."""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import sys
import time
from collections.abc import AsyncIterator
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from avoidd.config import AvoidanceConfig, GoalConfig
from avoidd.daemon.avoidance import VELOCITY_YAW_RATE_MASK, AvoidanceLoop
from avoidd.daemon.stats import log_line
from avoidd.mavlink import codec as mav
from avoidd.mavlink.goto import GlobalGoal, LocalGoal, send_goal
from avoidd.mavlink.mission import MissionItem
from avoidd.mavlink.mock_autopilot import MockAutopilot
from avoidd.planner.core import Goal
from tests.helpers import free_udp_port, open_udp_peer, start_hub, synthetic_config, wait_for
from tests.helpers import start_daemon as start
from tests.helpers import stop_daemon as stop

AVOIDANCE = {
    "avoidance": {"enabled": True, "goal": {"north_m": 30.0, "east_m": 0.0, "altitude_m": 1.5}}
}


async def _pair(
    tmp_path: Path, autopilot: MockAutopilot, sections: dict[str, Any] | None = None
) -> tuple[Any, asyncio.Task[int]]:
    port = free_udp_port()
    await autopilot.start(f"udpin:127.0.0.1:{port}")
    config = synthetic_config(tmp_path, f"udpout:127.0.0.1:{port}", sections=sections or AVOIDANCE)
    return await start(config)


def _setpoints(autopilot: MockAutopilot) -> list[Any]:
    return autopilot.of_type("SET_POSITION_TARGET_LOCAL_NED")


async def test_ardupilot_guided_gets_velocity_setpoints_and_loiter_gets_none(
    tmp_path: Path,
) -> None:
    autopilot = MockAutopilot(system_id=7, mode="GUIDED", armed=True)
    daemon, task = await _pair(tmp_path, autopilot)
    try:
        assert await wait_for(lambda: len(_setpoints(autopilot)) >= 20, 15.0)
        message = _setpoints(autopilot)[-1]
        assert message.coordinate_frame == mav.MAV_FRAME_LOCAL_NED
        assert message.type_mask == VELOCITY_YAW_RATE_MASK
        assert (message.target_system, message.target_component) == (7, 1)
        assert daemon.avoidance.state in {"moving", "dead end", "no path", "arrived"}
        # The periodic log line says what the planner does and toward which goal.
        line = log_line(daemon.snapshot(time.monotonic_ns()))
        state = daemon.avoidance.last_decision.state
        flying = "; avoidance moving to goal " if state == "moving" else f"({state}): goal "
        assert flying in line, line
        # The pilot takes over: once avoidd has heard the new mode, nothing more is sent.
        autopilot.mode = "LOITER"
        assert await wait_for(lambda: daemon.avoidance.state == "mode does not take setpoints", 5)
        line = log_line(daemon.snapshot(time.monotonic_ns()))
        assert line.endswith("; avoidance silent: mode does not take setpoints"), line
        count = len(_setpoints(autopilot))
        await asyncio.sleep(0.6)
        assert len(_setpoints(autopilot)) <= count + 1  # at most one already in flight
        # Disarmed in GUIDED: nothing either.
        autopilot.mode, autopilot.armed = "GUIDED", False
        assert await wait_for(lambda: daemon.avoidance.state == "disarmed", 5)
        count = len(_setpoints(autopilot))
        await asyncio.sleep(0.6)
        assert len(_setpoints(autopilot)) <= count + 1
        texts = [m.text for m in autopilot.of_type("STATUSTEXT")]
        assert "avoidd: avoidance disarmed" in texts
        # The state changes are kept in order with their times (a run's summary shows them).
        states = [state for _, state in daemon.avoidance.history]
        assert states[-1] == "disarmed" and "mode does not take setpoints" in states[:-1]
        times_ns = [t_ns for t_ns, _ in daemon.avoidance.history]
        assert times_ns == sorted(times_ns)
    finally:
        await stop(daemon, task)
        await autopilot.stop()


async def test_px4_prestreams_hold_setpoints_until_offboard(tmp_path: Path) -> None:
    # Armed in Position mode before avoidd starts: someone else flies it, avoidd is silent.
    autopilot = MockAutopilot(flavour="px4", system_id=7, mode="POSCTL", armed=True)
    daemon, task = await _pair(tmp_path, autopilot)
    try:
        flies = "pilot flies; waiting for a new goal"
        assert await wait_for(
            lambda: daemon.avoidance is not None and daemon.avoidance.state == flies, 15.0
        )
        await asyncio.sleep(0.5)
        assert not _setpoints(autopilot)
        # A new arming: prestream.
        autopilot.armed = False
        assert await wait_for(lambda: daemon.avoidance.state == "disarmed", 5.0)
        autopilot.armed = True
        assert await wait_for(lambda: len(_setpoints(autopilot)) >= 30, 15.0)
        assert daemon.avoidance.state == "prestream"
        # Above 2 Hz (the stream is at 20 Hz), and every one holds still.
        recent = _setpoints(autopilot)[-20:]
        assert all((m.vx, m.vy, m.vz, m.yaw_rate) == (0, 0, 0, 0) for m in recent)
        autopilot.mode = "OFFBOARD"
        assert await wait_for(lambda: daemon.avoidance.state != "prestream", 5)
        assert daemon.avoidance.state in {"moving", "dead end", "no path", "arrived", "stale"}
        # The pilot switches back to Position mode: no prestream any more, nothing is sent
        # after the cycle under way.
        autopilot.mode = "POSCTL"
        assert await wait_for(lambda: daemon.avoidance.state == flies, 5)
        count = len(_setpoints(autopilot))
        await asyncio.sleep(0.6)
        assert len(_setpoints(autopilot)) <= count + 1
        # A new goal from the ground station: prestream again, so OFFBOARD can be re-entered.
        daemon.avoidance.set_goal(Goal(10.0, 5.0, 1.5, "GCS goal"))
        assert await wait_for(lambda: daemon.avoidance.state == "prestream", 5)
    finally:
        await stop(daemon, task)
        await autopilot.stop()


async def test_no_prestream_while_px4_says_a_failsafe_is_in_effect(tmp_path: Path) -> None:
    """After PX4's offboard-loss fallback its heartbeat says CRITICAL, and setpoints coming
    back would end the failsafe and put it back in OFFBOARD by itself: a new goal then waits
    for the pilot to pick a mode (which ends the failsafe) before avoidd prestreams."""
    autopilot = MockAutopilot(flavour="px4", system_id=7, mode="POSCTL", armed=True, failsafe=True)
    daemon, task = await _pair(tmp_path, autopilot)
    try:
        flies = "pilot flies; waiting for a new goal"
        assert await wait_for(
            lambda: daemon.avoidance is not None and daemon.avoidance.state == flies, 15.0
        )
        assert daemon.vehicle.mode is not None and daemon.vehicle.mode.failsafe
        daemon.avoidance.set_goal(Goal(10.0, 5.0, 1.5, "GCS goal"))
        waiting = "autopilot failsafe; waiting for the pilot to pick a mode"
        assert await wait_for(lambda: daemon.avoidance.state == waiting, 5.0)
        await asyncio.sleep(1.5)  # PX4 would be back in OFFBOARD after 1 s of setpoints
        assert daemon.avoidance.state == waiting
        assert not _setpoints(autopilot)
        # The pilot picks Position mode: the failsafe is over, and avoidd offers OFFBOARD.
        autopilot.failsafe = False
        assert await wait_for(lambda: len(_setpoints(autopilot)) >= 10, 10.0)
        assert daemon.avoidance.state == "prestream"
    finally:
        await stop(daemon, task)
        await autopilot.stop()


def test_a_goal_given_before_the_first_mode_is_heard_still_prestreams() -> None:
    """The start rule (armed in another mode when avoidd starts: someone else flies) is about
    the goal avoidd started with; a goal given afterwards is the ground station asking."""
    vehicle = SimpleNamespace(mode=None, link_up=True, reboots=0, wants_origin=False)
    config = AvoidanceConfig(enabled=True, px4_prestream=True)
    loop = AvoidanceLoop(config, None, vehicle, None, lambda *a: None, 20.0)  # type: ignore[arg-type]
    loop.set_goal(Goal(10.0, 0.0, 2.0, "GCS goal"))
    vehicle.mode = SimpleNamespace(armed=True, guided=False, autopilot="PX4", failsafe=False)
    assert not loop.cycle.facts(loop.autopilot_state(), goal=True, fresh=True).taken_over
    # Without a goal given after the start, the rule holds.
    started_with_goal = AvoidanceLoop(
        config.model_copy(update={"goal": GoalConfig(north_m=10.0, east_m=0.0, altitude_m=2.0)}),
        None,  # type: ignore[arg-type]
        vehicle,  # type: ignore[arg-type]
        None,  # type: ignore[arg-type]
        lambda *a: None,
        20.0,
    )
    state = started_with_goal.autopilot_state()
    assert started_with_goal.cycle.facts(state, goal=True, fresh=True).taken_over


async def test_stale_perception_is_an_explicit_zero_velocity_hold(tmp_path: Path) -> None:
    autopilot = MockAutopilot(system_id=7, mode="GUIDED", armed=True)
    port = free_udp_port()
    await autopilot.start(f"udpin:127.0.0.1:{port}")
    # Frames twice a second and an age limit of 20 ms: perception is never fresh.
    config = synthetic_config(
        tmp_path,
        f"udpout:127.0.0.1:{port}",
        source={"kind": "synthetic", "fps": 2, "seed": 3},
        pipeline={"max_age_ms": 20, "log_interval_s": 1.0},
        sections=AVOIDANCE,
    )
    daemon, task = await start(config)
    try:
        assert await wait_for(lambda: len(_setpoints(autopilot)) >= 20, 15.0)
        assert daemon.avoidance.state == "stale"
        recent = _setpoints(autopilot)[-10:]
        assert all((m.vx, m.vy, m.vz) == (0, 0, 0) for m in recent)
        # STATUSTEXT is spaced 0.5 s apart: it may still wait behind the head's own.
        assert await wait_for(
            lambda: "avoidd: avoidance stale" in [m.text for m in autopilot.of_type("STATUSTEXT")],
            5.0,
        )
    finally:
        await stop(daemon, task)
        await autopilot.stop()


async def test_a_goal_addressed_to_avoidd_replaces_the_current_one_and_commands_are_refused(
    tmp_path: Path,
) -> None:
    autopilot = MockAutopilot(system_id=7, mode="GUIDED", armed=True)
    daemon, task = await _pair(tmp_path, autopilot)
    try:
        assert await wait_for(lambda: daemon.avoidance is not None and daemon.vehicle.link_up, 10)
        goal = autopilot.codec.build(
            "SET_POSITION_TARGET_LOCAL_NED",
            0,
            7,
            mav.MAV_COMP_ID_OBSTACLE_AVOIDANCE,
            mav.MAV_FRAME_LOCAL_NED,
            0x0FF8,  # position only
            12.0,
            -4.0,
            -3.0,
            0,
            0,
            0,
            0,
            0,
            0,
            0,
            0,
        )
        autopilot.send(goal)
        assert await wait_for(lambda: daemon.avoidance.goal.label == "GCS goal", 5)
        assert (daemon.avoidance.goal.north_m, daemon.avoidance.goal.east_m) == (12.0, -4.0)
        assert daemon.avoidance.goal.altitude_m == 3.0
        assert await wait_for(
            lambda: (
                "avoidd: goal N12.0 E-4.0 A3.0" in [m.text for m in autopilot.of_type("STATUSTEXT")]
            ),
            3,
        )
        # DO_REPOSITION as COMMAND_LONG (no frame for its altitude): refused, as ArduPilot does.
        reposition = autopilot.codec.build(
            "COMMAND_LONG",
            7,
            mav.MAV_COMP_ID_OBSTACLE_AVOIDANCE,
            192,
            0,
            -1,
            0,
            0,
            0,
            47.0,
            8.0,
            20.0,
        )
        autopilot.send(reposition)
        assert await wait_for(
            lambda: any(
                m.command == 192 and m.result == mav.MAV_RESULT_UNSUPPORTED
                for m in autopilot.of_type("COMMAND_ACK")
            ),
            3,
        )
    finally:
        await stop(daemon, task)
        await autopilot.stop()


def _param_values(autopilot: MockAutopilot, name: str) -> list[float]:
    return [
        m.param_value for m in autopilot.of_type("PARAM_VALUE") if m.param_id.rstrip("\x00") == name
    ]


async def test_parameters_list_read_set_range_check_and_persist(tmp_path: Path) -> None:
    params_file = tmp_path / "params.json"
    autopilot = MockAutopilot(system_id=7, mode="LOITER", armed=True)
    port = free_udp_port()
    await autopilot.start(f"udpin:127.0.0.1:{port}")
    sections = {"avoidance": {"enabled": False, "params_file": str(params_file)}}
    # Unsigned, so switching avoidance on needs the opt-in (tests/test_trust_link.py).
    config = synthetic_config(
        tmp_path,
        f"udpout:127.0.0.1:{port}",
        mavlink={"control": {"unsigned_may_weaken": True}},
        sections=sections,
    )
    daemon, task = await start(config)
    me = mav.MAV_COMP_ID_OBSTACLE_AVOIDANCE
    try:
        assert await wait_for(lambda: daemon.vehicle.link_up, 10)
        autopilot.send(autopilot.codec.build("PARAM_REQUEST_LIST", 7, me))
        assert await wait_for(lambda: len(autopilot.of_type("PARAM_VALUE")) >= 7, 5)
        first = autopilot.of_type("PARAM_VALUE")[0]
        assert first.param_count == 7 and first.param_type == mav.MAV_PARAM_TYPE_REAL32
        assert _param_values(autopilot, "AVD_ENABLE") == [0.0]
        # Switch avoidance on and change the margin; an out-of-range speed is refused.
        for name, value in (("AVD_ENABLE", 1.0), ("AVD_MARGIN", 1.5), ("AVD_MAX_SPEED", 99.0)):
            autopilot.send(autopilot.codec.build("PARAM_SET", 7, me, name.encode(), value, 9))
        # Every set is answered (the refused one with the value unchanged).
        assert await wait_for(
            lambda: (
                _param_values(autopilot, "AVD_MAX_SPEED") == [3.0, 3.0]
                and len(_param_values(autopilot, "AVD_ENABLE")) == 2
                and len(_param_values(autopilot, "AVD_MARGIN")) == 2
            ),
            5,
        )
        assert _param_values(autopilot, "AVD_ENABLE")[-1] == 1.0
        assert _param_values(autopilot, "AVD_MARGIN")[-1] == 1.5
        assert daemon.avoidance.config.enabled and daemon.avoidance.planner.clearance_m == 2.0
        autopilot.send(autopilot.codec.build("PARAM_REQUEST_READ", 7, me, b"AVD_MARGIN", -1))
        assert await wait_for(lambda: len(_param_values(autopilot, "AVD_MARGIN")) == 3, 5)
    finally:
        await stop(daemon, task)
        await autopilot.stop()
    saved = json.loads(params_file.read_text())
    assert saved["AVD_ENABLE"] == 1.0 and saved["AVD_MARGIN"] == 1.5
    assert saved["AVD_MAX_SPEED"] == 3.0
    # Read back at the next start.
    from avoidd.config import AvoidanceConfig
    from avoidd.daemon.params import ParamTable

    # A saved AVD_ENABLE never switches avoidance on: the configuration must.
    table = ParamTable(AvoidanceConfig(params_file=params_file), params_file)
    assert not table.config.enabled and table.config.margin_m == 1.5
    table = ParamTable(AvoidanceConfig(enabled=True, params_file=params_file), params_file)
    assert table.config.enabled


async def test_goals_only_from_the_vehicle_or_a_ground_station_and_qgc_style_reads(
    tmp_path: Path,
) -> None:
    autopilot = MockAutopilot(system_id=7, mode="LOITER", armed=True)
    daemon, task = await _pair(tmp_path, autopilot)
    stranger = mav.Codec(99, 1)  # another vehicle on the network
    ground = mav.Codec(255, 190)
    try:
        assert await wait_for(lambda: daemon.vehicle.link_up, 10)
        me = mav.MAV_COMP_ID_OBSTACLE_AVOIDANCE

        def goal(codec: mav.Codec, north: float) -> Any:
            fields = (0, 7, me, mav.MAV_FRAME_LOCAL_NED, 0x0FF8, north, 0.0, -3.0)
            return codec.build("SET_POSITION_TARGET_LOCAL_NED", *fields, *([0.0] * 8))

        assert autopilot.transport is not None
        autopilot.transport.send(stranger.pack(goal(stranger, 50.0)))
        await asyncio.sleep(0.5)
        assert daemon.avoidance.goal.north_m == 30.0  # ignored
        heartbeat = ground.build("HEARTBEAT", mav.MAV_TYPE_GCS, 8, 0, 0, 0)
        autopilot.transport.send(ground.pack(heartbeat))
        autopilot.transport.send(ground.pack(goal(ground, 40.0)))
        assert await wait_for(lambda: daemon.avoidance.goal.north_m == 40.0, 5)
        # QGroundControl asks every component (0) for the parameter list.
        autopilot.transport.send(ground.pack(ground.build("PARAM_REQUEST_LIST", 7, 0)))
        assert await wait_for(lambda: len(autopilot.of_type("PARAM_VALUE")) >= 7, 5)
    finally:
        await stop(daemon, task)
        await autopilot.stop()


async def test_switching_avoidance_off_in_flight_holds_for_a_second_then_goes_silent(
    tmp_path: Path,
) -> None:
    autopilot = MockAutopilot(system_id=7, mode="GUIDED", armed=True)
    daemon, task = await _pair(tmp_path, autopilot)
    me = mav.MAV_COMP_ID_OBSTACLE_AVOIDANCE
    try:
        flying = {"moving", "dead end", "no path", "arrived"}
        assert await wait_for(
            lambda: daemon.avoidance is not None and daemon.avoidance.state in flying, 15
        )
        autopilot.send(autopilot.codec.build("PARAM_SET", 7, me, b"AVD_ENABLE", 0.0, 9))
        assert await wait_for(lambda: daemon.avoidance.state == "avoidance off", 5)
        start_count = len(_setpoints(autopilot))
        await asyncio.sleep(0.5)
        holding = _setpoints(autopilot)[start_count:]
        assert holding and all((m.vx, m.vy, m.vz) == (0, 0, 0) for m in holding)
        await asyncio.sleep(1.0)
        count = len(_setpoints(autopilot))
        await asyncio.sleep(0.5)
        assert len(_setpoints(autopilot)) <= count + 1
    finally:
        await stop(daemon, task)
        await autopilot.stop()


ORIGIN = (47.3977419, 8.5455938, 488.0)


def _item(seq: int, north_deg: float, east_deg: float, up_m: float) -> MissionItem:
    lat, lon = round((ORIGIN[0] + north_deg) * 1e7), round((ORIGIN[1] + east_deg) * 1e7)
    frame = mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
    return MissionItem(seq, frame, mav.MAV_CMD_NAV_WAYPOINT, lat, lon, up_m)


def _texts(autopilot: MockAutopilot) -> list[str]:
    return [m.text for m in autopilot.of_type("STATUSTEXT")]


async def test_global_goals_wait_for_the_origin_and_are_acknowledged(tmp_path: Path) -> None:
    autopilot = MockAutopilot(system_id=7, mode="GUIDED", armed=True, home_up_m=0.5)
    sections = {"avoidance": {"enabled": True}}
    daemon, task = await _pair(tmp_path, autopilot, sections)
    me = mav.MAV_COMP_ID_OBSTACLE_AVOIDANCE
    lat, lon = round((ORIGIN[0] + 0.001) * 1e7), round((ORIGIN[1] + 0.001) * 1e7)

    def acks(result: int) -> int:
        return sum(
            m.command == mav.MAV_CMD_DO_REPOSITION and m.result == result
            for m in autopilot.of_type("COMMAND_ACK")
        )

    reposition = autopilot.codec.build(
        "COMMAND_INT", 7, me, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
        mav.MAV_CMD_DO_REPOSITION, 0, 0, -1, 0, 0, math.nan, lat, lon, 10.0,
    )  # fmt: skip
    try:
        assert await wait_for(lambda: daemon.vehicle.link_up, 10)
        # No GPS yet: the autopilot has no origin, so a global goal cannot be placed.
        autopilot.send(reposition)
        assert await wait_for(lambda: acks(mav.MAV_RESULT_TEMPORARILY_REJECTED) == 1, 5)
        assert daemon.avoidance.goal is None
        refused = "avoidd: goal refused: no GPS origin yet"
        assert await wait_for(lambda: refused in _texts(autopilot), 5)
        # A fix: avoidd asks for the origin and home again and then takes the same command.
        autopilot.origin = ORIGIN
        assert await wait_for(lambda: daemon.vehicle.origin is not None, 6)
        assert await wait_for(lambda: daemon.vehicle.home_up_m is not None, 6)
        autopilot.send(reposition)
        assert await wait_for(lambda: acks(mav.MAV_RESULT_ACCEPTED) == 1, 5)
        goal = daemon.avoidance.goal
        assert goal.north_m == pytest.approx(111.32, abs=0.05)
        assert goal.east_m == pytest.approx(111.32 * math.cos(math.radians(47.398)), abs=0.05)
        assert goal.altitude_m == pytest.approx(10.5)  # 10 m above home, home 0.5 m up
        # SET_POSITION_TARGET_GLOBAL_INT, altitude above sea level: newest goal wins.
        target = autopilot.codec.build(
            "SET_POSITION_TARGET_GLOBAL_INT", 0, 7, me, mav.MAV_FRAME_GLOBAL_INT, 0x0FF8,
            lat, round(ORIGIN[1] * 1e7), 500.0, 0, 0, 0, 0, 0, 0, 0, 0,
        )  # fmt: skip
        autopilot.send(target)
        assert await wait_for(lambda: daemon.avoidance.goal.east_m == pytest.approx(0.0), 5)
        assert daemon.avoidance.goal.altitude_m == pytest.approx(12.0)
    finally:
        await stop(daemon, task)
        await autopilot.stop()


async def test_home_is_asked_again_after_each_arming(tmp_path: Path) -> None:
    """Both autopilots move home to where the vehicle stands when it arms."""
    autopilot = MockAutopilot(system_id=7, mode="GUIDED", armed=False, home_up_m=0.5)
    autopilot.origin = ORIGIN
    daemon, task = await _pair(tmp_path, autopilot, {"avoidance": {"enabled": True}})
    try:
        assert await wait_for(lambda: daemon.vehicle.home_up_m == pytest.approx(0.5), 10)
        # Home moves without an arming (nothing tells avoidd): the known home stays.
        autopilot.home_up_m = 1.25
        await asyncio.sleep(2.5)
        assert daemon.vehicle.home_up_m == pytest.approx(0.5)
        # Armed: avoidd asks again and takes the new home.
        autopilot.armed = True
        assert await wait_for(lambda: daemon.vehicle.home_up_m == pytest.approx(1.25), 6)
        # Disarmed, moved, armed again: once more.
        autopilot.armed = False
        assert await wait_for(lambda: not daemon.vehicle.mode.armed, 5)
        autopilot.home_up_m = -0.75
        autopilot.armed = True
        assert await wait_for(lambda: daemon.vehicle.home_up_m == pytest.approx(-0.75), 6)
    finally:
        await stop(daemon, task)
        await autopilot.stop()


async def test_the_mission_is_downloaded_despite_losses_flown_in_order_and_read_again(
    tmp_path: Path,
) -> None:
    # Item 0 is ArduPilot's home; waypoint 1 is where the vehicle hovers (reached at once);
    # waypoint 2 is 111 m north.
    mission = [_item(0, 0, 0, 0), _item(1, 0, 0, 1.5), _item(2, 0.001, 0, 1.5)]
    autopilot = MockAutopilot(
        system_id=7,
        mode="GUIDED",
        armed=True,
        origin=ORIGIN,
        mission=mission,
        mission_drops={("MISSION_COUNT", -1), ("MISSION_ITEM_INT", 1)},
        mission_repeats=True,
    )
    sections = {"avoidance": {"enabled": True, "follow_mission": True}}
    daemon, task = await _pair(tmp_path, autopilot, sections)
    try:
        assert await wait_for(lambda: "avoidd: reached waypoint 1" in _texts(autopilot), 20)
        assert await wait_for(lambda: daemon.avoidance.goal.label == "waypoint 2", 5)
        assert daemon.avoidance.goal.north_m == pytest.approx(111.32, abs=0.05)
        assert autopilot.counts["MISSION_ACK"] == 1
        # Each lost answer was asked for again, nothing more.
        lists = autopilot.counts["MISSION_REQUEST_LIST"]
        item_1 = [m.seq for m in autopilot.of_type("MISSION_REQUEST_INT")].count(1)
        assert (lists, item_1) == (2, 2)
        # A ground station uploads a new mission: avoidd reads it and starts over.
        autopilot.mission = [_item(0, 0, 0, 0), _item(1, 0, 0.002, 3.0)]
        assert await wait_for(lambda: daemon.avoidance.goal.east_m > 100.0, 8)
        assert daemon.avoidance.goal.label == "waypoint 1"
        assert daemon.avoidance.goal_source == "mission"
    finally:
        await stop(daemon, task)
        await autopilot.stop()


@contextlib.asynccontextmanager
async def _behind_endpoint(
    tmp_path: Path, mavlink: dict[str, Any] | None = None
) -> AsyncIterator[tuple[MockAutopilot, Any, int]]:
    """No router: the autopilot on avoidd's link, a ground-station endpoint of avoidd's own.

    Yields the autopilot, the daemon (once it knows the origin) and the endpoint's port.
    """
    autopilot = MockAutopilot(system_id=7, mode="GUIDED", armed=True, origin=ORIGIN)
    port, gcs_port = free_udp_port(), free_udp_port()
    await autopilot.start(f"udpin:127.0.0.1:{port}")
    link = {
        "connection": f"udpout:127.0.0.1:{port}",
        "gcs_connection": f"udpin:127.0.0.1:{gcs_port}",
        **(mavlink or {}),
    }
    sections = {"avoidance": {"enabled": True}, "mavlink": link}
    config = synthetic_config(tmp_path, f"udpout:127.0.0.1:{port}", sections=sections)
    daemon, task = await start(config)
    try:
        assert await wait_for(lambda: daemon.vehicle.origin is not None, 10)
        yield autopilot, daemon, gcs_port
    finally:
        await stop(daemon, task)
        await autopilot.stop()


async def test_goto_reaches_avoidd_through_its_own_ground_station_endpoint(
    tmp_path: Path,
) -> None:
    async with _behind_endpoint(tmp_path) as (autopilot, daemon, gcs_port):
        where = f"udpout:127.0.0.1:{gcs_port}"
        answer = await send_goal(where, LocalGoal(12.0, -4.0, 3.0), None, 20.0)
        assert (answer.accepted, answer.system_id) == (True, 7), answer.text
        assert daemon.avoidance.goal == Goal(12.0, -4.0, 3.0, "GCS goal")
        # A global goal avoidd refuses: the reason comes through the endpoint too.
        lat, lon = ORIGIN[0] + 0.0005, ORIGIN[1]
        refused = await send_goal(where, GlobalGoal(lat, lon, 0.2), None, 20.0)
        assert refused.accepted is False
        assert refused.text == "refused (MAV_RESULT_DENIED): less than 0.5 m above ground"
        # What the ground station sent reached the autopilot (its HEARTBEAT, unchanged).
        counts = daemon.gcs.counters()
        assert counts["to_autopilot"] > 0 and counts["to_gcs"] > 0
        assert any(m.get_srcSystem() == 255 for m in autopilot.of_type("HEARTBEAT"))
        # A ground station there hears the autopilot itself (forwarded) as well as avoidd.
        station = await open_udp_peer()
        gcs = mav.Codec(255, 190)
        beat = gcs.build(
            "HEARTBEAT", mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, mav.MAV_STATE_ACTIVE
        )
        station.transport.sendto(gcs.pack(beat), ("127.0.0.1", gcs_port))

        def heard(component: int) -> bool:
            return any(
                (m.get_srcSystem(), m.get_srcComponent()) == (7, component)
                for m in station.of_type("HEARTBEAT")
            )

        try:
            assert await wait_for(lambda: heard(1) and heard(196), 10)
        finally:
            station.close()


async def test_the_ground_station_endpoint_takes_no_command_the_link_would_not(
    tmp_path: Path,
) -> None:
    # The same trust rule as the autopilot's link: a sender that is neither the vehicle nor a
    # configured ground station commands nothing through the endpoint either.
    control = {"control": {"ground_stations": [250]}}
    async with _behind_endpoint(tmp_path, control) as (_, daemon, gcs_port):
        answer = await send_goal(
            f"udpout:127.0.0.1:{gcs_port}", LocalGoal(12.0, -4.0, 3.0), None, 3.0
        )
        assert answer.accepted is None and answer.system_id == 7  # heard, not obeyed
        assert answer.text.startswith("avoidd (system 7) heard, but it did not answer")
        assert daemon.avoidance.goal is None
        assert daemon.vehicle.refused_commands["sender"] > 0


async def test_nothing_from_the_ground_station_endpoint_is_taken_for_the_autopilot(
    tmp_path: Path,
) -> None:
    # A sender on the endpoint forges the autopilot's heartbeat, attitude and position (system
    # 7, component 1) before the real autopilot ever spoke: avoidd adopts nothing, its link
    # stays down and it holds no position. Forwarded to the autopilot's port, they are bytes.
    port, gcs_port = free_udp_port(), free_udp_port()
    sections = {
        "avoidance": {"enabled": True},
        "mavlink": {
            "connection": f"udpout:127.0.0.1:{port}",
            "gcs_connection": f"udpin:127.0.0.1:{gcs_port}",
        },
    }
    config = synthetic_config(tmp_path, f"udpout:127.0.0.1:{port}", sections=sections)
    daemon, task = await start(config)
    forger = await open_udp_peer()
    fake = mav.Codec(7, 1)
    messages = [
        fake.build("HEARTBEAT", mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_ARDUPILOTMEGA, 209, 4, 4),
        fake.build("ATTITUDE", 1000, 0.5, 0.0, 0.0, 0.0, 0.0, 0.0),
        fake.build("LOCAL_POSITION_NED", 1000, 999.0, 0.0, -2.0, 0.0, 0.0, 0.0),
    ]
    try:
        for _ in range(100):  # until 30 have been decoded, 10 s at most
            for message in messages:
                forger.transport.sendto(fake.pack(message), ("127.0.0.1", gcs_port))
            await asyncio.sleep(0.1)
            if daemon.gcs.counters().get("decoded", 0) >= 30:
                break
        assert daemon.gcs.counters().get("decoded", 0) >= 30, daemon.gcs.counters()
        await asyncio.sleep(0.5)
        assert not daemon.vehicle.link_up
        assert daemon.vehicle.mode is None and daemon.vehicle.position is None
    finally:
        forger.close()
        await stop(daemon, task)


async def test_goto_tells_no_avoidd_heard_from_avoidd_silent() -> None:
    # Nothing answers on the port: "no avoidd heard", with what to check.
    port = free_udp_port()
    answer = await send_goal(f"udpout:127.0.0.1:{port}", LocalGoal(1.0, 0.0, 2.0), None, 1.0)
    assert answer.accepted is None and answer.system_id is None
    assert answer.text.startswith("no avoidd heard within 1 s: nothing from MAVLink component 196")
    # With the vehicle's system given, silence is still "no avoidd heard".
    given = await send_goal(f"udpout:127.0.0.1:{port}", LocalGoal(1.0, 0.0, 2.0), 7, 1.0)
    assert given.text.startswith("no avoidd heard") and given.system_id is None


async def test_goto_reaches_avoidd_through_a_router_like_a_ground_station(tmp_path: Path) -> None:
    hub = await start_hub()
    autopilot = MockAutopilot(system_id=7, mode="GUIDED", armed=True, origin=ORIGIN)
    await autopilot.start(f"udpout:127.0.0.1:{hub.port}")
    sections = {"avoidance": {"enabled": True}}
    config = synthetic_config(tmp_path, f"udpout:127.0.0.1:{hub.port}", sections=sections)
    daemon, task = await start(config)
    try:
        assert await wait_for(lambda: daemon.vehicle.origin is not None, 10)
        # The library call: a local goal, the vehicle's system learned from avoidd's heartbeat.
        answer = await send_goal(f"udpout:127.0.0.1:{hub.port}", LocalGoal(12.0, -4.0, 3.0))
        assert (answer.accepted, answer.system_id) == (True, 7)
        assert answer.text == "avoidd: goal N12.0 E-4.0 A3.0"
        assert daemon.avoidance.goal == Goal(12.0, -4.0, 3.0, "GCS goal")
        # The command line, as a user types it: a global goal, then one avoidd refuses.
        lat, lon = ORIGIN[0] + 0.0005, ORIGIN[1]
        command = [sys.executable, "-m", "avoidd", "--log-level", "WARNING", "goto"]
        where = f"udpout:127.0.0.1:{hub.port}"
        for args, code, text in [
            (["--global", str(lat), str(lon), "6"], 0, "MAV_RESULT_ACCEPTED"),
            # The refusal says why: the reason of avoidd's STATUSTEXT with the ACK's result.
            (["--global", str(lat), str(lon), "0.2"], 1, "refused (MAV_RESULT_DENIED): "),
        ]:
            process = await asyncio.create_subprocess_exec(
                *command, where, *args, "--timeout", "20", stdout=asyncio.subprocess.PIPE
            )
            out, _ = await process.communicate()
            said = out.decode().strip()
            assert process.returncode == code and said.startswith(text), said
            assert "no reason given" not in said
            if code:
                assert len(said) > len(text) + 5, said
        assert daemon.avoidance.goal.north_m == pytest.approx(55.66, abs=0.05)
        assert daemon.avoidance.goal.altitude_m == pytest.approx(6.0)
    finally:
        await stop(daemon, task)
        await autopilot.stop()
        hub.close()
