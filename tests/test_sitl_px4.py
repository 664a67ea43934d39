"""avoidd against a real PX4 SITL (SIH physics): discovery and restart, collision prevention on
avoidd's OBSTACLE_DISTANCE, and avoidd's planner flying OFFBOARD.

PX4's ports are fixed (its GCS link sends to UDP 14550, its onboard link to 14540): these tests
run one PX4 at a time. Each waits for PX4's estimator (ready about 1.5 s after boot with
avoidd.params' EKF2_ANGERR_INIT) and then lets it settle for 20 s before arming.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import math
import time
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest
from pymavlink import mavutil

from avoidd.config.sim import load_scenario
from avoidd.daemon import Daemon
from avoidd.daemon.outputs import Outputs
from avoidd.errors import LinkError
from avoidd.loading import load_all
from avoidd.mavlink import codec as mav
from avoidd.planner.core import Goal
from avoidd.sim.external import window_around_minimum
from avoidd.sim.gcs import GroundStation
from avoidd.sim.px4 import Px4Sitl
from avoidd.sim.px4_run import Px4Run
from tests.helpers import synthetic_config, wait_for

pytestmark = [pytest.mark.sitl, pytest.mark.timeout(300)]

SCENARIOS = Path(__file__).resolve().parents[1] / "sitl" / "px4"
MAV_AUTOPILOT_PX4 = 12
UNKNOWN_CM = 65535


async def test_px4_discovery_streams_arming_and_restart(px4_sitl_dir: Path, tmp_path: Path) -> None:
    """avoidd recognises PX4, decodes its mode and arming, gets its streams, and sees it restart.

    PX4 SITL v1.15.4 denies MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN (MAV_RESULT_DENIED, seen): then
    the test restarts its process, as a power cycle would, and watches avoidd take it up again.
    """
    sitl = Px4Sitl(px4_sitl_dir)
    t0 = time.monotonic()
    gcs = await sitl.start()
    async with _stopped_on_error(sitl):
        config, calibrations = load_all(
            synthetic_config(
                tmp_path,
                sitl.onboard_connection,
                mavlink={"system_id": "auto"},
                pipeline={"max_age_ms": 300, "log_interval_s": 5.0},
            )
        )
        daemon = Daemon(config, calibrations)
    task = asyncio.create_task(daemon.run())
    try:
        vehicle = daemon.vehicle
        assert await wait_for(lambda: vehicle.link_up and vehicle.mode is not None, 20.0)
        beat = gcs.of_type("HEARTBEAT")[-1]
        assert beat.autopilot == MAV_AUTOPILOT_PX4
        assert vehicle.mode is not None and vehicle.mode.autopilot == "PX4"
        assert not vehicle.mode.armed
        # avoidd's decoding of PX4's mode is the ground station's (pymavlink's own table).
        assert await wait_for(lambda: _same_mode(daemon, gcs), 5.0), _px4_mode(gcs)
        first_mode = vehicle.mode.name
        assert first_mode in {"POSCTL", "LOITER"}, first_mode
        # PX4 sends ATTITUDE only once its estimator has settled.
        ready_s = await sitl.wait_estimator(120.0)
        assert await wait_for(lambda: vehicle.streams_acknowledged, 10.0)
        attitude, position = daemon.received["ATTITUDE"], daemon.received["LOCAL_POSITION_NED"]
        await asyncio.sleep(2.0)
        attitude_hz = (daemon.received["ATTITUDE"] - attitude) / 2.0
        position_hz = (daemon.received["LOCAL_POSITION_NED"] - position) / 2.0
        # Arming as PX4 reports it, in a take-off that cannot reach its height (10 m, above
        # MIS_TAKEOFF_ALT): the failure says what PX4 did, its console included.
        with pytest.raises(LinkError) as failed:
            await sitl.take_off(10.0, tries=1, climb_s=8.0)
        assert await wait_for(lambda: vehicle.mode is not None and vehicle.mode.armed, 5.0)
        assert await wait_for(lambda: _same_mode(daemon, gcs), 5.0), _px4_mode(gcs)
        airborne_mode = vehicle.mode.name
        assert airborne_mode in {"TAKEOFF", "LOITER"}, airborne_mode
        story = str(failed.value)
        # "taking off": PX4's take-off has begun (it ends "in air" unless the take-off stalls,
        # which a CI run saw here too).
        assert "TAKEOFF armed" in story and "taking off" in story, story
        assert "Armed by external command" in story or "Takeoff detected" in story, story
        assert await gcs.disarm_to_retry() == mav.MAV_RESULT_ACCEPTED  # in the air: by force
        assert await wait_for(lambda: vehicle.mode is not None and not vehicle.mode.armed, 5.0)
        # MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN. PX4 SITL either reboots in place (its boot clock
        # starts over) or its process ends; for the latter, start the process again.
        process = sitl.process
        assert process is not None
        reboots = vehicle.reboots
        result = await gcs.command(246, 1.0)
        await wait_for(lambda: process.returncode is not None or vehicle.reboots > reboots, 15.0)
        exited = process.returncode is not None
        restart_ns = time.monotonic_ns()
        if exited or result != mav.MAV_RESULT_ACCEPTED:
            # This SITL denies the command (MAV_RESULT_DENIED, seen): restart the process, as a
            # power cycle or a supervisor would.
            restart_ns = time.monotonic_ns()
            await sitl.restart()
        assert await wait_for(lambda: vehicle.link_up, 20.0)
        # Its boot clock started over: avoidd forgets its state and asks for the streams again.
        assert await wait_for(lambda: vehicle.reboots > reboots, 15.0), (result, exited)
        back_s = (time.monotonic_ns() - restart_ns) / 1e9
        position = daemon.received["LOCAL_POSITION_NED"]
        assert await wait_for(lambda: vehicle.streams_acknowledged, 15.0)
        assert await wait_for(lambda: daemon.received["LOCAL_POSITION_NED"] > position + 10, 5.0)
    finally:
        daemon.stop()
        try:
            assert await asyncio.wait_for(task, 30.0) == 0
        finally:
            await sitl.stop()
    print(
        f"\nPX4 first mode {first_mode}; estimator ready after {ready_s:.1f} s; ATTITUDE "
        f"{attitude_hz:.0f} Hz, LOCAL_POSITION_NED {position_hz:.0f} Hz; reboot command "
        f"MAV_RESULT {result}, process exited: {exited}; reboot seen {back_s:.1f} s after the "
        f"command or restart; test {time.monotonic() - t0:.0f} s; a take-off to 10 m: {story}"
    )
    assert ready_s < 90.0
    assert attitude_hz >= 20 and position_hz >= 5


def _record_sent(monkeypatch: pytest.MonkeyPatch) -> list[tuple[int, Any]]:
    """Every OBSTACLE_DISTANCE avoidd sends from now on, with the time it was built."""
    sent: list[tuple[int, Any]] = []
    build = Outputs.obstacle_distance_message

    def recording(self: Outputs, now_ns: int) -> Any:
        message = build(self, now_ns)
        if message is not None:
            sent.append((time.monotonic_ns(), message))
        return message

    monkeypatch.setattr(Outputs, "obstacle_distance_message", recording)
    return sent


def _longest_gap_s(sent: list[tuple[int, Any]]) -> float:
    """The longest pause in avoidd's OBSTACLE_DISTANCE stream (PX4 drops data older than 0.5 s:
    a loaded machine's pause shows here when PX4 stops a push early)."""
    times = [t for t, _ in sent]
    return max((b - a for a, b in itertools.pairwise(times)), default=0) / 1e9


def _folded(distances: list[int]) -> list[int]:
    return [int(d) for d in distances[:36]]


def _push_story(run: Px4Run, sent: list[tuple[int, Any]]) -> str:
    """Second by second from the push's start: where the vehicle was, how fast, and the nearest
    reading avoidd sent (None: every bin unknown), with what avoidd and PX4 said: why a push
    went wrong."""
    summary = run.summary
    story = []
    for second in range(int(summary.flight_s) + 1):
        samples = [x for x in summary.samples if second <= x.t_s < second + 1]
        start_ns, end_ns = run._t0_ns + second * 10**9, run._t0_ns + (second + 1) * 10**9
        maps = [m for t, m in sent if start_ns <= t < end_ns]
        known = [
            (d, 10 * (i if i < 18 else i - 36))  # PX4's layout: 36 ten-degree bins
            for m in maps
            for i, d in enumerate(_folded(m.distances))
            if d != UNKNOWN_CM
        ]
        nearest = f"{min(known)[0]} cm at {min(known)[1]} deg" if known else None
        if samples:
            x = samples[-1]
            story.append(
                f"{second}s N{x.north_m:.1f} E{x.east_m:.1f} up {x.altitude_m:.1f} "
                f"{x.speed_m_s:.1f}m/s maps {len(maps)} nearest {nearest}"
            )
    vehicle = run.daemon.vehicle if run.daemon is not None else None
    return (
        f"{'; '.join(story)}; home {run.home_up_m:.2f} m above PX4's origin (avoidd's now "
        f"{vehicle and vehicle.home_up_m}); reboots seen {vehicle and vehicle.reboots}; "
        f"heading before lining up {run.heading_before_push_deg}; PX4's estimate "
        f"{run.start_moved_m} m from the start before the push (the world moved there); "
        f"avoidd {summary.states}; PX4 said {summary.autopilot_said}"
    )


async def test_px4_collision_prevention_stops_a_pushed_vehicle_on_avoidd_data(
    px4_sitl_dir: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Position mode, MPC_POS_MODE 0, CP_DIST 2: full forward stick at a wall 12 m ahead."""
    sent = _record_sent(monkeypatch)
    t0 = time.monotonic()
    scenario = load_scenario(SCENARIOS / "wall-stop.yaml")
    run = Px4Run(scenario, px4_sitl_dir, mode="push", cp_dist_m=2.0)
    summary = await run.run()
    gcs = run.gcs
    assert gcs is not None
    closest = min(summary.samples, key=lambda s: s.clearance_m)
    radius_m = scenario.avoidance.vehicle_radius_m
    print(
        f"\npush: closest approach edge {closest.clearance_m:.2f} m (centre "
        f"{closest.clearance_m + radius_m:.2f} m, CP_DIST 2.0) at {closest.t_s:.1f} s; top speed "
        f"{max(s.speed_m_s for s in summary.samples):.1f} m/s; end N{summary.final_ne_m[0]:.2f}; "
        f"longest gap between avoidd's OBSTACLE_DISTANCE {_longest_gap_s(sent):.2f} s; "
        f"heading before lining up {run.heading_before_push_deg:.1f} deg; estimate "
        f"{run.start_moved_m:.2f} m from the start before it; end E"
        f"{summary.final_ne_m[1]:.2f}; test {time.monotonic() - t0:.0f} s"
    )
    print(_push_story(run, sent))  # shown when a later assertion fails
    assert not summary.collided, _push_story(run, sent)
    assert summary.passed, f"{summary.failures}: {_push_story(run, sent)}"
    # Full stick moved it most of the way (PX4 flew), and it stopped short of the wall (the
    # scenario's closest approach). How near PX4 lets it come is PX4's (seen: 1.4-1.8 m from
    # the centre with CP_DIST 2, braking from 3 m/s); what avoidd told it is avoidd's: its
    # forward reading when the vehicle was closest is the distance to the wall, within a
    # stereo camera's error at that range.
    assert max(s.north_m for s in summary.samples) > 6.0
    true_m = closest.clearance_m + radius_m
    closest_ns = run._t0_ns + int(closest.t_s * 1e9)
    ahead = [
        d / 100.0
        for t, m in sent
        if abs(t - closest_ns) <= 300_000_000
        for d in (_folded(m.distances)[i] for i in (35, 0, 1))  # -10, 0, +10 degrees
        if d != UNKNOWN_CM
    ]
    assert ahead, f"avoidd reported nothing ahead when the wall was {true_m:.2f} m away"
    assert abs(min(ahead) - true_m) <= max(0.3, 0.15 * true_m), (min(ahead), true_m)
    # PX4's merged map (streamed back on the GCS link) is what avoidd sent: each PX4 bin that
    # holds a reading equals one avoidd sent for the same or a neighbouring bin within the
    # second before (PX4 1.15 keeps its map in the body frame, ten-degree bins from straight
    # ahead, and fills each from the message bin at the ceiling of its angle, so a reading can
    # land one bin over). Checked during the push only: PX4 1.15 forgets a bin's reading after
    # 0.5 s without news only while the stick asks for motion (CollisionPrevention's
    # _calculateConstrainedSetpoint), so before the push a bin avoidd no longer vouches for
    # keeps its last reading however old; from 0.5 s into the push every held reading is
    # recent. (Before the push the count is printed, not asserted.)
    pushing_ns = run._t0_ns + 500_000_000
    echoes = [
        h
        for h in gcs.heard
        if h.message.get_type() == "OBSTACLE_DISTANCE" and gcs.from_autopilot(h.message)
    ]
    assert len(echoes) >= 20, "PX4 streamed no OBSTACLE_DISTANCE back"
    checked = mismatched = 0
    unpushed = {"checked": 0, "mismatched": 0}
    for heard in echoes:
        echo = heard.message
        assert echo.increment == 10 or round(echo.increment_f) == 10
        pushing = heard.received_ns >= pushing_ns
        recent = [
            _folded(m.distances)
            for t, m in sent
            if heard.received_ns - 1_500_000_000 <= t <= heard.received_ns
        ]
        if not recent:
            continue
        for index, value in enumerate(_folded(echo.distances)):
            if value >= UNKNOWN_CM or value > echo.max_distance:
                continue
            candidates = {row[(index + k) % 36] for row in recent for k in (-1, 0, 1)} - {
                UNKNOWN_CM
            }
            matches = any(abs(value - c) <= max(10, 0.05 * c) for c in candidates)
            if pushing:
                checked += 1
                mismatched += not matches
            else:
                unpushed["checked"] += 1
                unpushed["mismatched"] += not matches
    # And the other way: a bin in which every map avoidd sent in the 0.45 s before an echo
    # held a reading (PX4 keeps one for 0.5 s, and a newer "clear" would replace it) has a
    # reading in PX4's map, in the same or a neighbouring bin.
    max_cm = sent[-1][1].max_distance  # avoidd's: beyond it a bin is clear
    covered = dropped = 0
    for heard in echoes:
        echo = heard.message
        before = [
            _folded(m.distances)
            for t, m in sent
            if heard.received_ns - 450_000_000 <= t <= heard.received_ns - 50_000_000
        ]
        if not before:
            continue
        held = _folded(echo.distances)
        for index in range(36):
            if any(row[index] >= UNKNOWN_CM or row[index] > max_cm for row in before):
                continue
            covered += 1
            near = [held[(index + k) % 36] for k in (-1, 0, 1)]
            if all(v >= UNKNOWN_CM or v > echo.max_distance for v in near):
                dropped += 1
    print(
        f"PX4 echoed {len(echoes)} maps; in the push {checked} readings checked, {mismatched} "
        f"mismatched (before it {unpushed['checked']} and {unpushed['mismatched']}); "
        f"{covered} of avoidd's readings looked for in them, {dropped} missing"
    )
    assert checked >= 100
    assert mismatched <= 0.05 * checked
    assert covered >= 100
    assert dropped <= 0.05 * covered
    # Stopped: full stick still held, the vehicle no longer flies at the wall in the last
    # 3 s (unblocked it flies at over 3 m/s).
    last = [x for x in summary.samples if x.t_s >= summary.flight_s - 3.0]
    assert last and max(x.speed_m_s for x in last) < 1.0, [x.speed_m_s for x in last]


async def test_px4_blocks_motion_into_bins_avoidd_reports_unknown_after_its_camera_is_lost(
    px4_sitl_dir: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Position mode, CP_GO_NO_DATA 0: full forward stick while avoidd's camera is unplugged.

    avoidd sends every bin as unknown (65535) once its data is stale, PX4's merged map holds no
    reading, and the vehicle stays put; with the camera back it flies on and stops at the wall.
    """
    sent = _record_sent(monkeypatch)
    t0 = time.monotonic()
    scenario = load_scenario(SCENARIOS / "blind-push.yaml")
    replug_s = next(a.t_s for a in scenario.timeline if a.action == "camera_replug")
    run = Px4Run(scenario, px4_sitl_dir, mode="push", cp_dist_m=2.0, params={"CP_GO_NO_DATA": 0})
    summary = await run.run()
    gcs = run.gcs
    assert gcs is not None and run._t0_ns > 0
    push_ns = run._t0_ns
    pushed = [s for s in summary.samples if s.t_s >= 0.0]
    start_north = pushed[0].north_m
    # Unplugged at 0 s: avoidd's data is stale after its max age (0.3 s), and PX4 keeps a bin
    # for 0.5 s after its last reading; meanwhile full stick accelerates the vehicle, which
    # then brakes. From 3 s on it must hold still until the camera is back. Whether PX4 held
    # is read on PX4's LOCAL_POSITION_NED as the ground station hears it.
    estimate = [
        (
            (h.received_ns - push_ns) / 1e9,
            float(h.message.x),
            math.hypot(h.message.vx, h.message.vy),
        )
        for h in gcs.heard
        if h.message.get_type() == "LOCAL_POSITION_NED"
        and gcs.from_autopilot(h.message)
        and h.received_ns >= push_ns
    ]
    stopping = [e for e in estimate if e[0] < 3.0]
    held = [e for e in estimate if 3.0 <= e[0] <= replug_s]
    stop_travel = max(e[1] for e in stopping) - estimate[0][1]
    held_travel = max(e[1] for e in held) - min(e[1] for e in held)
    into_unknown = max(e[1] for e in held) - held[0][1]
    total_travel = max(s.north_m for s in pushed) - start_north
    closest = min(pushed, key=lambda s: s.clearance_m)
    print(
        f"\nblind push: stopped after {stop_travel:.2f} m (top speed "
        f"{max(e[2] for e in stopping):.2f} m/s), then {held_travel:.2f} m of drift over "
        f"{replug_s - 3:.0f} s at full stick ({into_unknown:.2f} m of it on into the unknown; "
        f"top speed {max(e[2] for e in held):.2f} m/s); with the camera back "
        f"{total_travel:.2f} m in all, closest edge "
        f"{closest.clearance_m:.2f} m; heading before lining up "
        f"{run.heading_before_push_deg:.1f} deg; test {time.monotonic() - t0:.0f} s"
    )
    print(_push_story(run, sent))  # shown when a later assertion fails
    # avoidd said "unknown" in every bin while blind (within its max age of the unplug).
    unknown = [m for t, m in sent if push_ns + 1_000_000_000 <= t <= push_ns + replug_s * 1e9]
    assert len(unknown) >= 50
    assert all(set(_folded(m.distances)) == {UNKNOWN_CM} for m in unknown)
    # PX4's merged map held no reading in that time.
    echoes = [
        h.message
        for h in gcs.heard
        if h.message.get_type() == "OBSTACLE_DISTANCE"
        and gcs.from_autopilot(h.message)
        and push_ns + 2_000_000_000 <= h.received_ns <= push_ns + replug_s * 1e9
    ]
    assert len(echoes) >= 10
    # No data (UINT16_MAX), not "clear" (max_distance + 1): PX4 knows it has no reading.
    assert all(set(_folded(e.distances)) == {UNKNOWN_CM} for e in echoes), [
        sorted(set(_folded(e.distances))) for e in echoes
    ]
    # Full stick, and the vehicle did not move into the unknown: from where it was at 3 s, it
    # got no farther north (PX4 holding in Position mode drifts, mostly back: see
    # ``held_travel``); and it never flew (full stick unblocked is over 3 m/s).
    assert stop_travel < 4.0
    assert into_unknown < 0.5 and max(e[2] for e in held) < 0.8
    # With the camera back, it flew on, without a collision (how near collision prevention
    # lets it come is test_px4_collision_prevention_stops_a_pushed_vehicle_on_avoidd_data's).
    assert not summary.collided
    seen_again = [m for t, m in sent if t > push_ns + replug_s * 1e9]
    known = [m for m in seen_again if set(_folded(m.distances)) != {UNKNOWN_CM}]
    assert total_travel > 4.0, (
        f"with the camera back: {len(known)} of avoidd's {len(seen_again)} maps knew a bin; "
        f"{_push_story(run, sent)}"
    )


async def test_px4_offboard_planner_flies_round_the_wall_and_yields_to_the_pilot(
    px4_sitl_dir: Path,
) -> None:
    """avoidd prestreams, the GCS switches to OFFBOARD, avoidd flies round the wall to the goal
    with its clearance kept; Position mode then stops its setpoints at once."""
    t0 = time.monotonic()
    run = Px4Run(load_scenario(SCENARIOS / "wall-around.yaml"), px4_sitl_dir, mode="planner")
    summary = await run.run()
    edges = sorted(s.clearance_m for s in summary.samples)
    print(
        f"\nplanner: {summary.as_json()}; edge clearance 1 % quantile "
        f"{edges[int(0.01 * (len(edges) - 1))] if edges else None}; "
        f"OFFBOARD {run.offboard_s} s after the request; "
        f"setpoints after Position mode {run.setpoints_after_release}; sticks' longest gap "
        f"{run.sticks.longest_gap_s if run.sticks else None} s; "
        f"test {time.monotonic() - t0:.0f} s"
    )
    # The scenario's criteria: no collision, goal within 60 s, and the built-in simulator's
    # clearance: the edge 0.9 m from the wall in 99 % of the samples. A failure shows the
    # flight around its closest approach: where, how fast, what the planner wanted.
    around = "\n".join(s.describe() for s in window_around_minimum(summary.samples, 4.0))
    assert summary.passed, (
        f"{summary.failures}; states {summary.states}; PX4 said {summary.autopilot_said}; "
        f"around the closest approach:\n{around}"
    )
    # Nor a brief dip the 1 % quantile would let through.
    assert summary.min_clearance_m >= 0.5, around
    assert run.offboard_s is not None
    assert run.setpoints_after_release == 0


def _state(daemon: Daemon) -> str | None:
    return None if daemon.avoidance is None else daemon.avoidance.state


def _px4_mode(gcs: GroundStation) -> str:
    beat = gcs.of_type("HEARTBEAT")[-1]
    return str(mavutil.interpret_px4_mode(beat.base_mode, beat.custom_mode))


def _same_mode(daemon: Daemon, gcs: GroundStation) -> bool:
    """avoidd's decoded mode and armed state are what the ground station's last HEARTBEAT says."""
    mode = daemon.vehicle.mode
    beat = gcs.of_type("HEARTBEAT")[-1]
    armed = bool(beat.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED)
    return mode is not None and (mode.name, mode.armed) == (_px4_mode(gcs), armed)


@contextlib.asynccontextmanager
async def _stopped_on_error(sitl: Px4Sitl) -> AsyncIterator[None]:
    """Stop a started PX4 when setting up the rest of a test fails (nothing left running)."""
    try:
        yield
    except BaseException:
        await sitl.stop()
        raise


async def test_px4_leaves_offboard_when_avoidd_stops_and_a_restarted_avoidd_waits(
    px4_sitl_dir: Path, tmp_path: Path
) -> None:
    """avoidd stopped in OFFBOARD: PX4 falls back to Position mode after COM_OF_LOSS_T (1 s).
    avoidd started again stays silent (PX4 holds in Position mode); a new goal while PX4's
    failsafe is in effect still sends nothing (setpoints would end the failsafe and put PX4
    back in OFFBOARD by itself); once the pilot picks Position mode avoidd prestreams, and when
    OFFBOARD is entered again it flies."""
    t0 = time.monotonic()
    sitl = Px4Sitl(px4_sitl_dir)
    gcs = await sitl.start()
    sticks = gcs.sticks()  # neutral, 20 Hz: Position mode needs a pilot's manual control
    sections = {
        "avoidance": {
            "enabled": True,
            "unknown": "free",
            "goal": {"north_m": 10.0, "east_m": 0.0, "altitude_m": 3.0},
        }
    }
    async with _stopped_on_error(sitl):
        config, calibrations = load_all(
            synthetic_config(
                tmp_path,
                sitl.onboard_connection,
                source={"kind": "synthetic", "fps": 10, "seed": 3, "obstacles": []},
                mavlink={"system_id": "auto"},
                pipeline={"max_age_ms": 300, "log_interval_s": 5.0},
                sections=sections,
            )
        )
        daemon = Daemon(config, calibrations)
    task: asyncio.Task[int] | None = asyncio.create_task(daemon.run())
    try:
        await sitl.wait_estimator(120.0)
        await sitl.take_off(2.0)  # tries again when a take-off stalls; says why it failed
        assert await wait_for(lambda: daemon.avoidance.state == "prestream", 20.0)
        await asyncio.sleep(1.5)
        assert await gcs.set_mode("px4", "OFFBOARD") == mav.MAV_RESULT_ACCEPTED
        assert await wait_for(lambda: _px4_mode(gcs) == "OFFBOARD", 5.0)
        assert await wait_for(lambda: daemon.avoidance.state not in {"prestream", "stale"}, 5.0)
        await asyncio.sleep(3.0)  # avoidd flies
        # avoidd stops: its setpoints end.
        loop = daemon.avoidance
        daemon.stop()
        assert await asyncio.wait_for(task, 30.0) == 0
        task = None
        assert await wait_for(lambda: _px4_mode(gcs) != "OFFBOARD", 10.0)
        # From the last setpoint; heard on PX4's next HEARTBEAT: never before the switch, up
        # to a beat after it.
        fallback_s = (time.monotonic_ns() - loop.last_sent_ns) / 1e9
        fallback_mode = _px4_mode(gcs)
        # avoidd again: PX4 flies armed in Position mode; avoidd stays silent. (PX4 would go
        # back to OFFBOARD by itself as soon as setpoints came back: its failsafe clears.)
        daemon = Daemon(config, calibrations)
        task = asyncio.create_task(daemon.run())
        flies = "pilot flies; waiting for a new goal"
        assert await wait_for(lambda: _state(daemon) == flies, 20.0)
        since = time.monotonic_ns()
        await asyncio.sleep(4.0)
        modes = {
            str(mavutil.interpret_px4_mode(m.base_mode, m.custom_mode))
            for m in gcs.of_type("HEARTBEAT", since)
        }
        track = gcs.of_type("LOCAL_POSITION_NED", since)
        speeds = [math.hypot(m.vx, m.vy) for m in track]
        # The last second of the silent window (PX4's own clock: loaded machines stretch ours).
        last_s = [
            math.hypot(m.vx, m.vy) for m in track if m.time_boot_ms >= track[-1].time_boot_ms - 1000
        ]
        # From 2 s into the window on (PX4's clock), braking from avoidd's speed is over.
        after_2s = [
            math.hypot(m.vx, m.vy) for m in track if m.time_boot_ms >= track[0].time_boot_ms + 2000
        ]
        assert _state(daemon) == flies
        assert daemon.avoidance is not None and daemon.avoidance.sent == 0
        statuses = {m.system_status for m in gcs.of_type("HEARTBEAT", since)}
        # A new goal while PX4's failsafe is in effect (its HEARTBEAT says CRITICAL): a
        # prestream now would end the failsafe and PX4 would return to OFFBOARD by itself, so
        # avoidd waits for the pilot.
        assert daemon.vehicle.mode is not None and daemon.vehicle.mode.failsafe, statuses
        daemon.avoidance.set_goal(Goal(12.0, 0.0, 3.0, "GCS goal"))
        waiting = "autopilot failsafe; waiting for the pilot to pick a mode"
        assert await wait_for(lambda: _state(daemon) == waiting, 5.0), _state(daemon)
        goal_ns = time.monotonic_ns()
        await asyncio.sleep(2.5)  # PX4 needs a second of setpoints for OFFBOARD
        failsafe_modes = {
            str(mavutil.interpret_px4_mode(m.base_mode, m.custom_mode))
            for m in gcs.of_type("HEARTBEAT", goal_ns)
        }
        sent_in_failsafe = daemon.avoidance.sent
        # The pilot picks Position mode: the failsafe is over, avoidd prestreams, OFFBOARD is
        # entered, and avoidd flies.
        assert await gcs.set_mode("px4", "POSCTL") == mav.MAV_RESULT_ACCEPTED
        assert await wait_for(lambda: _state(daemon) == "prestream", 5.0), _state(daemon)
        await asyncio.sleep(1.5)
        prestream_modes = {_px4_mode(gcs)}
        prestreamed = daemon.avoidance.sent
        assert await gcs.set_mode("px4", "OFFBOARD") == mav.MAV_RESULT_ACCEPTED
        assert await wait_for(lambda: _px4_mode(gcs) == "OFFBOARD", 5.0)
        planning = {"moving", "dead end", "no path", "arrived"}
        assert await wait_for(lambda: _state(daemon) in planning, 10.0), _state(daemon)
        flying_state = _state(daemon)
    finally:
        sticks.stop()
        if task is not None:
            daemon.stop()
            with contextlib.suppress(Exception):
                await asyncio.wait_for(task, 30.0)
        await sitl.stop()
    print(
        f"\nloss: PX4 left OFFBOARD {fallback_s:.2f} s after avoidd's last setpoint, into "
        f"{fallback_mode}; restarted avoidd silent 4 s, PX4 in {sorted(modes)}, speed "
        f"{speeds[0]:.2f} m/s at first, at most {max(speeds):.2f}, in the last second at most "
        f"{max(last_s):.2f} m/s, from 2 s on at most {max(after_2s):.2f} m/s; its HEARTBEAT "
        f"system_status {sorted(statuses)}; a goal in the failsafe: {sent_in_failsafe} "
        f"setpoints, PX4 in {sorted(failsafe_modes)}; in Position mode: "
        f"{prestreamed} prestream setpoints, PX4 in "
        f"{sorted(prestream_modes)}; after OFFBOARD: {flying_state}; sticks' longest gap "
        f"{sticks.longest_gap_s:.2f} s; test {time.monotonic() - t0:.0f} s"
    )
    assert fallback_mode == "POSCTL"
    # COM_OF_LOSS_T 1 s after the last setpoint, heard up to a heartbeat (1 s) later.
    assert 0.95 <= fallback_s <= 3.0
    assert modes == {"POSCTL"} and prestream_modes == {"POSCTL"}
    assert statuses == {mav.MAV_STATE_CRITICAL}
    assert sent_in_failsafe == 0 and failsafe_modes == {"POSCTL"}
    # PX4 brakes from avoidd's last speed (how far it got depends on when the window starts:
    # a quick restart catches it at 2.4 m/s) and holds: nothing pushes the vehicle while avoidd
    # is silent. Holding in Position mode, PX4 itself drifts: up to 0.27 m/s idle, 0.48 m/s
    # with both cores busy.
    assert max(speeds) <= max(speeds[0], 1.0) + 0.2
    assert max(after_2s) < 1.0
    assert max(last_s) < 0.6
