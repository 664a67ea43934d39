"""The simulated vehicle as an autopilot on a MAVLink link, and avoidd's daemon flying it in
real time (``avoidd sim run --realtime``)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from avoidd.cli import main
from avoidd.config.sim import load_scenario
from avoidd.mavlink import codec as mav
from avoidd.sim.flight import SimAutopilot
from avoidd.sim.gcs import GroundStation
from avoidd.sim.mav_autopilot import SimulatedAutopilot, scan_from_message
from avoidd.sim.realtime import RealtimeRun
from avoidd.sim.vehicle import Multirotor
from tests.helpers import free_udp_port, wait_for

SCENARIOS = Path(__file__).resolve().parents[1] / "sitl" / "scenarios"
S = 1_000_000_000


def _fly(rules: SimAutopilot, vehicle: Multirotor, seconds: float, t0_ns: int = 0) -> int:
    """Step the rules and the vehicle for ``seconds`` of simulated time; the end time."""
    now_ns = t0_ns
    for _ in range(round(seconds / 0.01)):
        state = vehicle.state
        velocity, yaw_rate = rules.command(
            now_ns, state.yaw_rad, position_ned=state.position_m, velocity_ned=state.velocity_m_s
        )
        vehicle.step(0.01, velocity, yaw_rate)
        now_ns += 10_000_000
    return now_ns


def test_arducopter_arms_takes_off_holds_and_lands() -> None:
    rules, vehicle = SimAutopilot(mode="LAND", armed=False), Multirotor()
    assert not rules.arm(True, 0)  # LAND does not arm
    assert rules.set_mode("GUIDED", 0) and rules.arm(True, 0)
    assert not rules.takeoff(0.1, 0)  # below 0.5 m is no take-off
    assert rules.takeoff(3.0, 0)
    t_ns = _fly(rules, vehicle, 8.0)
    assert vehicle.state.altitude_m == pytest.approx(3.0, abs=0.3)
    t_ns = _fly(rules, vehicle, 3.0, t_ns)  # then it holds there
    assert vehicle.state.altitude_m == pytest.approx(3.0, abs=0.3)
    assert np.hypot(*vehicle.state.position_m[:2]) < 0.2
    rules.set_mode("LAND", t_ns)
    _fly(rules, vehicle, 12.0, t_ns)
    assert vehicle.state.altitude_m < 0.06 and not rules.armed  # landed and disarmed


def test_guided_position_targets_and_stabilize_coasts() -> None:
    rules, vehicle = SimAutopilot(mode="GUIDED", armed=True), Multirotor()
    vehicle.state.position_m = np.array([0.0, 0.0, -2.0])
    rules.position_setpoint(np.array([10.0, -5.0, -2.0]), 0)
    t_ns = _fly(rules, vehicle, 10.0)
    assert np.linalg.norm(vehicle.state.position_m - [10.0, -5.0, -2.0]) < 0.3
    rules.setpoint(np.array([2.0, 0.0, 0.0]), 0.0, t_ns)
    t_ns = _fly(rules, vehicle, 2.0, t_ns)
    rules.set_mode("STABILIZE", t_ns)  # level, no braking: it keeps going
    before = vehicle.state.position_m.copy()
    _fly(rules, vehicle, 2.0, t_ns)
    assert vehicle.state.position_m[0] - before[0] > 2.5
    rules.set_mode("LOITER", t_ns)  # holds
    t_ns = _fly(rules, vehicle, 4.0, t_ns)
    assert np.hypot(*vehicle.state.velocity_m_s[:2]) < 0.1


@pytest.mark.parametrize(("increment", "offset", "count"), [(5.0, -20.0, 72), (10.0, 0.0, 36)])
def test_obstacle_distance_reads_back_in_both_layouts(
    increment: float, offset: float, count: int
) -> None:
    codec = mav.Codec(1, 196)
    distances = [65535] * 72
    ahead = round(-offset / increment)  # the message bin that points straight ahead
    distances[ahead] = 350
    message = codec.build("OBSTACLE_DISTANCE", 0, 0, distances, 0, 20, 2000, increment, offset, 12)
    decoded = next(iter(codec.decode(codec.pack(message))))
    scan = scan_from_message(decoded)
    assert scan[0] == 350
    assert (scan == 350).sum() == round(increment / 5.0)
    assert (scan == 65535).sum() == 72 - round(increment / 5.0)
    assert count == round(360 / increment)


async def test_the_simulated_autopilot_answers_a_ground_station_and_flies() -> None:
    port = free_udp_port()
    autopilot = SimulatedAutopilot(mode="STABILIZE", armed=False)
    await autopilot.start(f"udpin:127.0.0.1:{port}")
    gcs = GroundStation(f"udpout:127.0.0.1:{port}")
    await gcs.open()
    try:
        await gcs.wait_heartbeat(5.0)
        assert await gcs.request_message_interval("LOCAL_POSITION_NED", 20.0) == 0
        assert await gcs.set_mode("ardupilot", "LAND") == 0
        assert await gcs.command(400, 1.0) == mav.MAV_RESULT_DENIED  # not in LAND
        assert await gcs.set_mode("ardupilot", "GUIDED") == 0
        assert await gcs.command(400, 1.0) == 0
        assert await gcs.command(22, 0, 0, 0, 0, 0, 0, 2.0) == 0
        beat = await gcs.next_message(lambda m: m.get_type() == "HEARTBEAT", 3.0)
        assert beat is not None and beat.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED

        def climbed() -> bool:
            heard = gcs.of_type("LOCAL_POSITION_NED")
            return bool(heard) and -heard[-1].z > 1.7

        assert await wait_for(climbed, 15.0)
    finally:
        await gcs.close()
        await autopilot.stop()


@pytest.mark.timeout(120)
async def test_avoidds_daemon_stops_the_simulated_vehicle_at_a_wall_in_real_time() -> None:
    run = RealtimeRun(load_scenario(SCENARIOS / "wall-headon.yaml"))
    summary = await run.run(free_udp_port())
    print(summary.as_json())
    assert summary.samples and not summary.collided, summary.as_json()
    # It flew towards the pocket's back wall and stopped short of it, at about its margin.
    assert max(s.north_m for s in summary.samples) > 8.0
    assert summary.min_clearance_m > 0.5, summary.as_json()
    assert summary.reached_s is None
    sent = run.autopilot.counts
    assert sent["SET_POSITION_TARGET_LOCAL_NED"] > 50 and sent["OBSTACLE_DISTANCE"] > 50


@pytest.mark.timeout(120)
async def test_px4_takes_offboard_from_avoidds_prestream_in_real_time() -> None:
    scenario = load_scenario(SCENARIOS / "px4-offboard.yaml").model_copy(update={"duration_s": 10})
    run = RealtimeRun(scenario)
    summary = await run.run(free_udp_port())
    print(summary.as_json())
    # The timeline's switch at 2 s is accepted only because avoidd already streams setpoints.
    assert "OFFBOARD" in [mode for _, mode in run.autopilot.rules.mode_changes], summary
    assert not summary.collided, summary.as_json()
    travelled = max(s.north_m for s in summary.samples) - summary.samples[0].north_m
    assert travelled > 5.0, summary.as_json()


def test_reported_position_and_attitude_carry_the_asked_noise() -> None:
    autopilot = SimulatedAutopilot(position_noise_m=0.2, attitude_noise_rad=0.01, noise_seed=3)
    autopilot.vehicle.state.position_m = np.array([4.0, -2.0, -3.0])
    position_id, attitude_id = mav.message_id("LOCAL_POSITION_NED"), mav.message_id("ATTITUDE")
    positions = [autopilot.stream_message(position_id) for _ in range(400)]
    north = np.array([m.x for m in positions if m is not None])
    assert north.mean() == pytest.approx(4.0, abs=0.05) and north.std() == pytest.approx(
        0.2, rel=0.2
    )
    attitudes = [autopilot.stream_message(attitude_id) for _ in range(400)]
    roll = np.array([m.roll for m in attitudes if m is not None])
    assert roll.std() == pytest.approx(0.01, rel=0.2)
    exact = SimulatedAutopilot()
    exact.vehicle.state.position_m = np.array([4.0, -2.0, -3.0])
    message = exact.stream_message(position_id)
    assert message is not None and (message.x, message.y, message.z) == (4.0, -2.0, -3.0)


@pytest.mark.timeout(120)
def test_sim_run_realtime_prints_the_table_and_writes_the_picture(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    scenario = tmp_path / "headon.yaml"
    scenario.write_text(
        (SCENARIOS / "wall-headon.yaml")
        .read_text()
        .replace("../worlds/pocket.yaml", str(SCENARIOS.parent / "worlds" / "pocket.yaml"))
        .replace("duration_s: 10", "duration_s: 6")
    )
    out = tmp_path / "out"
    code = main(["sim", "run", str(scenario), "--realtime", "--out", str(out)])
    printed = capsys.readouterr().out
    header, line = printed.splitlines()[:2]
    assert header.split()[:4] == ["scenario", "seed", "coll", "min"]
    assert line.split()[:3] == ["wall-headon", "planner", "no"], printed
    report = json.loads((out / "summary.json").read_text())
    assert report["trace"] and report["collided"] is False
    assert (out / "plot.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert code == (0 if report["passed"] else 1)
