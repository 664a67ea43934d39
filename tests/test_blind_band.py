"""The left border band's blind zone: readings kept, a surface hidden nearer never read past.

At column x of the left view nothing nearer than f B / x can be matched (its match is outside
the right image). The band's confirmed readings stand; a bin whose band pixels are left
unmeasured where its reading's surface would be measurable holds something nearer that no
match can see, and reads unknown (``avoidd.perception.blind_band``).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from avoidd.config import PerceptionConfig
from avoidd.evaluation.scenes import NEAR_RIG, SceneCase, noisy_frame, suite_head, truth_bins
from avoidd.perception.blind_band import hidden_bins, patch_side_px, settle_hidden
from avoidd.perception.frames import Pose
from avoidd.pipeline import HeadPipeline
from avoidd.sources.scene import Box, Pole, Scene, render_pair
from avoidd.types import SECTOR_COUNT, SectorScan
from avoidd.vision.calibration import Calibration

LEVEL = Pose(np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]), np.zeros(3))
"""A level camera looking along forward (camera x right, y down, z forward)."""


def _run(obstacles: tuple[Box | Pole, ...], seed: int = 7) -> tuple[dict[int, float], np.ndarray]:
    scene = Scene(
        camera_height_m=1.5, camera_pitch_deg=0.0, obstacles=obstacles, backdrop_m=45.0, seed=seed
    )
    case = SceneCase("blind", NEAR_RIG, scene, 0.0)
    rendered = render_pair(scene, NEAR_RIG)
    pipeline = HeadPipeline(
        suite_head(case, 64), Calibration(NEAR_RIG, None, Path("blind")), 20.0, PerceptionConfig()
    )
    result = pipeline.process(noisy_frame(case, rendered, 1.5))
    truth = truth_bins(
        rendered.truth,
        pipeline.mount,
        case.pose,
        PerceptionConfig(),
        NEAR_RIG.fx * pipeline.sectors.min_size_m,
    )
    return truth, result.scan.distance_m


def _lateral_m(column: float, forward_m: float) -> float:
    return (column - NEAR_RIG.cx) * forward_m / NEAR_RIG.fx


@pytest.mark.parametrize(
    ("forward_m", "diameter_m", "column"), [(1.5, 0.05, 12), (2.0, 0.05, 8), (1.0, 0.05, 30)]
)
def test_a_thin_pole_hidden_in_the_band_never_lets_the_wall_behind_it_through(
    forward_m: float, diameter_m: float, column: int
) -> None:
    # A pole narrower than the baseline (0.12 m) stands so near the left edge that its
    # disparity exceeds its column: the right camera does not see it at all. The textured
    # wall behind it at 6 m is measured around it. The pole's bins must read it or unknown,
    # never the wall (with the band's readings kept but no blind-zone rule, bin 65 read the
    # wall, 7.1-7.2 m, in the first two cases).
    wall = Box(6.15, -3.0, 0.3, 8.0, 3.0)
    pole = Pole(forward_m + diameter_m / 2, _lateral_m(column, forward_m), diameter_m, 3.0)
    truth, read = _run((wall, pole))
    pole_bins = [b for b, t in truth.items() if t < 3.0]
    assert pole_bins, truth
    for index in pole_bins:
        value = float(read[index])
        assert math.isnan(value) or value <= 1.1 * truth[index], (index, truth[index], value)


@pytest.mark.parametrize("forward_m", [2.5, 4.0])
def test_a_wall_across_the_band_is_read_there(forward_m: float) -> None:
    # A textured wall fills the view: the band's columns beyond its own blind zone (columns
    # above f B / Z) are matched and confirmed, so the bin the band covers (65, -35 deg) reads
    # the wall. Before, the band was blanked and the bin read unknown.
    truth, read = _run((Box(forward_m + 0.15, 0.0, 0.3, 12.0, 3.0),))
    assert 65 in truth
    assert abs(float(read[65]) - truth[65]) <= 0.1 * truth[65], (truth[65], read[65])


def test_hidden_bins_weighs_evidence_against_the_reading() -> None:
    # A level 640x480 rig (f B = 48). Bin 65 (-35 deg) spans band columns 12-64.
    band_px = 64
    evidence = np.zeros((NEAR_RIG.height, band_px), dtype=bool)
    distance = np.full(SECTOR_COUNT, np.nan, dtype=np.float32)
    distance[65] = 6.0  # depth 6 cos(35 deg) = 4.9 m there: disparity 9.8 px
    evidence[150:170, 30:50] = True  # 20 px square where the 6 m surface would be measured
    hidden = hidden_bins(evidence, NEAR_RIG, LEVEL, 0.05, 20, distance)
    assert hidden[65] and hidden.sum() == 1
    # Where the reading's own surface is blind (columns below its disparity) the same patch
    # says nothing: that surface runs on there.
    near = distance.copy()
    near[65] = 1.0  # disparity 59 px at the band's columns
    assert not hidden_bins(evidence, NEAR_RIG, LEVEL, 0.05, 20, near).any()
    # A patch smaller than the smallest obstacle would look there is noise.
    small = np.zeros_like(evidence)
    side = patch_side_px(30, NEAR_RIG.baseline_m, 0.05, 20)
    small[150 : 150 + side - 1, 30 : 30 + side - 1] = True
    assert not hidden_bins(small, NEAR_RIG, LEVEL, 0.05, 20, distance).any()
    # Clear is a reading too: a patch takes it away.
    clear = distance.copy()
    clear[65] = np.inf
    assert hidden_bins(evidence, NEAR_RIG, LEVEL, 0.05, 20, clear)[65]
    # Rays below the level (the ground, blind near the vehicle, grazing far away) are none.
    ground = np.zeros_like(evidence)
    ground[300:400, 20:60] = True
    assert not hidden_bins(ground, NEAR_RIG, LEVEL, 0.05, 20, clear).any()


def test_a_hidden_bin_never_reads_farther_or_clear() -> None:
    # With the band: readings 3, 5, clear, 13.02 m; without it: 10, 4, clear, 13.0 m. Hidden
    # bins take the no-farther reading without the band, else unknown; others stay.
    def scan(values: list[float]) -> SectorScan:
        distance = np.full(SECTOR_COUNT, np.nan, dtype=np.float32)
        distance[:4] = values
        points = np.zeros((SECTOR_COUNT, 3), dtype=np.float32)
        points[:4, 0] = values
        return SectorScan(0, distance, points)

    with_band = scan([3.0, 5.0, math.inf, 13.02])
    without = scan([10.0, 4.0, math.inf, 13.0])
    hidden = np.zeros(SECTOR_COUNT, dtype=bool)
    hidden[[0, 1, 2, 3]] = True
    settle_hidden(with_band, without, hidden)
    read = with_band.distance_m
    assert math.isnan(read[0])  # 10 m would be farther than the 3 m seen with the band
    assert read[1] == pytest.approx(4.0) and with_band.points_frd_m[1, 0] == pytest.approx(4.0)
    assert math.isnan(read[2])  # never clear over a hidden surface
    assert read[3] == pytest.approx(13.0)
    assert np.isnan(with_band.points_frd_m[[0, 2]]).all()
