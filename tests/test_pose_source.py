"""The external-simulation camera: frames rendered from the pose the autopilot reports."""

from __future__ import annotations

import math
import os
import signal
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from avoidd.config import MavlinkConfig, PerceptionConfig, load_config
from avoidd.config.sim import WorldConfig
from avoidd.errors import BrokenFrame, ConfigError, SourceError
from avoidd.loading import load_all
from avoidd.mavlink import codec as mav
from avoidd.mavlink.attitude import Attitude
from avoidd.mavlink.geo import GlobalPoint, north_east_m, offset_lat_lon
from avoidd.mavlink.link import MavLink
from avoidd.mavlink.mock_autopilot import MockAutopilot
from avoidd.mavlink.vehicle import Rangefinder, Vehicle
from avoidd.perception.pose import resolve_pose
from avoidd.sim import render_process
from avoidd.sim.lockstep import RIGS
from avoidd.sim.mav_autopilot import scan_from_message
from avoidd.sim.pose_source import PoseRenderedSource, VehiclePose, vehicle_pose
from avoidd.sim.render import StereoRenderer
from avoidd.sim.render_process import LocalRenderer, RenderProcess
from avoidd.sim.world import World
from avoidd.sources import open_source
from avoidd.types import Mount
from tests.helpers import free_udp_port, start_daemon, stop_daemon, synthetic_config, wait_for

COPTER = 2
WALL = {
    "version": 1,
    "seed": 5,
    "obstacles": [{"shape": "wall", "start_ne_m": [6, -5], "end_ne_m": [6, 5], "height_m": 6}],
}


def _renderer(seed: int = 0) -> LocalRenderer:
    world = World.from_config(WorldConfig.model_validate(WALL))
    return LocalRenderer(world, RIGS["320x240"], Mount(), seed=seed)


def _half_thickness(renderer: StereoRenderer) -> float:
    # Inside the wall the clearance is minus the depth to its nearer face.
    return -renderer.world.clearance_m(6.0, 0.0, 2.0)


def _vehicle() -> tuple[Vehicle, mav.Codec, MavLink]:
    config = MavlinkConfig(connection="udpout:127.0.0.1:9")
    link = MavLink(config.link, mav.Codec(1, 196))
    return Vehicle(link, config, lambda severity, text, key=None: None), mav.Codec(1, 1), link


def _feed(vehicle: Vehicle, link: MavLink, sender: mav.Codec, message: mav.Message) -> None:
    for decoded in link.codec.decode(sender.pack(message)):
        vehicle.handle(decoded, time.monotonic_ns())


def test_the_wall_ahead_comes_nearer_as_the_reported_pose_does() -> None:
    poses = iter(
        [VehiclePose(0.0, 0.0, -2.0, 0.0, 0.0, 0.0), VehiclePose(3.0, 0.0, -2.0, 0.0, 0.0, 0.0)]
    )
    local = _renderer(seed=1)
    renderer = local.renderer
    source = PoseRenderedSource(local, lambda t_ns: next(poses), fps=50.0)
    first, second = source.read(), source.read()
    assert (first.seq, second.seq) == (0, 1)
    assert second.t_capture_ns > first.t_capture_ns
    # No attitude (the daemon takes the autopilot's, as for a camera), but the height it was
    # rendered at, which the daemon prefers to a rangefinder that measures another truth.
    assert first.pose is not None and first.pose.height_m == 2.0
    assert math.isnan(first.pose.roll_deg) and math.isnan(first.pose.pitch_deg)
    config = PerceptionConfig()
    attitude = Attitude(0, 0.05, -0.02, 1.2)
    ranged = Rangefinder(first.t_capture_ns, 3.1)
    resolved = resolve_pose(first.t_capture_ns, first.pose, attitude, ranged, None, config)
    assert resolved.height_m == 2.0 and resolved.height_source == "simulator"
    assert resolved.source == "mavlink"
    assert resolved.roll_deg == pytest.approx(math.degrees(0.05))
    assert resolved.pitch_deg == pytest.approx(math.degrees(-0.02))
    # The left view's centre is the wall's face: 6 m less half its thickness, then 3 m less.
    face_m = 6.0 - _half_thickness(renderer)
    assert renderer.render(0.0, 0.0, -2.0, 0.0).depth_m[120, 160] == pytest.approx(face_m, abs=0.02)
    nearer = renderer.render(3.0, 0.0, -2.0, 0.0).depth_m[120, 160]
    assert nearer == pytest.approx(face_m - 3.0, abs=0.02)
    assert first.left.shape == (240, 320) and not np.array_equal(first.left, second.left)


def test_without_a_pose_a_frame_is_dropped_not_invented() -> None:
    source = PoseRenderedSource(_renderer(), lambda t_ns: None, fps=50.0, wait_s=0.05)
    with pytest.raises(BrokenFrame, match="no pose from the autopilot"):
        source.read()


def test_the_render_process_draws_what_the_local_renderer_does_in_a_session_of_its_own() -> None:
    world = World.from_config(WorldConfig.model_validate(WALL))
    local = LocalRenderer(world, RIGS["320x240"], Mount(), seed=4)
    remote = RenderProcess(world, RIGS["320x240"], Mount(), seed=4)
    try:
        for pose in [(0.0, 0.0, -2.0, 0.0, 0.0, 0.0), (2.5, 0.3, -2.2, 0.1, 3.0, -2.0)]:
            mine, theirs = local.render_pair(pose), remote.render_pair(pose)
            assert np.array_equal(mine[0], theirs[0]) and np.array_equal(mine[1], theirs[1])
        pid = remote.pid
        assert pid is not None
        # Its own session: the kernel shares the CPU out to it as to another program.
        assert os.getsid(pid) == pid != os.getsid(0)
    finally:
        remote.close()
    assert not _alive(pid)


def test_a_render_process_that_died_is_a_lost_camera_and_a_closed_one_is_gone() -> None:
    world = World.from_config(WorldConfig.model_validate(WALL))
    remote = RenderProcess(world, RIGS["320x240"], Mount())
    try:
        remote.render_pair((0.0, 0.0, -2.0, 0.0, 0.0, 0.0))
        pid = remote.pid
        assert pid is not None
        os.kill(pid, signal.SIGKILL)
        with pytest.raises(SourceError, match="renderer stopped"):
            for _ in range(3):  # the first send may still find the pipe open
                remote.render_pair((0.0, 0.0, -2.0, 0.0, 0.0, 0.0))
    finally:
        remote.close()
    assert not _alive(pid)


def test_a_late_renderer_is_broken_for_good_and_close_frees_a_waiting_thread(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # A late answer would pair a frame with the wrong pose: after a timeout the renderer
    # refuses every later frame and its child is gone.
    world = World.from_config(WorldConfig.model_validate(WALL))
    pose = (0.0, 0.0, -2.0, 0.0, 0.0, 0.0)
    late = RenderProcess(world, RIGS["320x240"], Mount())
    try:
        late.render_pair(pose)
        monkeypatch.setattr(render_process, "_PAIR_TIMEOUT_S", 0.3)
        os.kill(late.pid, signal.SIGSTOP)  # hung
        with pytest.raises(SourceError, match="gave no frame"):
            late.render_pair(pose)
        assert late.broken and not _alive(late.pid)
        with pytest.raises(SourceError, match="stopped earlier"):
            late.render_pair(pose)
    finally:
        late.close()
    # A capture thread waiting for a frame when the run ends: close() lets it go at once.
    waiting = RenderProcess(world, RIGS["320x240"], Mount())
    os.kill(waiting.pid, signal.SIGSTOP)
    failures: list[BaseException] = []

    def capture() -> None:
        try:
            waiting.render_pair(pose)
        except SourceError as exc:
            failures.append(exc)

    thread = threading.Thread(target=capture)
    thread.start()
    time.sleep(0.2)
    waiting.close()
    thread.join(10.0)
    assert not thread.is_alive() and len(failures) == 1
    assert not _alive(waiting.pid)
    waiting.close()  # twice is harmless


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    # A zombie not yet reaped counts as gone.
    with open(f"/proc/{pid}/stat") as stat:
        return stat.read().split(")")[-1].split()[0] != "Z"


def test_the_pose_is_the_autopilots_newest_report_shifted_to_the_world() -> None:
    vehicle, sender, link = _vehicle()
    pose_at = vehicle_pose(vehicle, offset_ne_m=(10.0, -2.0), max_age_ns=500_000_000)
    beat = sender.build("HEARTBEAT", COPTER, mav.MAV_AUTOPILOT_ARDUPILOTMEGA, 1, 4, 4)
    _feed(vehicle, link, sender, beat)
    assert pose_at(time.monotonic_ns()) is None  # nothing heard yet
    _feed(vehicle, link, sender, sender.build("ATTITUDE", 1000, 0.05, -0.02, 1.2, 0, 0, 0))
    assert pose_at(time.monotonic_ns()) is None  # an attitude alone is no pose
    position = sender.build("LOCAL_POSITION_NED", 1000, 3.0, 4.0, -2.5, 0.0, 0.0, 0.0)
    _feed(vehicle, link, sender, position)
    pose = pose_at(time.monotonic_ns())
    assert pose is not None
    assert (pose.north_m, pose.east_m, pose.down_m) == pytest.approx((13.0, 2.0, -2.5))
    assert (pose.roll_rad, pose.pitch_rad, pose.yaw_rad) == pytest.approx((0.05, -0.02, 1.2))
    # A position report older than the limit is no pose: the autopilot went quiet.
    assert pose_at(vehicle.position_received_ns + 600_000_000) is None


@pytest.mark.parametrize(
    ("lat_deg", "lon_deg", "north_m", "east_m"),
    [(-35.363261, 149.16523, 30.0, -4.0), (47.0, 179.9999, 12.0, 50.0), (60.0, 0.0, -900.0, 0.0)],
)
def test_offset_lat_lon_inverts_north_east(
    lat_deg: float, lon_deg: float, north_m: float, east_m: float
) -> None:
    origin = GlobalPoint(lat_deg, lon_deg, 0.0)
    lat, lon = offset_lat_lon(origin, north_m, east_m)
    assert -180.0 <= lon <= 180.0
    back = north_east_m(origin, lat, lon)
    assert math.hypot(back[0] - north_m, back[1] - east_m) < 1e-6


WORLDS = Path(__file__).resolve().parents[1] / "sitl" / "worlds"


async def test_a_sim_head_in_the_daemon_sees_the_world_from_the_autopilots_pose(
    tmp_path: Path,
) -> None:
    """``source: {kind: sim}``: avoidd run against an autopilot that simulates the vehicle."""
    # The autopilot reports the vehicle 4 m south of the world's wall line, 2.5 m up, level,
    # heading north; the wall (12 m ahead of the world's origin) is then 8 m away, less half
    # its thickness.
    autopilot = MockAutopilot(
        system_id=7, attitude=lambda _t: (0.0, 0.0, 0.0), position_ned=(4.0, 0.0, -2.5)
    )
    port = free_udp_port()
    await autopilot.start(f"udpin:127.0.0.1:{port}")
    source = {
        "kind": "sim",
        "world": str(WORLDS / "wall-ahead.yaml"),
        "fps": 10,
        "origin_ne_m": [0, 0],
    }
    config = synthetic_config(tmp_path, f"udpout:127.0.0.1:{port}", source=source)
    daemon, task = await start_daemon(config)
    try:

        def wall_seen() -> bool:
            scans = [scan_from_message(m) for m in autopilot.of_type("OBSTACLE_DISTANCE")]
            return any(abs(int(scan[0]) - 785) <= 40 for scan in scans)

        assert await wait_for(wall_seen, 20.0), [
            int(scan_from_message(m)[0]) for m in autopilot.of_type("OBSTACLE_DISTANCE")[-5:]
        ]
    finally:
        await stop_daemon(daemon, task)
        await autopilot.stop()


def test_check_config_refuses_a_broken_world_and_replay_explains(tmp_path: Path) -> None:
    world = tmp_path / "world.yaml"
    world.write_text("version: 1\nobstacles:\n  - {shape: wall, start_ne_m: [1, 2]}\n")
    source = {"kind": "sim", "world": str(world)}
    config = synthetic_config(tmp_path, "udpout:127.0.0.1:14550", source=source)
    with pytest.raises(ConfigError) as refused:
        load_all(config)
    assert any("world.yaml:3" in line for line in refused.value.lines), refused.value.lines
    with pytest.raises(SourceError, match="only `avoidd run`"):
        open_source(load_config(config).heads[0].source, RIGS["320x240"], "front", False)
