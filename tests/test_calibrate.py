"""Stereo calibration: board detection, rendered-rig round trip, importers, rectification."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from avoidd.calibrate.board import Board, detect
from avoidd.calibrate.importers import euroc_stereo, middlebury_rectified, read_middlebury
from avoidd.calibrate.render import BoardRenderer, default_rig, sample_poses, write_pairs
from avoidd.calibrate.stereo import (
    CalibrationFailed,
    PairObservation,
    PairReport,
    calibrate,
    observe_pair,
)
from avoidd.cli import main
from avoidd.errors import ConfigError
from avoidd.vision.calibration import StereoModel, load_calibration, rectification

CHESS = Board("chessboard", 10, 7, 0.05)
CHARUCO = Board("charuco", 8, 6, 0.06, 0.045)


def test_board_rejects_ambiguous_or_impossible_layouts() -> None:
    with pytest.raises(ValueError, match="odd"):
        Board("chessboard", 8, 6, 0.05)
    with pytest.raises(ValueError, match="marker"):
        Board("charuco", 8, 6, 0.05, 0.06)
    with pytest.raises(ValueError, match="metres"):
        Board("chessboard", 10, 7, 25.0)


def test_object_points_match_opencv_charuco_corners() -> None:
    ours = CHARUCO.object_points()
    theirs = np.asarray(CHARUCO.charuco().getChessboardCorners(), np.float32)
    np.testing.assert_allclose(ours[:, :2], theirs[:, :2], atol=1e-6)


@pytest.mark.parametrize("board", [CHESS, CHARUCO], ids=["chessboard", "charuco"])
def test_detected_corners_are_subpixel_accurate(board: Board) -> None:
    rig = default_rig()
    renderer = BoardRenderer(board, rig)
    rng = np.random.default_rng(3)
    errors = []
    for rvec, tvec in sample_poses(renderer, 4, rng):
        image = renderer.render(rig.left, rvec, tvec, rng)
        found = detect(board, image)
        assert found is not None
        truth = renderer.corners_px(rig.left, rvec, tvec)[found.ids]
        errors.append(np.linalg.norm(found.image_px - truth, axis=1))
    error = np.concatenate(errors)
    assert error.mean() < 0.15, f"mean corner error {error.mean():.3f} px"
    assert np.percentile(error, 95) < 0.35


def test_no_board_is_not_detected() -> None:
    rng = np.random.default_rng(0)
    noise = rng.integers(0, 255, (240, 320), dtype=np.uint8)
    assert detect(CHESS, noise) is None
    assert detect(CHARUCO, noise) is None


def _true_corner_dy(model: StereoModel, board: Board, count: int) -> np.ndarray:
    """|dy| after rectification of exact (noise-free) corner projections of the true rig."""
    rig = default_rig()
    renderer = BoardRenderer(board, rig)
    rng = np.random.default_rng(99)
    (k1, d1, r1, p1), (k2, d2, r2, p2) = rectification(model)
    dys = []
    for rvec, tvec in sample_poses(renderer, count, rng):
        left = renderer.corners_px(rig.left, rvec, tvec).reshape(-1, 1, 2)
        right = renderer.corners_px(rig.right, rvec, tvec).reshape(-1, 1, 2)
        left_r = cv2.undistortPoints(left, k1, d1, R=r1, P=p1).reshape(-1, 2)
        right_r = cv2.undistortPoints(right, k2, d2, R=r2, P=p2).reshape(-1, 2)
        dys.append(np.abs(left_r[:, 1] - right_r[:, 1]))
    return np.concatenate(dys)


def test_calibrate_command_recovers_the_virtual_rig(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder = tmp_path / "shots"
    write_pairs(folder, CHESS, default_rig(), 14, seed=5)
    # A pair whose board moved between the two shots, and a pair without the board.
    shutil.copy(folder / "left" / "003.png", folder / "left" / "900-moved.png")
    shutil.copy(folder / "right" / "007.png", folder / "right" / "900-moved.png")
    blank = np.full((480, 640), 110, np.uint8)
    cv2.imwrite(str(folder / "left" / "901-empty.png"), blank)
    cv2.imwrite(str(folder / "right" / "901-empty.png"), blank)
    # And a pair whose left image is cut off mid-file (a copy interrupted).
    whole = (folder / "left" / "004.png").read_bytes()
    (folder / "left" / "902-cut.png").write_bytes(whole[: len(whole) // 3])
    shutil.copy(folder / "right" / "004.png", folder / "right" / "902-cut.png")
    out = tmp_path / "calib.yaml"

    args = ["calibrate", str(folder), "--squares", "10x7", "--square-mm", "50", "--out", str(out)]
    assert main(args) == 0

    printed = capsys.readouterr().out
    assert "900-moved.png" in printed and "board moved" in printed
    assert "901-empty.png" in printed and "board not found" in printed
    assert "902-cut.png" in printed and "cannot read the image" in printed
    assert "RMS reprojection error" in printed and "rectification check" in printed
    truth = default_rig()
    calibration = load_calibration(out)  # the file is read back like any other
    assert calibration.maps is not None
    text = out.read_text()
    model = StereoModel.model_validate(__import__("yaml").safe_load(text)["stereo"])
    baseline_m = float(np.linalg.norm(model.T_m))
    assert baseline_m == pytest.approx(truth.baseline_m, rel=0.01)
    assert model.K1[0][0] == pytest.approx(truth.left.k[0, 0], rel=0.01)
    assert model.K1[1][1] == pytest.approx(truth.left.k[1, 1], rel=0.01)
    assert model.K2[0][0] == pytest.approx(truth.right.k[0, 0], rel=0.01)
    assert calibration.rig.baseline_m == pytest.approx(truth.baseline_m, rel=0.01)
    dy = _true_corner_dy(model, CHESS, 6)
    assert dy.max() < 0.3, f"rectified |dy| max {dy.max():.3f} px"
    assert "14 of 17 pairs used" in text


def _observe_rendered(board: Board, count: int, seed: int) -> list[PairObservation | PairReport]:
    """Render ``count`` pairs through the default rig and detect the board in both views."""
    rig = default_rig()
    renderer = BoardRenderer(board, rig)
    rng = np.random.default_rng(seed)
    observations = []
    for index, (rvec, tvec) in enumerate(sample_poses(renderer, count, rng)):
        left = detect(board, renderer.render(rig.left, rvec, tvec, rng))
        right = detect(board, renderer.render(rig.right, rvec, tvec, rng))
        observations.append(observe_pair(board, f"{index}", left, right))
    return observations


def test_charuco_round_trip() -> None:
    rig = default_rig()
    result = calibrate((640, 480), _observe_rendered(CHARUCO, 12, 11))
    assert all(p.used for p in result.pairs)
    assert float(np.linalg.norm(result.model.T_m)) == pytest.approx(rig.baseline_m, rel=0.01)
    assert result.model.K1[0][0] == pytest.approx(rig.left.k[0, 0], rel=0.01)
    assert result.dy_mean_px < 0.3
    assert _true_corner_dy(result.model, CHARUCO, 4).max() < 0.3


def test_too_few_pairs_fail_with_advice(tmp_path: Path) -> None:
    with pytest.raises(CalibrationFailed, match="only 3 usable pairs"):
        calibrate((640, 480), _observe_rendered(CHESS, 3, 2))
    write_pairs(tmp_path, CHESS, default_rig(), 2)
    assert main(["calibrate", str(tmp_path), "--out", str(tmp_path / "c.yaml")]) == 1
    assert not (tmp_path / "c.yaml").exists()


def test_charuco_options_need_a_marker_size(tmp_path: Path) -> None:
    args = ["calibrate", str(tmp_path), "--pattern", "charuco", "--out", str(tmp_path / "c.yaml")]
    assert main(args) == 2


MIDDLEBURY = """cam0=[1000.5 0 300.25; 0 1000.5 200.75; 0 0 1]
cam1=[1000.5 0 350.5; 0 1000.5 200.75; 0 0 1]
doffs=50.25
baseline=120.5
width=640
height=480
ndisp=64
"""


def test_middlebury_import(tmp_path: Path) -> None:
    path = tmp_path / "calib.txt"
    path.write_text(MIDDLEBURY)
    rig = middlebury_rectified(path)
    assert (rig.fx, rig.cx, rig.cy, rig.doffs) == (1000.5, 300.25, 200.75, pytest.approx(50.25))
    assert rig.baseline_m == pytest.approx(0.1205)
    assert read_middlebury(path).ndisp == 64
    out = tmp_path / "rig.yaml"
    assert main(["import-calibration", "middlebury", str(path), "--out", str(out)]) == 0
    loaded = load_calibration(out).rig
    assert loaded.doffs_px == pytest.approx(50.25) and loaded.width == 640
    path.write_text(MIDDLEBURY.replace("doffs=50.25", "doffs=12"))
    with pytest.raises(ConfigError, match="doffs"):
        middlebury_rectified(path)
    path.write_text(MIDDLEBURY.replace("baseline=120.5\n", ""))
    with pytest.raises(ConfigError, match="baseline"):
        middlebury_rectified(path)
    path.write_text(MIDDLEBURY.replace("width=640\n", ""))
    with pytest.raises(ConfigError, match="needs width="):
        middlebury_rectified(path)


def _euroc_yaml(path: Path, body_from_sensor: np.ndarray, cx: float) -> None:
    data = ", ".join(f"{v:.12f}" for v in body_from_sensor.ravel())
    path.write_text(
        "%YAML:1.0\nsensor_type: camera\nT_BS:\n  cols: 4\n  rows: 4\n"
        f"  data: [{data}]\nrate_hz: 20\nresolution: [752, 480]\ncamera_model: pinhole\n"
        f"intrinsics: [450.0, 451.0, {cx}, 250.0]\ndistortion_model: radial-tangential\n"
        "distortion_coefficients: [-0.28, 0.07, 0.0002, 0.00001]\n"
    )


def test_euroc_import_composes_body_transforms(tmp_path: Path) -> None:
    # Both cameras look along body x; the right one sits 0.11 m further along body y.
    camera_from_body = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    left, right = np.eye(4), np.eye(4)
    left[:3, :3] = right[:3, :3] = camera_from_body.T
    left[:3, 3] = (0.05, -0.02, 0.0)
    right[:3, 3] = (0.05, 0.09, 0.0)
    _euroc_yaml(tmp_path / "cam0.yaml", left, 370.0)
    _euroc_yaml(tmp_path / "cam1.yaml", right, 380.0)
    model = euroc_stereo(tmp_path / "cam0.yaml", tmp_path / "cam1.yaml")
    np.testing.assert_allclose(model.T_m, (-0.11, 0.0, 0.0), atol=1e-9)
    np.testing.assert_allclose(model.R, np.eye(3), atol=1e-9)
    assert model.K2[0][2] == 380.0 and model.D1 == [-0.28, 0.07, 0.0002, 0.00001]
    (tmp_path / "cam1.yaml").write_text(
        (tmp_path / "cam1.yaml").read_text().replace("pinhole", "omni")
    )
    with pytest.raises(ConfigError, match="only pinhole"):
        euroc_stereo(tmp_path / "cam0.yaml", tmp_path / "cam1.yaml")


def test_euroc_sequence_rectifies_below_one_pixel(data_dir: Path, tmp_path: Path) -> None:
    mav0 = data_dir / "euroc" / "V1_01_easy_micro" / "mav0"
    out = tmp_path / "euroc.yaml"
    cams = [str(mav0 / "cam0" / "sensor.yaml"), str(mav0 / "cam1" / "sensor.yaml")]
    assert main(["import-calibration", "euroc", *cams, "--out", str(out)]) == 0
    assert load_calibration(out).rig.baseline_m == pytest.approx(0.110, abs=0.002)

    figures_json = tmp_path / "dy.json"
    args = ["check-rectification", "--calibration", str(out), str(mav0), "--max-pairs", "10"]
    assert main([*args, "--json", str(figures_json)]) == 0
    figures = json.loads(figures_json.read_text())
    assert figures["matches"] > 300 and figures["board_pairs"] == 0
    assert figures["mean"] < 0.5 and figures["median"] < 0.3, figures

    # The check has teeth: the same rig with the right camera rolled by half a degree fails it.
    model = euroc_stereo(mav0 / "cam0" / "sensor.yaml", mav0 / "cam1" / "sensor.yaml")
    roll, _ = cv2.Rodrigues(np.array([0.0, 0.0, np.radians(0.5)]))
    tilted = model.model_copy(update={"R": tuple(map(tuple, roll @ np.asarray(model.R)))})
    from avoidd.vision.calibration import write_calibration

    write_calibration(out, tilted)
    assert main([*args, "--json", str(figures_json)]) == 1
    assert json.loads(figures_json.read_text())["mean"] > 1.0


def _rolled(path: Path, out: Path, degrees: float) -> None:
    """Write the calibration at ``path`` with its right camera rolled by ``degrees``."""
    from avoidd.vision.calibration import write_calibration

    model = StereoModel.model_validate(__import__("yaml").safe_load(path.read_text())["stereo"])
    roll, _ = cv2.Rodrigues(np.array([0.0, 0.0, np.radians(degrees)]))
    write_calibration(
        out, model.model_copy(update={"R": tuple(map(tuple, roll @ np.asarray(model.R)))})
    )


def test_check_rectification_verdict_on_rendered_board_pairs(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder, good, wrong = tmp_path / "shots", tmp_path / "calib.yaml", tmp_path / "rolled.yaml"
    write_pairs(folder, CHESS, default_rig(), 10, seed=3)
    assert main(["calibrate", str(folder), "--square-mm", "50", "--out", str(good)]) == 0
    figures_json = tmp_path / "dy.json"
    capsys.readouterr()

    # The board's own corners: every pair shows it, so every pair is measured on them.
    assert (
        main(
            [
                "check-rectification",
                "--calibration",
                str(good),
                str(folder),
                "--json",
                str(figures_json),
            ]
        )
        == 0
    )
    figures = json.loads(figures_json.read_text())
    assert figures["board_pairs"] == 10 and figures["mean"] < 0.15, figures
    assert "PASS" in capsys.readouterr().out

    # Another board size is not found: features alone, whose repeated corners must not be paired
    # with their neighbours (they gave a mean |dy| of several pixels).
    other_board = ["--squares", "9x4"]
    assert (
        main(
            [
                "check-rectification",
                "--calibration",
                str(good),
                str(folder),
                *other_board,
                "--json",
                str(figures_json),
            ]
        )
        == 0
    )
    figures = json.loads(figures_json.read_text())
    assert figures["board_pairs"] == 0 and figures["matches"] > 100
    assert figures["mean"] < 0.5 and figures["median"] < 0.1, figures

    # A calibration with the right camera rolled by one degree fails, on the board and without.
    _rolled(good, wrong, 1.0)
    capsys.readouterr()
    for extra in ([], other_board):
        assert main(["check-rectification", "--calibration", str(wrong), str(folder), *extra]) == 1
        assert "FAIL: mean |dy|" in capsys.readouterr().out
