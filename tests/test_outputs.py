"""DISTANCE_SENSOR and OBSTACLE_DISTANCE_3D: encoding, orientation, and a two-head daemon."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from avoidd.errors import ConfigError
from avoidd.loading import load_all
from avoidd.mavlink.codec import Codec
from avoidd.mavlink.layout import read_bins
from avoidd.mavlink.messages import (
    UNKNOWN_CM,
    DistanceSensorHead,
    nearest_points,
    sensor_orientation,
)
from avoidd.types import Mount, RectifiedRig, SectorScan
from tests.helpers import (
    MavlinkPeer,
    beat_as_generic_autopilot,
    open_udp_peer,
    start_daemon,
    stop_daemon,
    synthetic_config,
    wait_for,
    write_rectified_calibration,
)

RIG = RectifiedRig(320, 240, 200.0, 200.0, 159.5, 119.5, 0.12)


@pytest.mark.parametrize(
    ("yaw", "pitch", "expected"),
    [
        (0.0, 0.0, 0),
        (45.0, 0.0, 1),
        (90.0, 0.0, 2),  # to the right: MAV_SENSOR_ROTATION_YAW_90, clockwise seen from above
        (180.0, 0.0, 4),
        (-90.0, 0.0, 6),  # to the left is YAW_270
        (315.0, 0.0, 7),
        (-45.0, 1.5, 7),
        (0.0, -20.0, 0),  # a forward camera looking down still measures horizontal range
        (90.0, 30.0, 2),
        # Its reading is a horizontal range, never a height: no PITCH_270 (down) or PITCH_90.
        (0.0, -90.0, None),
        (0.0, 90.0, None),
        (0.0, -31.0, None),
        (30.0, 0.0, None),
    ],
)
def test_sensor_orientation(yaw: float, pitch: float, expected: int | None) -> None:
    assert sensor_orientation(Mount(yaw_deg=yaw, pitch_deg=pitch)) == expected


def _scan(values: dict[int, float], default: float = np.nan) -> SectorScan:
    distance = np.full(72, default, dtype=np.float32)
    for index, value in values.items():
        distance[index] = value
    return SectorScan(0, distance)


def test_distance_sensor_reading_and_round_trip() -> None:
    head = DistanceSensorHead(RIG, Mount(yaw_deg=90.0), 1)
    # Covered bins of a 77-degree head at +90: 11..25.
    clear = _scan({i: np.inf for i in range(11, 26)})
    assert head.reading_cm(clear, 20, 2000) == 2001
    assert head.reading_cm(_scan({18: 3.456} | {i: np.inf for i in range(11, 18)}), 20, 2000) == 346
    # Unknown bins and no obstacle: nothing can be vouched for.
    assert head.reading_cm(_scan({12: np.inf}), 20, 2000) is None
    # An obstacle outside its field of view is not its reading.
    assert head.reading_cm(_scan({0: 1.0} | {i: np.inf for i in range(11, 26)}), 20, 2000) == 2001
    codec = Codec(7, 196)
    data = codec.pack(head.message(codec, 1234, 346, 20, 2000, 0.42))
    peer = MavlinkPeer()
    peer.feed(data)
    (message,) = peer.of_type("DISTANCE_SENSOR")
    assert message.orientation == 2 and message.id == 1 and message.current_distance == 346
    assert message.time_boot_ms == 1234 and message.signal_quality == 42
    assert message.horizontal_fov == pytest.approx(math.radians(RIG.hfov_deg), rel=1e-6)
    assert message.vertical_fov == pytest.approx(2 * math.atan(120 / 200), rel=1e-6)
    assert message.quaternion == pytest.approx([math.cos(math.pi / 4), 0, 0, math.sin(math.pi / 4)])
    # A head that saw nothing valid still says "worst", never 0 (which means unknown).
    quality = codec.pack(head.message(codec, 0, 2001, 20, 2000, 0.0))
    peer.feed(quality)
    assert peer.of_type("DISTANCE_SENSOR")[-1].signal_quality == 1


def test_obstacle_distance_3d_round_trip_and_nearest_points() -> None:
    distance = np.full(72, np.inf, dtype=np.float32)
    points = np.full((72, 3), np.nan, dtype=np.float32)
    for index, (d, p) in {
        2: (4.0, (3.9, 0.8, -0.2)),
        70: (2.0, (1.9, -0.6, 0.1)),
        30: (9.0, (-7.0, 5.6, 0.0)),
    }.items():
        distance[index], points[index] = d, p
    scan = SectorScan(0, distance, points)
    chosen = nearest_points(scan, 2)
    assert [list(p) for p in chosen] == [
        pytest.approx([1.9, -0.6, 0.1]),
        pytest.approx([3.9, 0.8, -0.2]),
    ]
    codec = Codec(7, 196)
    peer = MavlinkPeer()
    peer.feed(codec.pack(codec.obstacle_distance_3d(55, chosen[0], 0.2, 20.0)))
    (message,) = peer.of_type("OBSTACLE_DISTANCE_3D")
    assert message.frame == 12  # MAV_FRAME_BODY_FRD
    assert (message.x, message.y, message.z) == pytest.approx((1.9, -0.6, 0.1), abs=1e-6)
    assert message.obstacle_id == 65535 and message.time_boot_ms == 55
    assert message.min_distance == pytest.approx(0.2) and message.max_distance == 20.0


def test_config_refuses_a_distance_sensor_head_it_cannot_name(tmp_path: Path) -> None:
    head = {
        "name": "front",
        "calibration": str(write_rectified_calibration(tmp_path)),
        "mount": {"yaw_deg": 30.0},
        "source": {"kind": "synthetic", "fps": 5},
    }
    on = {"distance_sensor": {"enabled": True}}
    config = synthetic_config(tmp_path, "udpout:127.0.0.1:14550", heads=[head], mavlink=on)
    with pytest.raises(ConfigError) as caught:
        load_all(config)
    assert "has no DISTANCE_SENSOR orientation" in "\n".join(caught.value.lines)
    # The same head is fine while DISTANCE_SENSOR is off.
    assert load_all(synthetic_config(tmp_path, "udpout:127.0.0.1:14550", heads=[head]))


async def test_two_heads_merge_and_each_reports_its_distance_sensor(tmp_path: Path) -> None:
    peer = await open_udp_peer()
    calibration = write_rectified_calibration(tmp_path)
    # Both within 0.1 f B = 2.4 m of this rig, where a pixel of disparity is <= 10% of depth.
    box = {"shape": "box", "forward_m": 2.5, "right_m": 0.0, "width_m": 1.0, "depth_m": 0.6}
    pole = {"shape": "pole", "forward_m": 2.0, "right_m": 0.0, "width_m": 0.2}
    heads = [
        {
            "name": name,
            "calibration": str(calibration),
            "mount": {"yaw_deg": yaw},
            "source": {"kind": "synthetic", "fps": 10, "seed": 4, "obstacles": [obstacle]},
        }
        for name, yaw, obstacle in (("front", 0.0, box), ("right", 90.0, pole))
    ]
    config = synthetic_config(
        tmp_path,
        f"udpout:127.0.0.1:{peer.port}",
        heads=heads,
        mavlink={
            "distance_sensor": {"enabled": True, "rate_hz": 10},
            "obstacle_distance_3d": {"enabled": True, "rate_hz": 5, "max_points": 4},
        },
    )
    daemon, task = await start_daemon(config)
    # An autopilot that is neither ArduPilot nor PX4: it gets DISTANCE_SENSOR.
    beat = beat_as_generic_autopilot(peer, daemon)
    try:
        assert await wait_for(
            lambda: (
                {m.id for m in peer.of_type("DISTANCE_SENSOR") if m.current_distance < 2000}
                == {0, 1}
                and len(peer.of_type("OBSTACLE_DISTANCE_3D")) >= 8
            ),
            20.0,
        ), "no DISTANCE_SENSOR from both heads"
    finally:
        beat.cancel()
        await stop_daemon(daemon, task)
        peer.close()
    sensors = [m for m in peer.of_type("DISTANCE_SENSOR") if m.current_distance < 2000]
    by_id = {m.id: m for m in sensors}
    assert by_id[0].orientation == 0 and by_id[1].orientation == 2
    # The box's front face is 2.2 m ahead; the pole's near side 1.9 m to the right.
    assert by_id[0].current_distance == pytest.approx(220, rel=0.04)
    assert by_id[1].current_distance == pytest.approx(190, rel=0.04)
    # The peer is an autopilot of another kind, so it gets DISTANCE_SENSOR (ArduPilot and PX4 not:
    # test_wire_layout) and the layout that starts at -20 degrees.
    scans = [
        read_bins(m.distances, m.increment_f, m.angle_offset)
        for m in peer.of_type("OBSTACLE_DISTANCE")
    ]
    merged = [scan for scan in scans if scan[18] < 2000]
    assert merged, "the right head's pole never reached the merged array"
    last = merged[-1]
    assert last[0] == pytest.approx(220, rel=0.04) and last[18] == pytest.approx(190, rel=0.04)
    assert last[36] == UNKNOWN_CM  # behind: no head sees it
    points = peer.of_type("OBSTACLE_DISTANCE_3D")
    assert all(m.frame == 12 for m in points)
    ranges = [math.hypot(m.x, m.y) for m in points]
    assert min(ranges) == pytest.approx(1.9, rel=0.05)
    # Points of the right head lie to the right (positive y in FRD), the box's ahead, and
    # every point between the ground (1.5 m down) and the height band.
    assert any(m.y > 1.7 and abs(m.x) < 0.5 for m in points)
    assert any(m.x > 2.0 and abs(m.y) < 0.6 for m in points)
    assert all(-2.0 <= m.z <= 1.2 for m in points)
