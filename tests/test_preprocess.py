"""The paper's preprocessing: resize (with the rig), denoising, adaptive-threshold texture mask."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from avoidd.cli import main
from avoidd.types import RectifiedRig
from avoidd.vision.depth import depth_from_disparity
from avoidd.vision.preprocess import adaptive_texture_mask, denoise, resize, scale_rig
from tests.helpers import synthetic_config

SOURCE = {
    "kind": "synthetic",
    "fps": 10,
    "seed": 2,
    "obstacles": [{"shape": "box", "forward_m": 3.0, "right_m": -0.8, "width_m": 0.8}],
}


def test_resize_scales_the_rig_so_depth_is_unchanged() -> None:
    rig = RectifiedRig(640, 480, 400.0, 400.0, 319.5, 239.5, 0.12, 2.0)
    half = scale_rig(rig, 0.5)
    assert (half.width, half.height) == (320, 240)
    assert (half.fx, half.cx, half.cy) == (200.0, 159.5, 119.5)  # pixel centres map exactly
    assert half.baseline_m == rig.baseline_m and half.doffs_px == 1.0
    disparity = np.array([[24.0]], dtype=np.float32)
    assert depth_from_disparity(disparity * 0.5, half)[0, 0] == pytest.approx(
        depth_from_disparity(disparity, rig)[0, 0]
    )
    image = np.zeros((480, 640), np.uint8)
    assert resize(image, 0.5).shape == (240, 320)
    assert resize(image, 1.0) is image


def test_denoise_median_removes_salt_and_mean_smooths() -> None:
    image = np.full((30, 30), 100, np.uint8)
    image[10, 10] = 255
    assert denoise(image, 3, 0)[10, 10] == 100
    smoothed = denoise(image, 0, 3)
    assert 100 < smoothed[10, 10] < 255 and smoothed[11, 11] > 100
    assert denoise(image, 0, 0) is image


@pytest.mark.parametrize("method", ["mean", "median"])
def test_adaptive_threshold_marks_texture_not_flat_or_smooth(method: str) -> None:
    rng = np.random.default_rng(3)
    image = np.zeros((60, 90), np.uint8)
    image[:, :30] = 120  # flat
    image[:, 30:60] = np.linspace(0, 255, 30, dtype=np.float32).astype(np.uint8)[None, :]  # ramp
    image[:, 60:] = rng.integers(0, 255, (60, 30), dtype=np.uint8)  # texture
    mask = adaptive_texture_mask(image, method, 7, 4.0, 3)
    assert not mask[:, 5:25].any()
    assert mask[:, 65:85].all()
    # A smooth ramp (3 to 4 levels per pixel; local mean equals the pixel) has no texture.
    assert mask[:, 36:54].mean() < 0.2


def test_pipeline_with_preprocessing_still_finds_the_obstacle(tmp_path: Path) -> None:
    head = {
        "name": "front",
        "calibration": str(tmp_path / "calib.yaml"),
        "source": SOURCE,
        "matcher": {"kind": "sgbm", "num_disparities": 32},
        "preprocess": {
            "resize_scale": 0.5,
            "median_px": 3,
            "texture": {"method": "mean", "window_px": 7, "offset": 2.0},
        },
    }
    config = synthetic_config(tmp_path, "udpout:127.0.0.1:14550", heads=[head])
    out = tmp_path / "replay.jsonl"
    assert main(["replay", "--config", str(config), "--max-frames", "3", "--out", str(out)]) == 0
    records = [json.loads(line) for line in out.read_text().splitlines()]
    for record in records:
        steps = record["preprocess_steps_ms"]
        assert set(steps) == {
            "preprocess.resize",
            "preprocess.denoise",
            "preprocess.texture",
        }
        nearest, truth = record["nearest"], record["truth"]
        error = abs(nearest["distance_m"] - truth["nearest_m"]) / truth["nearest_m"]
        assert error < 0.06, (nearest, truth)  # half resolution: one pixel is worth more
        assert round(nearest["bearing_deg"] / 5) == round(truth["nearest_bearing_deg"] / 5)


def test_depth_histogram_counts_measured_depths_on_linear_edges() -> None:
    from avoidd.vision.depth import depth_histogram

    depth = np.array([[0.5, 1.2, 1.9, np.nan, np.inf, 25.0, 3.0]], dtype=np.float32)
    edges, counts = depth_histogram(depth, 0.0, 4.0, 4)
    np.testing.assert_allclose(edges, [0.0, 1.0, 2.0, 3.0, 4.0])
    assert counts.tolist() == [1, 2, 0, 1]  # NaN, inf and 25 m left out; 3.0 in the last bin


def test_replay_writes_the_depth_histogram(tmp_path: Path) -> None:
    config = synthetic_config(tmp_path, "udpout:127.0.0.1:14550", source=SOURCE)
    out = tmp_path / "replay.jsonl"
    assert main(["replay", "--config", str(config), "--max-frames", "1", "--out", str(out)]) == 0
    record = json.loads(out.read_text().splitlines()[0])
    histogram = record["depth_histogram"]
    assert len(histogram["edges_m"]) == 41 and len(histogram["counts"]) == 40  # defaults
    assert histogram["edges_m"][0] == 0.0 and histogram["edges_m"][-1] == 20.0
    # The box (centre 3 m ahead, 1 m deep) shows a face of about 16,000 pixels at 2.5 m: the
    # histogram peaks in a bin next to 2.5 m, and the two bins around it hold the face.
    counts = histogram["counts"]
    assert max(range(len(counts)), key=counts.__getitem__) in (4, 5)
    assert counts[4] + counts[5] > 12_000 and sum(counts[:4]) == 0
    assert sum(histogram["counts"]) <= 320 * 240 * record["valid_fraction"] + 1
