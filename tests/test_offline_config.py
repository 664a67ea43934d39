"""Offline use without a link, --input over a missing source path, and what check-config tells."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from avoidd.cli import main
from avoidd.config import SyntheticSourceConfig
from avoidd.sources.synthetic import SyntheticSource
from avoidd.types import RectifiedRig
from tests.helpers import RIG_320, write_rectified_calibration, write_yaml

SOURCE = {
    "kind": "synthetic",
    "fps": 10,
    "seed": 2,
    "obstacles": [{"shape": "box", "forward_m": 3.0, "right_m": -0.8, "width_m": 0.8}],
}


def _pairs(folder: Path, count: int, csv: str | None = None) -> Path:
    rig = RectifiedRig(**{k if k != "doffs" else "doffs_px": v for k, v in RIG_320.items()})
    source = SyntheticSource(SyntheticSourceConfig.model_validate(SOURCE), rig, paced=False)
    (folder / "left").mkdir(parents=True)
    (folder / "right").mkdir()
    for i in range(count):
        frame = source.read()
        cv2.imwrite(str(folder / "left" / f"{i:03d}.png"), frame.left)
        cv2.imwrite(str(folder / "right" / f"{i:03d}.png"), frame.right)
    if csv is not None:
        (folder / "frames.csv").write_text(csv)
    return folder


def _config(tmp_path: Path, source: dict[str, object], mavlink: bool) -> Path:
    calibration = write_rectified_calibration(tmp_path)
    config: dict[str, object] = {
        "version": 1,
        "heads": [{"name": "front", "calibration": str(calibration), "source": source}],
    }
    if mavlink:
        config["mavlink"] = {"connection": "udpout:127.0.0.1:14550"}
    return write_yaml(tmp_path / "avoidd.yaml", config)


def test_replay_needs_no_mavlink_section(tmp_path: Path) -> None:
    config = _config(tmp_path, SOURCE, mavlink=False)
    out = tmp_path / "out.jsonl"
    assert main(["replay", "--config", str(config), "--max-frames", "2", "--out", str(out)]) == 0
    records = [json.loads(line) for line in out.read_text().splitlines()]
    assert len(records) == 2 and len(records[1]["sectors_cm"]) == 72


def test_run_without_a_connection_stops_with_the_fix(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    config = _config(tmp_path, SOURCE, mavlink=False)
    assert main(["run", "--config", str(config)]) == 2
    err = capsys.readouterr().err
    assert "mavlink.connection: not set" in err and "udpout:127.0.0.1:14550" in err


def test_input_replaces_a_configured_folder_that_does_not_exist(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder = _pairs(tmp_path / "pairs", 2)
    config = _config(tmp_path, {"kind": "files", "path": "nowhere"}, mavlink=False)
    # Without --input the missing folder is an error naming the line and the path...
    assert main(["check-config", str(config)]) == 2
    assert "heads[0].source.path: not found" in capsys.readouterr().err
    # ...with it, the configured path is not needed.
    out = tmp_path / "out.jsonl"
    args = ["replay", "--config", str(config), "--input", str(folder), "--out", str(out)]
    assert main(args) == 0
    assert len(out.read_text().splitlines()) == 2


@pytest.mark.parametrize(
    ("csv", "fragment"),
    [
        ("time,left\n1,2\n", "needs a header with a 't_capture_ns' column"),
        ("t_capture_ns\n1\nabc\n", "frames.csv:3: t_capture_ns is not an integer"),
        ("t_capture_ns,roll_deg\n1,0\n2,0\n", "give both or neither"),
        ("t_capture_ns,roll_deg,pitch_deg\n1,0,0\n2,0,95\n", "within +-90 degrees"),
        ("t_capture_ns,roll_deg,pitch_deg\n1,0,0\n2,nan,0\n", "roll_deg is not finite"),
    ],
)
def test_check_config_reads_a_recordings_frames_csv(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], csv: str, fragment: str
) -> None:
    _pairs(tmp_path / "rec", 2, csv)
    config = _config(tmp_path, {"kind": "files", "path": "rec"}, mavlink=True)
    assert main(["check-config", str(config)]) == 2
    err = capsys.readouterr().err
    assert fragment in err and "heads.front.source.path" in err


def test_check_config_tells_the_range_and_the_field_of_view(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder = _pairs(tmp_path / "rec", 2, "t_capture_ns\n0\n100000000\n")
    config = _config(tmp_path, {"kind": "files", "path": str(folder)}, mavlink=True)
    assert main(["check-config", str(config)]) == 0
    out = capsys.readouterr().out
    rig = RIG_320
    focal_baseline = rig["fx"] * rig["baseline_m"]
    # 64 disparities reach f B / 63; the near-field pass (4 x 63 px) four times nearer.
    assert f"f*B/(num_disparities-1) = {focal_baseline / 63:.2f} m" in out
    assert f"measures from {focal_baseline / 252:.2f} m (with the near-field pass" in out
    left = np.degrees(np.arctan((64 - rig["cx"]) / rig["fx"]))
    right = np.degrees(np.arctan((rig["width"] - 1 - rig["cx"]) / rig["fx"]))
    assert f"effective HFOV {right - left:.1f} deg" in out
    assert "OBSTACLE_DISTANCE range" in out


def test_avoidance_goals_from_config_mission_or_mavlink_are_valid_and_bad_ones_named(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    config = _config(tmp_path, SOURCE, mavlink=True)
    base = config.read_text()
    config.write_text(base + "avoidance: {enabled: true, follow_mission: true}\n")
    assert main(["check-config", str(config)]) == 0
    # Without a goal avoidance waits for one over MAVLink: valid.
    config.write_text(base + "avoidance: {enabled: true}\n")
    assert main(["check-config", str(config)]) == 0
    config.write_text(base + "avoidance: {enabled: true, follow_mission: maybe}\n")
    assert main(["check-config", str(config)]) == 2
    assert "avoidance.follow_mission" in capsys.readouterr().err
