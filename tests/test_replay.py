from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from avoidd.cli import main
from avoidd.sources.synthetic import SyntheticSource
from avoidd.types import RectifiedRig
from tests.helpers import RIG_320, synthetic_config

SOURCE = {
    "kind": "synthetic",
    "fps": 10,
    "seed": 2,
    "obstacles": [{"shape": "box", "forward_m": 3.0, "right_m": -0.8, "width_m": 0.8}],
}


def read_lines(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()]


def test_replay_synthetic_writes_one_object_per_frame(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    config = synthetic_config(tmp_path, "udpout:127.0.0.1:14550", source=SOURCE)
    out = tmp_path / "out" / "replay.jsonl"
    assert main(["replay", "--config", str(config), "--max-frames", "4", "--out", str(out)]) == 0
    records = read_lines(out)
    assert [r["seq"] for r in records] == [0, 1, 2, 3]
    assert [r["t_capture_ns"] for r in records] == [0, 100_000_000, 200_000_000, 300_000_000]
    for index, record in enumerate(records):
        assert set(record) >= {
            "seq",
            "t_capture_ns",
            "nearest",
            "sectors_cm",
            "raw_sectors_cm",
            "obstacles",
            "pose",
            "timing_ms",
            "truth",
        }
        assert len(record["sectors_cm"]) == 72
        assert set(record["timing_ms"]) == {
            "rectify",
            "preprocess",
            "match",
            "post",
            "depth",
            "obstacles",
            "encode",
        }
        truth = record["truth"]
        nearest = record["nearest"]
        assert truth["nearest_m"] == pytest.approx(3.0 - 0.5, rel=0.05)
        assert nearest["distance_m"] == pytest.approx(truth["nearest_m"], rel=0.03)
        truth_bin = round(truth["nearest_bearing_deg"] / 5) % 72
        raw = record["raw_sectors_cm"][truth_bin]
        assert raw == pytest.approx(truth["nearest_m"] * 100, rel=0.03)
        # A new obstacle waits for a second frame (2 of 3) before it is sent; until then its
        # bin is unknown, neither clear nor an obstacle.
        assert record["sectors_cm"][truth_bin] == (65535 if index == 0 else raw)
        obstacle = record["obstacles"][0]
        assert obstacle["distance_m"] == pytest.approx(truth["nearest_m"], rel=0.03)
        # Across the line of sight the box (0.8 wide, 1 deep, centre 14.9 deg left) shows its
        # front and one side: 0.8 cos + 1.0 sin of that angle.
        seen_at = math.atan2(0.8, 3.0)
        expected_width = 0.8 * math.cos(seen_at) + 1.0 * math.sin(seen_at)
        assert obstacle["width_m"] == pytest.approx(expected_width, rel=0.1)
        assert obstacle["height_m"] > 1.5  # the 3 m box, seen from 1.5 m up, minus the margin
        assert record["pose"]["height_m"] == 1.5 and record["pose"]["source"] == "synthetic"
    assert "nearest vs truth: median error" in capsys.readouterr().out


def test_replay_of_an_image_folder(tmp_path: Path) -> None:
    config = synthetic_config(tmp_path, "udpout:127.0.0.1:14550", source=SOURCE)
    rig = RectifiedRig(**{k if k != "doffs" else "doffs_px": v for k, v in RIG_320.items()})
    from avoidd.config import SyntheticSourceConfig

    source = SyntheticSource(SyntheticSourceConfig.model_validate(SOURCE), rig, paced=False)
    folder = tmp_path / "pairs"
    (folder / "left").mkdir(parents=True)
    (folder / "right").mkdir()
    for i in range(3):
        frame = source.read()
        cv2.imwrite(str(folder / "left" / f"{i:03d}.png"), frame.left)
        cv2.imwrite(str(folder / "right" / f"{i:03d}.png"), frame.right)
    (folder / "left" / "003.png").write_bytes(b"broken")
    cv2.imwrite(str(folder / "right" / "003.png"), frame.right)
    out = tmp_path / "folder.jsonl"
    code = main(["replay", "--config", str(config), "--input", str(folder), "--out", str(out)])
    assert code == 0
    records = read_lines(out)
    assert len(records) == 3  # the broken pair is dropped, not fatal
    assert all("truth" not in r for r in records)
    distances = [r["nearest"]["distance_m"] for r in records]
    assert np.allclose(distances, 2.5, rtol=0.03)


def test_replay_of_a_head_that_does_not_exist(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    config = synthetic_config(tmp_path, "udpout:127.0.0.1:14550", source=SOURCE)
    code = main(["replay", "--config", str(config), "--head", "rear", "--out", str(tmp_path / "x")])
    assert code == 2
    assert "--head rear: no such head; the config has front" in capsys.readouterr().err


def test_replay_plot_draws_the_nearest_reading_beside_the_truth(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from avoidd.replay_plot import read_records, series_of

    config = synthetic_config(tmp_path, "udpout:127.0.0.1:14550", source=SOURCE)
    out, plot = tmp_path / "replay.jsonl", tmp_path / "plots" / "nearest.png"
    argv = ["replay", "--config", str(config), "--max-frames", "4", "--out", str(out)]
    assert main([*argv, "--plot", str(plot)]) == 0
    assert f"wrote {plot}" in capsys.readouterr().out
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    series = series_of(read_records(out))
    assert series.t_s == pytest.approx([0.0, 0.1, 0.2, 0.3])
    assert series.has_truth
    for read, truth in zip(series.nearest_m, series.truth_m, strict=True):
        assert read is not None and truth is not None
        assert read == pytest.approx(truth, rel=0.03)


def test_a_replay_series_without_truth_or_reading_keeps_the_gaps() -> None:
    from avoidd.replay_plot import series_of

    records = [
        {"t_capture_ns": 5_000_000_000, "nearest": {"distance_m": 4.0}, "truth": None},
        {"t_capture_ns": 5_500_000_000, "nearest": None},
    ]
    series = series_of(records)
    assert series.t_s == [0.0, 0.5]
    assert series.nearest_m == [4.0, None]
    assert series.truth_m == [None, None] and not series.has_truth
