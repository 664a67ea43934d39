"""avoidd against a real ArduCopter SITL: how ArduPilot reads OBSTACLE_DISTANCE, what it does
when avoidd loses its camera, and avoidd after an autopilot reboot."""

from __future__ import annotations

import asyncio
import math
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from avoidd.daemon import Daemon
from avoidd.daemon.outputs import Outputs
from avoidd.errors import SourceError
from avoidd.loading import load_all
from avoidd.mavlink import codec as mav
from avoidd.mavlink.layout import ARDUPILOT_LAYOUT
from avoidd.mavlink.mission import MissionItem
from avoidd.sim.ardupilot import ArduPilotSitl
from avoidd.sources import open_source
from avoidd.types import SectorScan
from tests.helpers import free_udp_port, great_circle_ne, synthetic_config, wait_for
from tests.test_wire_layout import ardupilot_sectors

pytestmark = pytest.mark.sitl

PROXIMITY = 1 << 26  # MAV_SYS_STATUS_SENSOR_PROXIMITY
FRONT, FRONT_RIGHT = 10, 11  # ArduPilot's proximity DISTANCE_SENSOR ids: 10 + sector

# A box in the right half of the front sector (+11 deg, 2.8 m), a pole in its left half
# (-15 deg, 6 m) and a box in the front-right sector (+35 deg, 4 m): with bin 0 straight
# ahead, ArduPilot used to keep only the left half of the front sector (6 m, not 2.8 m).
SCENE = {
    "kind": "synthetic",
    "fps": 10,
    "seed": 3,
    "obstacles": [
        {"shape": "box", "forward_m": 3.0, "right_m": 0.6, "width_m": 0.4, "depth_m": 0.4},
        {"shape": "pole", "forward_m": 6.0, "right_m": -1.6, "width_m": 0.3},
        {"shape": "box", "forward_m": 3.4, "right_m": 2.3, "width_m": 0.6, "depth_m": 0.4},
    ],
}


async def _sitl_and_daemon(
    sitl_dir: Path,
    tmp_path: Path,
    sections: dict[str, Any] | None = None,
    mavlink: dict[str, Any] | None = None,
    **daemon_args: Any,
) -> tuple[ArduPilotSitl, Daemon, asyncio.Task[int]]:
    port = free_udp_port()
    sitl = ArduPilotSitl(sitl_dir, port)
    await sitl.__aenter__()
    config_path = synthetic_config(
        tmp_path,
        f"udpin:127.0.0.1:{port}",
        source=SCENE,
        mavlink={"system_id": "auto", **(mavlink or {})},
        pipeline={"max_age_ms": 300, "log_interval_s": 5.0},
        sections=sections,
    )
    config, calibrations = load_all(config_path)
    daemon = Daemon(config, calibrations, **daemon_args)
    return sitl, daemon, asyncio.create_task(daemon.run())


async def _stop(sitl: ArduPilotSitl, daemon: Daemon, task: asyncio.Task[int]) -> None:
    daemon.stop()
    try:
        assert await asyncio.wait_for(task, 10.0) == 0
    finally:
        await sitl.stop()


async def test_ardupilot_keeps_the_nearest_object_of_each_sector(
    sitl_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    sent: list[tuple[int, Any]] = []
    build = Outputs.obstacle_distance_message

    def recording(self: Outputs, now_ns: int) -> Any:
        message = build(self, now_ns)
        if message is not None:
            sent.append((time.monotonic_ns(), message))
        return message

    monkeypatch.setattr(Outputs, "obstacle_distance_message", recording)
    sitl, daemon, task = await _sitl_and_daemon(sitl_dir, tmp_path)
    try:
        gcs = sitl.gcs
        assert gcs is not None
        assert await gcs.request_message_interval("DISTANCE_SENSOR", 10) == 0
        assert await gcs.request_message_interval("SYS_STATUS", 5) == 0
        assert await wait_for(lambda: daemon.vehicle.link_up, 20.0)
        assert await wait_for(
            lambda: len([m for m in gcs.of_type("DISTANCE_SENSOR") if m.id == FRONT]) > 5, 20.0
        )
        since = time.monotonic_ns()
        await asyncio.sleep(5.0)
        reports = [
            (h.received_ns, h.message)
            for h in gcs.heard
            if h.received_ns >= since
            and h.message.get_type() == "DISTANCE_SENSOR"
            and h.message.id in (FRONT, FRONT_RIGHT)
        ]
        statuses = gcs.of_type("SYS_STATUS", since)
    finally:
        await _stop(sitl, daemon, task)
    # What ArduPilot reports for a sector is what avoidd sent for it: the nearest of its
    # bins, as the model of its folding (tests/test_wire_layout.py) gives it from each message
    # avoidd sent in the second before (ArduPilot smooths a sector's distance over updates).
    front = []
    for received_ns, report in reports:
        recent = [m for t, m in sent if received_ns - 1_000_000_000 <= t <= received_ns]
        expected = [
            ardupilot_sectors(list(m.distances), ARDUPILOT_LAYOUT).get(report.id - FRONT)
            for m in recent
        ]
        expected_cm = [100 * e for e in expected if e is not None]
        assert expected_cm, f"ArduPilot reports sector {report.id - FRONT}, avoidd sent none"
        low, high = min(expected_cm), max(expected_cm)
        assert 0.95 * low - 5 <= report.current_distance <= 1.05 * high + 5, (
            report.id,
            report.current_distance,
            low,
            high,
        )
        if report.id == FRONT:
            front.append(report.current_distance)
    print(f"front sector {min(front)}..{max(front)} cm over {len(front)} reports")
    # Every report of the front sector is the box at 2.8 m (its nearest corner 2.83 m), in
    # the sector's right half, never the pole at 6 m in its left half.
    assert len(front) >= 30
    assert all(255 <= d <= 300 for d in front), sorted(set(front))
    # And ArduPilot calls its proximity sensor present and healthy throughout.
    assert statuses and all(s.onboard_control_sensors_health & PROXIMITY for s in statuses)


class Unpluggable:
    """Opens the real source; once ``unplugged`` is set, every read fails like a lost camera."""

    def __init__(self) -> None:
        self.unplugged_ns: int | None = None

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        if self.unplugged_ns is not None:
            raise SourceError("camera 'front': /dev/video0 does not exist (unplugged)")
        inner = open_source(*args, **kwargs)
        outer = self

        class Camera:
            description = "unpluggable camera"

            def read(self) -> Any:
                if outer.unplugged_ns is not None:
                    raise SourceError("camera 'front': no frame (unplugged)")
                return inner.read()

            def close(self) -> None:
                inner.close()

        return Camera()


async def test_ardupilot_says_no_data_within_a_second_of_losing_the_camera(
    sitl_dir: Path, tmp_path: Path
) -> None:
    camera = Unpluggable()
    sitl, daemon, task = await _sitl_and_daemon(sitl_dir, tmp_path, open_source=camera)
    try:
        gcs = sitl.gcs
        assert gcs is not None
        assert await gcs.request_message_interval("SYS_STATUS", 20) == 0
        healthy = lambda: any(  # noqa: E731
            s.onboard_control_sensors_health & PROXIMITY
            for s in gcs.of_type("SYS_STATUS", time.monotonic_ns() - 200_000_000)
        )
        assert await wait_for(healthy, 30.0), "proximity never became healthy"
        await asyncio.sleep(1.0)
        camera.unplugged_ns = time.monotonic_ns()
        sick = await gcs.next_message(
            lambda m: (
                m.get_type() == "SYS_STATUS" and not m.onboard_control_sensors_health & PROXIMITY
            ),
            5.0,
        )
        lost_s = (time.monotonic_ns() - camera.unplugged_ns) / 1e9
        # While the camera is gone nothing is sent to ArduPilot (no message of unknown bins).
        sent = daemon.sent["OBSTACLE_DISTANCE"]
        await asyncio.sleep(1.0)
        assert daemon.sent["OBSTACLE_DISTANCE"] == sent
        # avoidd's own STATUSTEXT, which ArduPilot forwards to its ground station.
        texts = [
            h.message.text
            for h in gcs.heard
            if h.message.get_type() == "STATUSTEXT" and h.message.get_srcComponent() == 196
        ]
    finally:
        await _stop(sitl, daemon, task)
    print(f"proximity unhealthy {lost_s:.2f} s after the camera was unplugged")
    assert sick is not None
    assert lost_s <= 1.0
    assert "avoidd: front stale, camera lost" in texts or "avoidd: front camera lost" in texts


async def test_streams_come_back_within_two_seconds_of_a_reboot(
    sitl_dir: Path, tmp_path: Path
) -> None:
    sitl, daemon, task = await _sitl_and_daemon(sitl_dir, tmp_path)
    try:
        gcs = sitl.gcs
        assert gcs is not None
        vehicle = daemon.vehicle
        assert await wait_for(lambda: vehicle.link_up and vehicle.streams_acknowledged, 30.0)
        assert await wait_for(lambda: daemon.received["ATTITUDE"] > 50, 10.0)
        # MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN: reboot the autopilot (it is disarmed).
        asked_ns = time.monotonic_ns()
        assert await gcs.command(246, 1.0) == 0
        # The autopilot is back when avoidd hears it heartbeat again after a gap (it beats at
        # 1 Hz). Read on avoidd's own link: the ground station's TCP connection to SITL may
        # take longer to come back than the autopilot does.
        # Or, after avoidd counted a reboot (its boot clock went back: a quick reboot leaves no
        # long gap), at the first heartbeat after that. Not the heartbeat before it: avoidd also
        # counts a reboot when all its streams stop, which comes before the autopilot is back.
        seen = [vehicle.last_heartbeat_ns or 0]
        reboots_before = vehicle.reboots
        back_at: list[int] = []
        counted_at: list[int] = []

        def heartbeat_after_gap() -> bool:
            latest = vehicle.last_heartbeat_ns or 0
            if latest != seen[0]:
                if latest - seen[0] > 1_200_000_000 or (counted_at and latest > counted_at[0]):
                    back_at.append(latest)
                seen[0] = latest
            if not counted_at and vehicle.reboots > reboots_before:
                counted_at.append(time.monotonic_ns())
            return bool(back_at)

        assert await wait_for(heartbeat_after_gap, 30.0), "the autopilot did not come back"
        back_ns = back_at[0]
        attitude_before = daemon.received["ATTITUDE"]
        streams_back = await wait_for(
            lambda: daemon.received["ATTITUDE"] > attitude_before + 10, 5.0
        )
        took_s = (time.monotonic_ns() - back_ns) / 1e9

        # avoidd says it saw the reboot: its boot clock went back for 0.2 s of messages (which
        # may end after the streams are back, when a busy machine reads them in bursts), or
        # the link went down and came up again.
        def noticed() -> bool:
            # Not of_type(): avoidd's STATUSTEXT reaches the ground station through ArduPilot
            # but comes from avoidd's component, not the autopilot's.
            texts = [
                h.message.text
                for h in gcs.heard
                if h.received_ns >= asked_ns and h.message.get_type() == "STATUSTEXT"
            ]
            return vehicle.reboots > reboots_before or any("link up" in t for t in texts)

        noticed_in_5_s = await wait_for(noticed, 5.0)
        rebooted = vehicle.reboots
    finally:
        await _stop(sitl, daemon, task)
    print(f"streams back {took_s:.2f} s after the autopilot's first heartbeat; reboots {rebooted}")
    assert streams_back and took_s <= 2.0
    assert noticed_in_5_s, "avoidd saw neither the boot clock go back nor the link come back"


async def test_mission_and_reposition_from_a_real_ardupilot(sitl_dir: Path, tmp_path: Path) -> None:
    """avoidd reads the mission a ground station uploaded to ArduPilot (item 0, home, skipped)
    and takes a DO_REPOSITION the ground station addresses to it through ArduPilot's routing."""
    sections = {"avoidance": {"enabled": True, "follow_mission": True}}
    sitl, daemon, task = await _sitl_and_daemon(sitl_dir, tmp_path, sections)
    try:
        gcs = sitl.gcs
        assert gcs is not None
        # The EKF origin is set once the simulated GPS has a fix; avoidd asks until it has it.
        assert await wait_for(lambda: daemon.vehicle.origin is not None, 90.0)
        origin = daemon.vehicle.origin
        assert origin is not None
        home_lat, home_lon = -35.363261, 149.165230  # the SITL's --home
        assert abs(origin.lat_deg - home_lat) < 1e-4 and abs(origin.lon_deg - home_lon) < 1e-4
        frame = mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT

        def at(d_lat: float, d_lon: float, seq: int, up_m: float, command: int = 16) -> MissionItem:
            lat, lon = round((home_lat + d_lat) * 1e7), round((home_lon + d_lon) * 1e7)
            return MissionItem(seq, frame, command, lat, lon, up_m)

        mission = [
            at(0, 0, 0, 0),  # home, as ground stations send it
            at(0, 0, 1, 10, command=22),  # NAV_TAKEOFF: not a waypoint
            at(0.0004, 0.0003, 2, 12),
            at(0.0008, -0.0002, 3, 15),
        ]
        assert await gcs.upload_mission(mission) == 0
        # Read on avoidd's next look (MISSION_CURRENT's total, or the 15 s refresh).
        assert await wait_for(
            lambda: (
                daemon.avoidance.goal is not None and daemon.avoidance.goal.label == "waypoint 2"
            ),
            25.0,
        )
        goal = daemon.avoidance.goal
        north, east = great_circle_ne(
            origin.lat_deg, origin.lon_deg, home_lat + 0.0004, home_lon + 0.0003
        )
        assert math.hypot(goal.north_m - north, goal.east_m - east) < 0.1, (goal, north, east)
        home_up = daemon.vehicle.home_up_m
        assert home_up is not None and abs(home_up) < 1.0
        assert goal.altitude_m == pytest.approx(12.0 + home_up)
        # A ground station on ArduPilot's own port addresses avoidd (component 196): ArduPilot
        # routes the command to avoidd's link and avoidd's answer back.
        system = daemon.vehicle.system_id
        lat, lon = round((home_lat - 0.0005) * 1e7), round(home_lon * 1e7)
        ack = asyncio.ensure_future(
            gcs.next_message(
                lambda m: (
                    m.get_type() == "COMMAND_ACK"
                    and m.get_srcComponent() == mav.MAV_COMP_ID_OBSTACLE_AVOIDANCE
                    and m.command == mav.MAV_CMD_DO_REPOSITION
                ),
                10.0,
            )
        )
        await asyncio.sleep(0)
        reposition = gcs.codec.build(
            "COMMAND_INT", system, mav.MAV_COMP_ID_OBSTACLE_AVOIDANCE, frame,
            mav.MAV_CMD_DO_REPOSITION, 0, 0, -1, 0, 0, math.nan, lat, lon, 8.0,
        )  # fmt: skip
        gcs.send(reposition)
        answer = await ack
        assert answer is not None and answer.result == mav.MAV_RESULT_ACCEPTED
        goal = daemon.avoidance.goal
        assert goal.label == "GCS goal" and daemon.avoidance.goal_source == "gcs"
        assert goal.north_m == pytest.approx(
            great_circle_ne(origin.lat_deg, origin.lon_deg, lat / 1e7, lon / 1e7)[0], abs=0.1
        )
    finally:
        await _stop(sitl, daemon, task)


def _sector_reports(gcs: Any, sector_id: int, since_ns: int) -> list[int]:
    return [
        h.message.current_distance
        for h in gcs.heard
        if h.received_ns >= since_ns
        and h.message.get_type() == "DISTANCE_SENSOR"
        and h.message.id == sector_id
    ]


@pytest.mark.parametrize("fill", [False, True])
async def test_ardupilot_reads_an_unknown_bin_beside_a_reading_as_that_reading(
    sitl_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, fill: bool
) -> None:
    # What perception handed on: a surface at 3 m at +20 deg (the front sector's last bin),
    # the rest of the front sector clear, and the three bins of the front-right sector the
    # camera sees (+25 to +35 deg) unknown: the surface there could not be vouched for.
    distance = np.full(72, np.nan, dtype=np.float32)
    distance[[68, 69, 70, 71, 0, 1, 2, 3]] = np.inf
    distance[4] = 3.0

    def scan(self: Outputs, now_ns: int) -> SectorScan:
        return SectorScan(now_ns, distance.copy())

    monkeypatch.setattr(Outputs, "current_scan", scan)
    sitl, daemon, task = await _sitl_and_daemon(
        sitl_dir, tmp_path, mavlink={"obstacle_distance": {"fill_from_neighbours": fill}}
    )
    try:
        gcs = sitl.gcs
        assert gcs is not None
        assert await gcs.request_message_interval("DISTANCE_SENSOR", 10) == 0
        assert await wait_for(lambda: daemon.vehicle.link_up, 20.0)
        assert await wait_for(lambda: len(_sector_reports(gcs, FRONT, 0)) > 5, 20.0)
        since_ns = time.monotonic_ns()
        await asyncio.sleep(3.0)
        front = _sector_reports(gcs, FRONT, since_ns)
        front_right = _sector_reports(gcs, FRONT_RIGHT, since_ns)
    finally:
        await _stop(sitl, daemon, task)
    print(f"fill {fill}: front {sorted(set(front))}, front-right {sorted(set(front_right))} cm")
    assert front and all(295 <= d <= 305 for d in front), front
    if fill:
        # The unknown bin at +25 deg went out as 3 m: ArduPilot's front-right sector holds it.
        assert len(front_right) >= 10 and all(295 <= d <= 305 for d in front_right), front_right
    else:
        # 65535 there: ArduPilot holds nothing in that sector, as if it were empty.
        assert all(d > 2000 for d in front_right), front_right
