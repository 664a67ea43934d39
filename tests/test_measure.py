"""``measure``, ``calibrate-mount`` and ``render-board`` checked against rendered truth."""

from __future__ import annotations

import math
import re
import shutil
import subprocess
import sys
import types
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import yaml

from avoidd.calibrate.board import Board
from avoidd.calibrate.render import BoardRenderer, default_rig, sample_poses
from avoidd.cli import main
from avoidd.commands.measure import format_optical_axis
from avoidd.config import PerceptionConfig, load_config
from avoidd.errors import MeasureError
from avoidd.perception.measure import (
    camera_geometry,
    level_pose,
    measure_pixel,
    nearest_obstacle_pixel,
)
from avoidd.perception.mount_fit import fit_mount
from avoidd.perception.obstacles import Obstacle
from avoidd.sources.scene import FIRST_OBSTACLE_ID, GROUND_ID, Box, Scene, render_pair
from avoidd.sources.synthetic import SyntheticSource
from avoidd.types import FramePose, GroundTruth, Mount, RectifiedRig
from avoidd.vision.calibration import load_calibration
from tests.helpers import REPO, synthetic_config, write_rectified_calibration

RIG_640 = {
    "width": 640,
    "height": 480,
    "fx": 400.0,
    "fy": 400.0,
    "cx": 319.5,
    "cy": 239.5,
    "baseline_m": 0.12,
    "doffs": 0.0,
}
RIG = RectifiedRig(640, 480, 400.0, 400.0, 319.5, 239.5, 0.12, 0.0)
BOX_AHEAD = {"shape": "box", "forward_m": 4.0, "right_m": 0.0, "width_m": 1.0, "depth_m": 0.6}
"""A box whose near face is 3.7 m ahead, 1 m wide, 1.5 m tall (the default height)."""


def _rendered_head_config(
    folder: Path,
    pitch_deg: float,
    height_m: float,
    obstacles: list[dict[str, Any]],
    backdrop_m: float | None,
    position_m: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> Path:
    """A config with one 640x480 head on a rendered scene, mounted as the scene says."""
    calibration = write_rectified_calibration(folder, RIG_640)
    head = {
        "name": "front",
        "calibration": str(calibration),
        "mount": {"pitch_deg": pitch_deg, "position_m": list(position_m)},
        "source": {
            "kind": "synthetic",
            "seed": 5,
            "camera_height_m": height_m,
            "camera_pitch_deg": pitch_deg,
            "obstacles": obstacles,
            "backdrop_m": backdrop_m,
        },
    }
    return synthetic_config(folder, "udpout:127.0.0.1:9", rig=RIG_640, heads=[head])


def _truth_of(config_path: Path) -> GroundTruth:
    """The exact geometry of the first frame the config's head sees."""
    head = load_config(config_path).heads[0]
    assert head.source.kind == "synthetic"
    frame = SyntheticSource(head.source, load_calibration(head.calibration).rig, False).read()
    assert frame.truth is not None
    return frame.truth


def _foot_row(truth: GroundTruth, u: int) -> int:
    """The lowest row of column ``u`` that sees the obstacle (where it stands on the ground)."""
    rows = np.flatnonzero(truth.object_id[:, u] >= FIRST_OBSTACLE_ID)
    assert rows.size, f"column {u} does not see the obstacle"
    return int(rows.max())


# --- measure_pixel and the contact search on exact depth ----------------------------------------


def _exact_box_scene(pitch_deg: float = -10.0) -> tuple[GroundTruth, Any]:
    """The box ahead rendered from 1.5 m at a pitch, and its camera geometry (level vehicle)."""
    scene = Scene(1.5, pitch_deg, (Box(4.0, 0.0, 0.6, 1.0, 1.5),), 45.0, 5)
    truth = render_pair(scene, RIG).truth
    geometry = camera_geometry(Mount(pitch_deg=pitch_deg), np.eye(3), FramePose(0.0, 0.0, 1.5))
    return truth, geometry


@pytest.mark.parametrize(("u", "v"), [(320, 400), (100, 460), (500, 300), (620, 250)])
def test_measure_pixel_on_the_ground_gives_the_rendered_distance(u: int, v: int) -> None:
    truth, geometry = _exact_box_scene()
    assert truth.object_id[v, u] == GROUND_ID
    depth = truth.depth_m.astype(np.float32)
    measured = measure_pixel(depth, RIG, geometry, u, v)
    forward, right = (float(x) for x in truth.points_m[v, u, :2])
    # The paper's formulas are exact for a ground pixel when h and the tilt are right.
    assert measured.ground.depth_m == pytest.approx(float(truth.depth_m[v, u]), rel=1e-5)
    assert measured.ground.range_m == pytest.approx(math.hypot(forward, right), rel=1e-5)
    assert measured.ground.lateral_m == pytest.approx(right, abs=1e-4)
    # Stereo is the median of a 5x5 window: the ground's depth changes from row to row.
    assert measured.stereo_depth_m == pytest.approx(float(truth.depth_m[v, u]), rel=0.01)
    assert measured.stereo_range_m == pytest.approx(math.hypot(forward, right), rel=0.01)
    assert abs(measured.difference_pct) < 1.0


def test_measure_pixel_refuses_what_it_cannot_range() -> None:
    truth, geometry = _exact_box_scene()
    depth = truth.depth_m.astype(np.float32)
    with pytest.raises(MeasureError, match="outside"):
        measure_pixel(depth, RIG, geometry, 640, 100)
    with pytest.raises(MeasureError, match="horizon"):
        measure_pixel(depth, RIG, geometry, 320, 100)  # the tree line, above the horizon
    holes = depth.copy()
    holes[390:411, 310:331] = np.nan
    with pytest.raises(MeasureError, match="no stereo measurement"):
        measure_pixel(holes, RIG, geometry, 320, 400)


def test_contact_search_finds_the_foot_of_the_obstacle() -> None:
    truth, _ = _exact_box_scene()
    pose = FramePose(0.0, 0.0, 1.5)
    nearest = Obstacle(3.7, 0.0, 0.0, 1.0, 1.5, 1.5, 1000, (), ())
    margin_m = PerceptionConfig().ground.margin_m
    to_level = level_pose(Mount(pitch_deg=-10.0), np.eye(3), pose)
    found = nearest_obstacle_pixel(
        truth.depth_m.astype(np.float32), RIG, to_level, nearest, 1.5, margin_m
    )
    assert found is not None
    u, v = found
    assert truth.object_id[_foot_row(truth, u) - 5, u] >= FIRST_OBSTACLE_ID
    # The search walks down while the depth stays within 5% of the face's, and the ground next
    # to the foot is as far as the face: it never stops above the foot, but it overshoots by
    # the rows whose ground is within 5% of the face (10 rows here, on exact depth), so the
    # ground-plane range there is 6.4% short of the box.
    overshoot = v - _foot_row(truth, u)
    assert 0 <= overshoot <= 12
    geometry = camera_geometry(Mount(pitch_deg=-10.0), np.eye(3), pose)
    measured = measure_pixel(truth.depth_m.astype(np.float32), RIG, geometry, u, v)
    assert -0.08 <= measured.ground.range_m / 3.7 - 1.0 <= 0.0


# --- the measure command ----------------------------------------------------------------------

_NEAREST = re.compile(
    r"nearest obstacle (?P<d>[\d.]+) m at (?P<b>[-+\d.]+) deg, its ground contact at pixel "
    r"\((?P<u>\d+), (?P<v>\d+)\)"
)
_STEREO = re.compile(r"stereo: +depth +(?P<depth>[\d.]+) m, range +(?P<range>[\d.]+) m")
_GROUND = re.compile(r"ground plane: +depth +(?P<depth>[\d.]+) m, range +(?P<range>[\d.]+) m")


def test_measure_command_ranges_the_nearest_obstacle_and_a_given_pixel(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    config = _rendered_head_config(tmp_path, -10.0, 1.5, [BOX_AHEAD], 45.0)
    truth = _truth_of(config)

    assert main(["measure", "--config", str(config)]) == 0
    printed = capsys.readouterr().out
    nearest = _NEAREST.search(printed)
    assert nearest is not None, printed
    assert float(nearest["d"]) == pytest.approx(3.7, rel=0.03)
    assert abs(float(nearest["b"])) < 8.0  # the box spans -7.7..+7.7 degrees
    u, v = int(nearest["u"]), int(nearest["v"])
    # The contact lies in one of the box's columns, at or below its foot. From stereo depth
    # it lands further down in the ground than from exact depth (16 rows at this writing),
    # so the ground-plane range there comes out up to 12% short of the box.
    foot = _foot_row(truth, u)
    assert truth.object_id[foot - 5, u] >= FIRST_OBSTACLE_ID
    assert 0 <= v - foot <= 22
    ground = _GROUND.search(printed)
    assert ground is not None
    assert -0.12 <= float(ground["range"]) / 3.7 - 1.0 <= 0.0

    # A pixel given on the ground: the ground-plane depth is the rendered one (printed to
    # the millimetre), the stereo depth within 1.5% of it.
    assert main(["measure", "--config", str(config), "--pixel", "320", "400"]) == 0
    printed = capsys.readouterr().out
    depth_truth = float(truth.depth_m[400, 320])
    ground, stereo = _GROUND.search(printed), _STEREO.search(printed)
    assert ground is not None and stereo is not None, printed
    assert float(ground["depth"]) == pytest.approx(depth_truth, abs=0.0006)
    assert float(stereo["depth"]) == pytest.approx(depth_truth, rel=0.015)


def test_measure_command_says_when_nothing_is_in_view(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    config = _rendered_head_config(tmp_path, -10.0, 1.5, [], 45.0)
    assert main(["measure", "--config", str(config)]) == 1
    assert "no obstacle in view" in capsys.readouterr().out


# --- calibrate-mount ----------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("pitch_deg", "height_m", "roll_deg"),
    [(-25.0, 1.5, 0.0), (-35.0, 1.2, 0.0), (-25.0, 1.2, 4.0), (-30.0, 2.0, -3.0)],
)
def test_mount_fit_on_exact_ground_depth_is_exact(
    pitch_deg: float, height_m: float, roll_deg: float
) -> None:
    scene = Scene(height_m, pitch_deg, (), None, 5, vehicle_roll_deg=roll_deg)
    depth = render_pair(scene, RIG).truth.depth_m.astype(np.float32)
    fit = fit_mount([depth], RIG, 4.8)
    # Seen from the camera, a rolled vehicle tilts the ground about the optical axis by less
    # than the roll, and lowers the axis's depression: gravity in the optical frame is
    # (sin r, cos r cos p, cos r sin |p|) for mount pitch p and vehicle roll r.
    pitch, roll = math.radians(pitch_deg), math.radians(roll_deg)
    assert fit.height_m == pytest.approx(height_m, abs=1e-4)
    assert fit.pitch_deg == pytest.approx(
        -math.degrees(math.asin(math.cos(roll) * math.sin(-pitch))), abs=0.01
    )
    assert fit.roll_deg == pytest.approx(
        math.degrees(math.atan2(math.sin(roll), math.cos(roll) * math.cos(pitch))), abs=0.01
    )
    assert fit.plane.inlier_fraction > 0.99


_FIT = re.compile(
    r"camera height (?P<h>[\d.]+) m, pitch (?P<p>[-+\d.]+) deg, roll (?P<r>[-+\d.]+) deg"
)


@pytest.mark.parametrize(("pitch_deg", "height_m"), [(-25.0, 1.5), (-35.0, 1.2)])
def test_calibrate_mount_command_recovers_the_rendered_mount(
    tmp_path: Path, pitch_deg: float, height_m: float
) -> None:
    # Flat textured ground and no backdrop; the camera 0.1 m below the body origin.
    config = _rendered_head_config(tmp_path, pitch_deg, height_m, [], None, (0.0, 0.0, 0.1))
    done = subprocess.run(
        [sys.executable, "-m", "avoidd", "calibrate-mount", "--config", str(config)],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    fit = _FIT.search(done.stdout)
    assert fit is not None, done.stdout
    # Subpixel-refined disparity and a fit in disparity: height within 1 %, pitch within 0.3 deg.
    assert float(fit["h"]) == pytest.approx(height_m, rel=0.01)
    assert float(fit["p"]) == pytest.approx(pitch_deg, abs=0.3)
    assert abs(float(fit["r"])) < 0.2
    body = re.search(r"ground: \{height_m: (?P<h>[\d.]+), margin_m: [\d.]+\}", done.stdout)
    assert body is not None
    assert float(body["h"]) == pytest.approx(float(fit["h"]) + 0.1, abs=0.0011)


def test_calibrate_mount_on_the_demo_is_accurate_and_its_lines_pass_check_config(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # The demo: a synthetic camera 1.5 m up, pitch 0 (it read 1.470 m, +0.83 deg, "OP = inf m").
    config = tmp_path / "demo.yaml"
    shutil.copy(REPO / "config" / "demo.yaml", config)
    shutil.copytree(REPO / "config" / "calibration", tmp_path / "calibration")
    assert main(["calibrate-mount", "--config", str(config)]) == 0
    printed = capsys.readouterr().out
    fit = _FIT.search(printed)
    assert fit is not None, printed
    assert float(fit["h"]) == pytest.approx(1.5, rel=0.01)
    assert float(fit["p"]) == pytest.approx(0.0, abs=0.3)
    assert "inf" not in printed and "never meets the ground" in printed

    # The suggested lines replace the head's mount and perception.ground; check-config accepts.
    suggested = printed.split("perception.ground):\n", 1)[1]
    lines = yaml.safe_load(suggested)
    data = yaml.safe_load(config.read_text())
    data["heads"][0]["mount"] = lines["mount"]
    data["perception"]["ground"] = lines["ground"]
    config.write_text(yaml.safe_dump(data))
    assert main(["check-config", str(config)]) == 0, capsys.readouterr()


def test_optical_axis_text_never_prints_infinity() -> None:
    assert "OP = 1.50 m" in format_optical_axis(1.5, -45.0)
    assert "never meets the ground" in format_optical_axis(1.5, 0.0)
    assert "never meets the ground" in format_optical_axis(1.5, 3.0)
    far = format_optical_axis(1.5, -0.01)
    assert "too far to measure" in far and "inf" not in far


@pytest.mark.parametrize(
    ("height_m", "op_m", "tilt_deg"), [(1.5, 1.5, 45.0), (1.0, 1.7320508, 30.0), (2.0, 20.0, 5.71)]
)
def test_calibrate_mount_from_measured_h_and_op(
    height_m: float, op_m: float, tilt_deg: float, capsys: pytest.CaptureFixture[str]
) -> None:
    args = ["calibrate-mount", "--height-m", str(height_m), "--op-m", str(op_m)]
    assert main(args) == 0
    printed = capsys.readouterr().out
    assert f"= {tilt_deg:.2f} deg down" in printed
    assert f"mount: {{pitch_deg: {-tilt_deg:.2f}}}" in printed
    assert main(["calibrate-mount", "--height-m", "1.5"]) == 2  # OP missing


# --- render-board -------------------------------------------------------------------------------


def test_render_board_writes_pairs_in_which_opencv_finds_the_true_corners(
    tmp_path: Path,
) -> None:
    assert main(["render-board", str(tmp_path), "--count", "2", "--seed", "4"]) == 0
    # The command's defaults: a 10x7 chessboard of 25 mm squares (9x6 inner corners) seen by
    # the default virtual rig; the same seed gives the same poses. (Poses and corners need
    # only the board and the rig, not the renderer's costly per-pixel rays.)
    board = Board("chessboard", 10, 7, 0.025)
    rig = default_rig()
    projector = types.SimpleNamespace(board=board, rig=rig)
    projector.corners_px = lambda camera, rvec, tvec: BoardRenderer.corners_px(
        projector, camera, rvec, tvec
    )
    poses = sample_poses(projector, 2, np.random.default_rng(4))
    for side, camera in (("left", rig.left), ("right", rig.right)):
        names = sorted(p.name for p in (tmp_path / side).iterdir())
        assert names == ["000.png", "001.png"]
        for name, (rvec, tvec) in zip(names, poses, strict=True):
            image = cv2.imread(str(tmp_path / side / name), cv2.IMREAD_GRAYSCALE)
            assert image is not None and image.shape == (480, 640)
            found, corners = cv2.findChessboardCorners(image, (9, 6))
            assert found, f"{side}/{name}: OpenCV finds no 9x6 chessboard"
            criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 40, 1e-3)
            corners = cv2.cornerSubPix(image, corners, (5, 5), (-1, -1), criteria)
            detected = corners.reshape(-1, 2)
            truth = projector.corners_px(camera, rvec, tvec)
            # Every true corner has a detected one within a few tenths of a pixel.
            distances = np.linalg.norm(truth[:, None, :] - detected[None, :, :], axis=2)
            assert distances.min(axis=1).max() < 0.3, f"{side}/{name}"
