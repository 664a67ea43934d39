"""Daemon paths on recorded frames: a stale head among fresh ones, held readings expiring, the
temporal filter restarting with a looping recording, the autopilot's attitude in perception."""

from __future__ import annotations

import asyncio
import math
import socket
import threading
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from avoidd.mavlink.layout import UNKNOWN_CM, read_bins
from avoidd.mavlink.mock_autopilot import MockAutopilot
from avoidd.sources.scene import Pole, Scene, render_pair, to_uint8
from avoidd.types import RectifiedRig
from tests.helpers import (
    RIG_320,
    beat_as_generic_autopilot,
    free_udp_port,
    open_udp_peer,
    start_daemon,
    stop_daemon,
    synthetic_config,
    wait_for,
    write_rectified_calibration,
)

RIG = RectifiedRig(*(RIG_320[k] for k in ("width", "height", "fx", "fy", "cx", "cy", "baseline_m")))
"""The rig of the calibration the heads are given."""
CLEAR_CM = 2001
"""What a bin reads when it is measured and clear (max_distance_cm + 1)."""
POLE_AHEAD = Pole(2.0, 0.0, 0.2, 3.0)
"""A pole whose near side is 1.9 m straight ahead (bin 0)."""


def _write_recording(folder: Path, scenes: list[tuple[Scene, int]], seed: int = 0) -> Path:
    """Render each scene and write it ``count`` times as grey PNG pairs (fresh noise each)."""
    (folder / "left").mkdir(parents=True)
    (folder / "right").mkdir()
    rng = np.random.default_rng(seed)
    index = 0
    for scene, count in scenes:
        rendered = render_pair(scene, RIG)
        for _ in range(count):
            for side, view in (("left", rendered.left), ("right", rendered.right)):
                noise = rng.normal(0.0, 1.5, view.shape).astype(np.float32)
                grey = cv2.cvtColor(to_uint8(view, noise), cv2.COLOR_BGR2GRAY)
                cv2.imwrite(str(folder / side / f"{index:04d}.png"), grey)
            index += 1
    return folder


def _scene(*obstacles: Pole, roll_deg: float = 0.0, pitch_deg: float = 0.0) -> Scene:
    """The camera 1.5 m up, level on a level vehicle unless told, a tree line at 45 m."""
    return Scene(1.5, 0.0, obstacles, 45.0, 11, roll_deg, pitch_deg)


def _files_head(name: str, folder: Path, calibration: Path, **extra: Any) -> dict[str, Any]:
    """A head reading a recording folder at 10 frames per second."""
    source = {"kind": "files", "path": str(folder), "fps": 10} | extra.pop("source", {})
    return {"name": name, "calibration": str(calibration), "source": source, **extra}


def _bins(message: Any) -> list[int]:
    """An OBSTACLE_DISTANCE's values in avoidd's bin order (bin i at 5 i degrees)."""
    return read_bins(message.distances, message.increment_f, message.angle_offset)


def _runs(values: list[str]) -> list[str]:
    """The values with repeats collapsed: ``a a b a`` -> ``a b a``."""
    return [v for i, v in enumerate(values) if i == 0 or values[i - 1] != v]


def _last(values: list[str], value: str) -> int:
    """Index of the last occurrence of ``value``."""
    return len(values) - 1 - values[::-1].index(value)


def _state(value_cm: int, near_cm: float) -> str:
    """A bin's reading as 'near' (the obstacle), 'clear', 'unknown' or 'other'."""
    if value_cm == UNKNOWN_CM:
        return "unknown"
    if value_cm == CLEAR_CM:
        return "clear"
    return "near" if abs(value_cm - near_cm) <= 0.06 * near_cm else "other"


async def test_one_stale_head_leaves_the_others_untouched(tmp_path: Path) -> None:
    # "front" renders a box forever; "back" plays a short recording of a pole behind the
    # vehicle and goes stale when it ends.
    peer = await open_udp_peer()
    calibration = write_rectified_calibration(tmp_path)
    recording = _write_recording(tmp_path / "back", [(_scene(POLE_AHEAD), 15)])
    box = {"shape": "box", "forward_m": 2.5, "right_m": 0.0, "width_m": 1.0, "depth_m": 0.6}
    heads = [
        {
            "name": "front",
            "calibration": str(calibration),
            "source": {"kind": "synthetic", "fps": 10, "seed": 4, "obstacles": [box]},
        },
        _files_head("back", recording, calibration, mount={"yaw_deg": 180.0}),
    ]
    config = synthetic_config(
        tmp_path,
        f"udpout:127.0.0.1:{peer.port}",
        heads=heads,
        mavlink={"distance_sensor": {"enabled": True, "rate_hz": 10}},
        # Generous, so that a busy machine does not make the front head stale too.
        pipeline={"max_age_ms": 1000, "log_interval_s": 1.0},
    )
    daemon, task = await start_daemon(config)
    # An autopilot that is neither ArduPilot nor PX4: it gets DISTANCE_SENSOR.
    beat = beat_as_generic_autopilot(peer, daemon)
    try:
        assert await wait_for(
            lambda: any(
                _state(_bins(m)[36], 190) == "near" for m in peer.of_type("OBSTACLE_DISTANCE")
            ),
            20.0,
        ), "the back head's pole never arrived"
        assert await wait_for(
            lambda: any("back stale" in m.text for m in peer.of_type("STATUSTEXT")), 10.0
        )
        stale_at = next(
            i
            for i, r in enumerate(peer.messages)
            if r.message.get_type() == "STATUSTEXT" and "back stale" in r.message.text
        )
        assert await wait_for(
            lambda: (
                sum(r.message.get_type() == "OBSTACLE_DISTANCE" for r in peer.messages[stale_at:])
                >= 15
                and sum(r.message.get_type() == "HEARTBEAT" for r in peer.messages[stale_at:]) >= 2
            ),
            10.0,
        )
    finally:
        beat.cancel()
        await stop_daemon(daemon, task)
        peer.close()
    before = [r.message for r in peer.messages[:stale_at]]
    after = [r.message for r in peer.messages[stale_at:]]
    assert not any("front stale" in m.text for m in peer.of_type("STATUSTEXT"))
    # While both were fresh: the pole behind in bin 36, each head its own DISTANCE_SENSOR.
    sensors_before = {m.id: m for m in before if m.get_type() == "DISTANCE_SENSOR"}
    assert sensors_before[1].orientation == 4  # MAV_SENSOR_ROTATION_YAW_180
    assert sensors_before[1].current_distance == pytest.approx(190, rel=0.06)
    # Once the back head is stale: its 15 bins are unknown in every message, the front's
    # untouched (the box 2.2 m ahead), and only the front's DISTANCE_SENSOR goes on.
    scans = [_bins(m) for m in after if m.get_type() == "OBSTACLE_DISTANCE"]
    assert scans and all(scan[29:44] == [UNKNOWN_CM] * 15 for scan in scans)
    assert all(scan[0] == pytest.approx(220, rel=0.04) for scan in scans)
    sensors_after = [m for m in after if m.get_type() == "DISTANCE_SENSOR"]
    assert sensors_after and {m.id for m in sensors_after} == {0}
    assert all(m.current_distance == pytest.approx(220, rel=0.04) for m in sensors_after)
    # One head stale is enough for a CRITICAL heartbeat.
    assert all(m.system_status == 5 for m in after if m.get_type() == "HEARTBEAT")


@pytest.mark.parametrize(
    ("hold_ms", "max_age_ms", "after_the_pole"),
    [
        # Held 2 s, but nothing older than 0.3 s is sent: the held reading goes unknown when
        # it is too old to send, and the bin clear once the hold is over.
        (2000, 300, ["near", "unknown", "clear"]),
        # Held 0.2 s while 1 s old readings may be sent: clear as soon as the hold is over.
        (200, 1000, ["near", "clear"]),
    ],
)
async def test_a_held_reading_expires(
    tmp_path: Path, hold_ms: int, max_age_ms: int, after_the_pole: list[str]
) -> None:
    # The pole is in view for 0.6 s, then gone for 4.5 s. Never the pole again after it went.
    peer = await open_udp_peer()
    calibration = write_rectified_calibration(tmp_path)
    recording = _write_recording(tmp_path / "rec", [(_scene(POLE_AHEAD), 6), (_scene(), 45)])
    config = synthetic_config(
        tmp_path,
        f"udpout:127.0.0.1:{peer.port}",
        heads=[_files_head("front", recording, calibration)],
        pipeline={"max_age_ms": max_age_ms, "log_interval_s": 1.0},
        sections={"perception": {"temporal": {"hold_ms": hold_ms}}},
    )

    def states() -> list[str]:
        return _runs([_state(_bins(m)[0], 190) for m in peer.of_type("OBSTACLE_DISTANCE")])

    def cleared() -> bool:
        seen = states()
        return "near" in seen and "clear" in seen[_last(seen, "near") :]

    daemon, task = await start_daemon(config)
    try:
        assert await wait_for(cleared, 20.0), f"bin 0 never went clear: {states()}"
    finally:
        await stop_daemon(daemon, task)
        peer.close()
    seen = states()
    # (Before that the pole may blink unknown if a frame comes late; after it, no pole.)
    last_near = _last(seen, "near")
    assert seen[last_near : last_near + len(after_the_pole)] == after_the_pole, seen


async def test_a_looping_recording_restarts_the_temporal_filter(tmp_path: Path) -> None:
    # The recording ends with the pole in view and starts without it. The filter holds a
    # vanished obstacle for 2 s (and max_age lets a held reading be sent), longer than the
    # 0.5 s without the pole: only a filter that starts over at the loop ever sees the bin
    # clear again after the pole.
    peer = await open_udp_peer()
    calibration = write_rectified_calibration(tmp_path)
    recording = _write_recording(tmp_path / "rec", [(_scene(), 5), (_scene(POLE_AHEAD), 5)])
    head = _files_head("front", recording, calibration, source={"loop": True})
    config = synthetic_config(
        tmp_path,
        f"udpout:127.0.0.1:{peer.port}",
        heads=[head],
        pipeline={"max_age_ms": 2500, "log_interval_s": 1.0},
        sections={"perception": {"temporal": {"hold_ms": 2000}}},
    )

    def states() -> list[str]:
        return _runs([_state(_bins(m)[0], 190) for m in peer.of_type("OBSTACLE_DISTANCE")])

    daemon, task = await start_daemon(config)
    try:
        assert await wait_for(lambda: "near" in states(), 20.0), "the pole never showed"
        assert await wait_for(lambda: "clear" in states()[states().index("near") :], 6.0), (
            f"bin 0 stayed on the pole after the recording looped: {states()}"
        )
        assert await wait_for(lambda: states().count("near") >= 2, 6.0)
    finally:
        await stop_daemon(daemon, task)
        peer.close()


async def test_the_autopilot_attitude_is_what_perception_uses(tmp_path: Path) -> None:
    # Frames without a recorded pose, taken from a vehicle rolled 8 degrees (right side down)
    # and pitched 4 down: the mock autopilot reports that attitude, and a downward rangefinder
    # that reads the camera's 1.5 m along the tilted body axis. Interpreted as level, the
    # ground on the right would rise into view as obstacles 3.5 to 5 m away.
    roll, pitch = math.radians(8.0), math.radians(-4.0)
    autopilot = MockAutopilot(
        system_id=7,
        attitude=lambda _t: (roll, pitch, 0.3),
        rangefinder_m=1.5 / (math.cos(roll) * math.cos(pitch)),
    )
    port = free_udp_port()
    await autopilot.start(f"udpin:127.0.0.1:{port}")
    calibration = write_rectified_calibration(tmp_path)
    scene = _scene(POLE_AHEAD, roll_deg=8.0, pitch_deg=-4.0)
    recording = _write_recording(tmp_path / "rec", [(scene, 40)])
    head = _files_head("front", recording, calibration, source={"loop": True})
    config = synthetic_config(tmp_path, f"udpout:127.0.0.1:{port}", heads=[head])
    daemon, task = await start_daemon(config)

    def latest_pose() -> Any:
        latest = daemon.heads[0].latest if daemon.heads else None
        return None if latest is None else latest.pose

    def later_scans(after_ns: int) -> list[list[int]]:
        """Scans of frames captured after ``after_ns`` (time_usec is the capture time)."""
        return [
            _bins(m)
            for m in autopilot.of_type("OBSTACLE_DISTANCE")
            if m.time_usec * 1000 >= after_ns
        ]

    try:
        assert await wait_for(
            lambda: (pose := latest_pose()) is not None and pose.source == "mavlink", 20.0
        ), f"no frame was interpreted with the autopilot's attitude: {latest_pose()}"
        # From 0.3 s of capture time on (beyond the filter's hold of anything seen before).
        settled_ns = daemon.heads[0].latest.t_capture_ns + 300_000_000
        assert await wait_for(lambda: len(later_scans(settled_ns)) >= 10, 15.0)
        pose = latest_pose()
    finally:
        await stop_daemon(daemon, task)
        await autopilot.stop()
    assert pose.roll_deg == pytest.approx(8.0, abs=0.01)
    assert pose.pitch_deg == pytest.approx(-4.0, abs=0.01)
    assert pose.height_source == "rangefinder"
    assert pose.height_m == pytest.approx(1.5, abs=0.01)
    for scan in later_scans(settled_ns):
        assert _state(scan[0], 190) == "near", scan[:8]
        assert all(v in (CLEAR_CM, UNKNOWN_CM) for v in scan[2:8]), scan[:8]


async def test_stop_and_wait_gives_the_exit_code_and_logs_a_run_that_raised_or_hangs(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """What the simulations call when tidying up after a flight, failed or not."""
    config = synthetic_config(tmp_path, f"udpout:127.0.0.1:{free_udp_port()}")
    daemon, task = await start_daemon(config)
    assert await wait_for(lambda: daemon.sent["OBSTACLE_DISTANCE"] > 0, 15.0)
    assert await daemon.stop_and_wait(task) == 0

    async def raises() -> int:
        raise RuntimeError("a head thread died")

    async def hangs() -> int:
        await asyncio.sleep(60.0)
        return 0

    assert await daemon.stop_and_wait(asyncio.create_task(raises())) is None
    assert "avoidd ended with an error" in caplog.text and "a head thread died" in caplog.text
    hanging = asyncio.create_task(hangs())
    assert await daemon.stop_and_wait(hanging, timeout_s=0.2) is None
    assert "avoidd did not stop within 0.2 s" in caplog.text
    assert hanging.cancelled()


async def test_stop_and_wait_closes_the_link_of_a_run_that_did_not_stop_in_time(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A head thread that takes long to join (a camera read stuck on a busy machine): the run is
    cancelled mid-shutdown, and its udpin port must still be freed for the next daemon."""
    port = free_udp_port()
    config = synthetic_config(tmp_path, f"udpin:127.0.0.1:{port}")
    daemon, task = await start_daemon(config)
    assert await wait_for(lambda: bool(daemon.heads) and daemon.heads[0].stats.processed > 0, 15.0)
    joined = threading.Event()

    def slow_join(self: object, timeout_s: float = 5.0) -> None:
        joined.wait(3.0)

    monkeypatch.setattr(daemon.heads[0].__class__, "join", slow_join)
    try:
        assert await daemon.stop_and_wait(task, timeout_s=0.5) is None
        probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            probe.bind(("127.0.0.1", port))  # free again: the link was closed
        finally:
            probe.close()
    finally:
        joined.set()
