"""The perception targets on rendered scenes with exact truth (see avoidd.evaluation.scenes).

Targets (issue: perception): within the range where one pixel of disparity is at most 10% of
depth, the nearest-obstacle distance has a median error <= 2% and a 95th percentile <= 5%;
every obstacle (all are at least 0.1 m wide) is reported in its bin; obstacle-free ground seen
with roll and pitch up to 20 degrees gives no obstacle bin; the paper's ground-plane geometry
agrees with stereo within 3% at ground contacts where its model holds.

The targets are asserted on three draws of the suite (``SEEDS``), not one. The no-false-bin
target does not hold on all of them: that test asserts the bound measured instead.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from avoidd.config import HeadConfig
from avoidd.evaluation.scenes import (
    SceneCase,
    SuiteSummary,
    contact_suite,
    draws,
    run_suite,
    suite,
)
from avoidd.pipeline import HeadPipeline
from avoidd.sources.files import FolderSource
from avoidd.sources.scene import render_pair, to_uint8
from avoidd.vision.calibration import Calibration

pytestmark = pytest.mark.timeout(400)
"""The suite's fixture renders and runs 114 scenes: 81 s idle on this 2-core machine
(2026-11-27), over the project's 120 s per test with two busy processes beside it. The timeout
guards against a hang, not a speed."""

SEEDS = (2024, 1, 2)
"""Three draws of the suite: the default one and the next two seeds, chosen before measuring."""


@pytest.fixture(scope="module")
def summary() -> SuiteSummary:
    return run_suite(draws(SEEDS) + contact_suite())


def test_draws_are_named_apart() -> None:
    names = [case.name for case in draws((2024, 1))]
    assert len(set(names)) == len(names) == 68
    assert names[0] == "2024/pole-00" and names[34] == "1/pole-00"


def test_nearest_distance_error(summary: SuiteSummary) -> None:
    errors = summary.errors_pct
    assert len(errors) == 24 * len(SEEDS) + 12  # and the contact scenes
    assert summary.percentile(50) <= 2.0, summary.format()
    assert summary.percentile(95) <= 5.0, summary.format()
    for seed in SEEDS:  # and on each draw alone
        draw = SuiteSummary([r for r in summary.results if r.name.startswith(f"{seed}/")])
        assert draw.percentile(50) <= 2.0 and draw.percentile(95) <= 5.0, draw.format()


def test_every_obstacle_in_its_bin(summary: SuiteSummary) -> None:
    assert summary.missed == [], summary.format()


def test_no_false_bins(summary: SuiteSummary) -> None:
    # Before the ground check (avoidd.perception.ground_match) this target did not hold on
    # every draw: two false bins in one obstacle-free ground scene seen by the near rig at 20
    # degrees of vehicle pitch (seed 2, ground-r+0-p+20-fb48), three in two such scenes over
    # seeds 1-7 and 2024 (272 scenes); now none there (docs/perception.md).
    ground = [r for r in summary.results if "/ground" in r.name]
    assert len(ground) == 10 * len(SEEDS)
    assert summary.false_bins == [], summary.format()


def test_ground_plane_geometry_agrees_with_stereo_at_contacts(summary: SuiteSummary) -> None:
    contacts = summary.contact_errors_pct
    assert len(contacts) >= 10
    assert max(abs(c) for c in contacts) <= 3.0, summary.format()


def _write_recording(folder: Path, case: SceneCase, attitude: bool) -> None:
    rendered = render_pair(case.scene, case.rig)
    rng = np.random.default_rng(3)
    (folder / "left").mkdir(parents=True)
    (folder / "right").mkdir()
    for view, image in (("left", rendered.left), ("right", rendered.right)):
        noise = rng.normal(0.0, 1.5, image.shape).astype(np.float32)
        cv2.imwrite(str(folder / view / "0000.png"), to_uint8(image, noise))
    roll, pitch = case.scene.vehicle_roll_deg, case.scene.vehicle_pitch_deg
    lines = (
        ["t_capture_ns,roll_deg,pitch_deg,height_m", f"0,{roll},{pitch},1.5"]
        if attitude
        else ["t_capture_ns", "0"]
    )
    (folder / "frames.csv").write_text("\n".join(lines) + "\n")


def test_a_recordings_attitude_is_used_for_the_ground(tmp_path: Path) -> None:
    """Tilted ground from a recording: clear with its attitude, false obstacles without."""
    case = next(c for c in suite() if c.name == "ground-r+20-p-20-fb48")
    finite_bins = {}
    for attitude in (True, False):
        folder = tmp_path / f"attitude-{attitude}"
        _write_recording(folder, case, attitude)
        frame = FolderSource(folder, None, paced=False, loop=False).read()
        head = HeadConfig.model_validate(
            {
                "name": "front",
                "calibration": __file__,
                "source": {"kind": "synthetic"},
                "matcher": {"kind": "sgbm", "num_disparities": 128},
            }
        )
        pipeline = HeadPipeline(head, Calibration(case.rig, None, folder), 20.0)
        result = pipeline.process(frame)
        assert result.pose is not None
        assert result.pose.source == ("recording" if attitude else "config")
        finite_bins[attitude] = int(np.count_nonzero(np.isfinite(result.scan.distance_m)))
    assert finite_bins[True] == 0
    assert finite_bins[False] > 0


def test_a_suite_without_ranged_scenes_still_prints_its_table() -> None:
    # eval-perception --scenes 0 --edge-scenes N used to end in a StatisticsError.
    text = SuiteSummary([]).format()
    assert "no scene with an obstacle to range" in text and "false bins: 0" in text
