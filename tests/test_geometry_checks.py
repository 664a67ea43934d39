"""Impossible geometry is refused at load, and never turns into "clear" at run time."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from avoidd.config import PerceptionConfig, SectorsConfig
from avoidd.errors import BrokenFrame, ConfigError
from avoidd.loading import load_all, obstacle_range_cm
from avoidd.perception.frames import camera_to_level
from avoidd.perception.ground import free_space_evidence
from avoidd.perception.perceive import perceive
from avoidd.types import FramePose, Mount, RectifiedRig
from avoidd.vision.depth import depth_from_disparity
from tests.helpers import REPO

CONFIG = """\
version: 1
heads:
  - name: front
    calibration: calib.yaml
    mount: {yaw_deg: 0, pitch_deg: 0, roll_deg: 0, position_m: [0.1, 0, 0]}
    source: {kind: synthetic, fps: 15, camera_height_m: 1.5}
mavlink:
  connection: udpout:127.0.0.1:14550
perception:
  ground: {height_m: 1.5}
"""
CALIBRATION = (
    "version: 1\n"
    "rectified: {width: 320, height: 240, fx: 200, fy: 200, cx: 159.5, cy: 119.5, "
    "baseline_m: 0.1, doffs: 0}\n"
)
STEREO = """\
version: 1
stereo:
  width: 320
  height: 240
  K1: [[200, 0, 160], [0, 200, 120], [0, 0, 1]]
  D1: [0, 0, 0, 0, 0]
  K2: [[200, 0, 160], [0, 200, 120], [0, 0, 1]]
  D2: [0, 0, 0, 0, 0]
  R: [[1, 0, 0], [0, 1, 0], [0, 0, 1]]
  T_m: [-0.1, 0, 0]
"""


def _write(tmp_path: Path, config: str, calibration: str) -> Path:
    (tmp_path / "calib.yaml").write_text(calibration)
    path = tmp_path / "avoidd.yaml"
    path.write_text(config)
    return path


@pytest.mark.parametrize(
    ("config_edit", "calibration_edit", "fragment"),
    [
        (
            ("position_m: [0.1, 0, 0]", "position_m: [.nan, 0, 0]"),
            None,
            "position_m[0]: Input should be a finite number",
        ),
        (
            ("position_m: [0.1, 0, 0]", "position_m: [0.1, .inf, 0]"),
            None,
            "position_m[1]: Input should be a finite number",
        ),
        (
            ("position_m: [0.1, 0, 0]", "position_m: [0.1, 0, 40]"),
            None,
            "position_m[2]: Input should be less than or equal to 5",
        ),
        (("yaw_deg: 0", "yaw_deg: .nan"), None, "mount.yaw_deg"),
        (("height_m: 1.5}", "height_m: .inf}"), None, "ground.height_m"),
        (("camera_height_m: 1.5", "camera_height_m: .nan"), None, "camera_height_m"),
        (None, ("cy: 119.5", "cy: .inf"), "rectified.cy"),
        (None, ("fx: 200", "fx: .inf"), "rectified.fx"),
        (None, ("doffs: 0", "doffs: -1000"), "doffs -1000 px is beyond half the image width"),
        (None, ("cx: 159.5", "cx: -5"), "cx -5 lies outside the image"),
        (None, ("fx: 200", "fx: 2"), "fx 2 px is not a focal length"),
        (None, ("baseline_m: 0.1", "baseline_m: .nan"), "rectified.baseline_m"),
        (None, ("baseline_m: 0.1", "baseline_m: 1e-12"), "too short for stereo ranging"),
        (None, ("baseline_m: 0.1", "baseline_m: 0.004"), "resolves only to 0.8 m"),
        (None, ("baseline_m: 0.1", "baseline_m: 0.0125"), "resolves only to 2.5 m"),
        (
            ("fps: 15,", "fps: 15, seed: 1,"),
            ("baseline_m: 0.1", "baseline_m: 0.01"),
            "at least 3 m",
        ),
    ],
)
def test_check_config_refuses_impossible_geometry(
    tmp_path: Path,
    config_edit: tuple[str, str] | None,
    calibration_edit: tuple[str, str] | None,
    fragment: str,
) -> None:
    config, calibration = CONFIG, CALIBRATION
    if config_edit is not None:
        assert config_edit[0] in config
        config = config.replace(*config_edit)
    if calibration_edit is not None:
        assert calibration_edit[0] in calibration
        calibration = calibration.replace(*calibration_edit)
    path = _write(tmp_path, config, calibration)
    with pytest.raises(ConfigError) as info:
        load_all(path)
    text = "\n".join(info.value.lines)
    assert fragment in text, text
    # Every line names the file and the line it is about.
    assert all(":" in line and ".yaml" in line for line in info.value.lines)
    result = subprocess.run(
        [sys.executable, "-m", "avoidd", "check-config", str(path)],
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=60,
    )
    assert result.returncode == 2
    assert fragment in result.stderr
    assert "Traceback" not in result.stderr


@pytest.mark.parametrize(
    ("old", "new"),
    [("T_m: [-0.1, 0, 0]", "T_m: [.nan, 0, 0]"), ("D1: [0, 0, 0, 0, 0]", "D1: [.inf, 0, 0, 0, 0]")],
)
def test_stereo_calibrations_refuse_non_finite_numbers(tmp_path: Path, old: str, new: str) -> None:
    path = _write(tmp_path, CONFIG, STEREO.replace(old, new))
    with pytest.raises(ConfigError) as info:
        load_all(path)
    assert "calib.yaml" in info.value.lines[0]


def test_check_config_says_how_far_the_rig_resolves_and_cuts_the_maximum(tmp_path: Path) -> None:
    # f*B = 200 px * 0.06 m: at a 0.5 px error a reading at 12 m may be 50 % off.
    path = _write(tmp_path, CONFIG, CALIBRATION.replace("baseline_m: 0.1", "baseline_m: 0.06"))
    result = subprocess.run(
        [sys.executable, "-m", "avoidd", "check-config", str(path)],
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=60,
    )
    assert result.returncode == 0, result.stderr
    assert "resolves to 12.0 m" in result.stdout
    assert "to 1200 cm (max_distance_cm 2000 cut to what the rig resolves)" in result.stdout
    # A looser error setting halves it.
    looser = CONFIG.replace("    source:", "    disparity_error_px: 1.0\n    source:")
    path = _write(tmp_path, looser, CALIBRATION.replace("baseline_m: 0.1", "baseline_m: 0.06"))
    config, calibrations = load_all(path)
    assert obstacle_range_cm(
        config.mavlink.obstacle_distance, [(config.heads[0], calibrations["front"])]
    ) == (5, 600)


def test_the_shipped_configs_pass_the_same_checks() -> None:
    for path in sorted((REPO / "config").glob("*.yaml")):
        load_all(path)


RIG = RectifiedRig(320, 240, 200.0, 200.0, 159.5, 119.5, 0.1)


def test_a_point_behind_the_cameras_is_no_measurement() -> None:
    # A negative d + doffs is impossible, so not "far" (it used to read as infinitely far,
    # and every bin clear).
    rig = RectifiedRig(320, 240, 200.0, 200.0, 159.5, 119.5, 0.1, -50.0)
    depth = depth_from_disparity(np.full((2, 2), 10.0, dtype=np.float32), rig)
    assert np.isnan(depth).all()


def test_nan_geometry_is_no_evidence_of_free_space() -> None:
    depth = np.full((240, 320), np.inf, dtype=np.float32)  # every pixel measured far
    level = camera_to_level(Mount(), 0.0, 0.0)
    band = PerceptionConfig().band
    assert free_space_evidence(depth, RIG, level, band, 20.0).any()
    broken = camera_to_level(Mount(position_m=(math.nan, 0.0, 0.0)), 0.0, 0.0)
    assert not free_space_evidence(depth, RIG, broken, band, 20.0).any()
    tilted = camera_to_level(Mount(), math.nan, 0.0)
    assert not free_space_evidence(depth, RIG, tilted, band, 20.0).any()


@pytest.mark.parametrize(
    ("pose", "mount"),
    [
        (FramePose(math.nan, 0.0, 1.5, "mavlink", "config"), Mount()),
        (FramePose(0.0, 0.0, math.inf, "mavlink", "altitude"), Mount()),
        (FramePose(0.0, 0.0, 1.5, "mavlink", "config"), Mount(position_m=(0.0, math.nan, 0.0))),
    ],
)
def test_a_frame_with_impossible_geometry_is_dropped_not_clear(
    pose: FramePose, mount: Mount
) -> None:
    depth = np.full((240, 320), np.inf, dtype=np.float32)
    perception = PerceptionConfig()
    with pytest.raises(BrokenFrame, match="not a finite number"):
        perceive(depth, RIG, mount, pose, perception, SectorsConfig(), _histogram(), 20.0, 0)


def test_obstacle_points_that_form_no_cluster_are_no_evidence_of_clear() -> None:
    # A wall 2 m ahead with disparities spread too thin to form a cluster anywhere: its bins
    # must read unknown, not clear, however many of their pixels were measured.
    rng = np.random.default_rng(1)
    depth = rng.uniform(1.0, 19.0, (240, 320)).astype(np.float32)
    pose = FramePose(0.0, 0.0, 1.5, "config", "config")
    seen = perceive(
        depth,
        RIG,
        Mount(),
        pose,
        PerceptionConfig(),
        SectorsConfig(min_pixels=100000),
        _histogram(),
        20.0,
        0,
    )
    covered = ~np.isnan(seen.scan.distance_m)
    assert not np.isposinf(seen.scan.distance_m).any(), seen.scan.distance_m[covered]


def _histogram():  # type: ignore[no-untyped-def]
    from avoidd.config import HistogramConfig

    return HistogramConfig()


async def test_the_daemon_claims_clear_no_farther_than_the_rig_resolves(tmp_path: Path) -> None:
    # A 6 cm rig at 200 px resolves to 12 m: ArduPilot is told so (max_distance), no bin says
    # more, and the planner's clear bins see no farther.
    from avoidd.mavlink.mock_autopilot import MockAutopilot
    from tests.helpers import RIG_320, free_udp_port, synthetic_config, wait_for
    from tests.helpers import start_daemon as start
    from tests.helpers import stop_daemon as stop

    autopilot = MockAutopilot(system_id=7, mode="LOITER")
    port = free_udp_port()
    await autopilot.start(f"udpin:127.0.0.1:{port}")
    rig = {**RIG_320, "baseline_m": 0.06}
    config = synthetic_config(tmp_path, f"udpout:127.0.0.1:{port}", rig=rig)
    daemon, task = await start(config)
    try:
        assert await wait_for(lambda: len(autopilot.of_type("OBSTACLE_DISTANCE")) >= 10, 20)
        messages = autopilot.of_type("OBSTACLE_DISTANCE")
        assert {m.max_distance for m in messages} == {1200}
        assert all(d <= 1201 or d == 65535 for m in messages for d in m.distances)
        assert any(d == 1201 for m in messages for d in m.distances)  # clear: beyond 12 m
        assert daemon.avoidance.planner.max_range_m == 12.0
        assert all(head.pipeline.max_range_m == 12.0 for head in daemon.heads)
    finally:
        await stop(daemon, task)
        await autopilot.stop()
