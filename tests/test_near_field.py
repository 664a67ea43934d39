"""The near field: nothing nearer than the main search range reads farther than it is."""

from __future__ import annotations

import math

import numpy as np
import pytest

from avoidd.config import NearFieldConfig, PostprocessConfig
from avoidd.evaluation.near import format_near, near_suite, run_near_case
from avoidd.vision.nearfield import NearField, unseen_behind


def _field(main_disparities: int = 64) -> NearField:
    return NearField(main_disparities, NearFieldConfig(scale=4, num_disparities=64))


def test_the_coarse_pass_reaches_four_times_farther_and_sets_the_minimum_range() -> None:
    field = _field()
    assert field.max_disparity_px == 63 * 4
    # The demo rig: f B = 48 px m reaches 0.76 m with 64 disparities, 0.19 m with the pass.
    assert field.min_range_m(48.0) == pytest.approx(48.0 / 252.0)


def test_merge_takes_the_coarse_pass_only_beyond_the_main_range() -> None:
    main = np.full((4, 600), 10.0, dtype=np.float32)
    coarse = np.full((4, 600), 10.5, dtype=np.float32)
    coarse[1, 550:] = 120.0  # a near surface the main matcher read at 10 px
    coarse[2, 560:] = 300.0  # beyond the coarse range too: the object may be nearer still
    result = _field().merge(main, coarse)
    merged = result.disparity
    assert merged[0, 400] == 10.0  # in range: the main matcher's value stays
    assert np.all(merged[1, 550:] == 120.0)
    assert np.all(merged[2, 560:] == 252.0)  # put at the limit: read at the minimum range
    assert result.saturated_pixels == 40
    assert result.near_pixels == 50 + 40
    # What the right camera cannot see is dropped: behind the near surfaces in their rows,
    # and left of the largest near disparity in every row.
    assert np.isnan(merged[1, 430:550]).all() and np.isnan(merged[0, :252]).all()
    assert np.all(main == 10.0)  # the input is not modified


class _GivenCoarse(NearField):
    """The real merge on a coarse map the test chooses (the coarse matcher's guesses)."""

    def __init__(self, coarse: np.ndarray) -> None:
        super().__init__(64, NearFieldConfig(scale=4, num_disparities=64), PostprocessConfig())
        self._given = coarse

    def coarse(self, left: np.ndarray, right: np.ndarray) -> np.ndarray:
        return self._given.copy()


def test_coarse_guesses_in_featureless_sky_or_alone_do_not_blank_the_left_band() -> None:
    # A textured scene under 40 rows of plain sky; the main matcher measured it all at 10.
    # A few rows of open sky that the coarse pass read as near (seen in a rendered scene:
    # rows 0-3 across 450 columns) blanked every row left of their disparity, and with it a
    # 5 cm pole at 5 m. Neither sky nor a lone coarse pixel (4 x 4 px) is a surface; a
    # textured patch two coarse pixels across is, and still blanks the band.
    rng = np.random.default_rng(4)
    height, width = 120, 400
    left = rng.integers(0, 255, (height, width)).astype(np.uint8)
    left[:40] = 190
    right = left.copy()
    main = np.full((height, width), 10.0, dtype=np.float32)
    coarse = np.full((height, width), 10.0, dtype=np.float32)
    coarse[0:4, 150:380] = 160.0  # the sky
    coarse[60:64, 300:304] = 160.0  # one coarse pixel of texture
    result = _GivenCoarse(coarse).apply(left, right, main)
    assert result.near_pixels == 0 and result.blanked_pixels == 0
    assert np.array_equal(result.disparity, main)
    coarse[80:88, 300:308] = 160.0  # a patch two coarse pixels across
    result = _GivenCoarse(coarse).apply(left, right, main)
    assert result.near_pixels == 64
    assert np.isnan(result.disparity[50, :150]).all()


def test_what_the_right_camera_cannot_see_is_dropped() -> None:
    # One row, a near surface at columns 100..119 with disparity 60: the right camera sees
    # nothing of columns 40..99 behind it, and a continuation left of column 60 would be
    # outside its view in every row.
    disparity = np.full((3, 160), 5.0, dtype=np.float32)
    near = np.zeros((3, 160), dtype=np.bool_)
    disparity[1, 100:120] = 60.0
    near[1, 100:120] = True
    hidden = unseen_behind(disparity, near)
    assert hidden[1, 40:100].all()
    assert not hidden[1, 120:].any() and not hidden[1, 100:120].any()
    assert hidden[0, :60].all() and hidden[2, :60].all()
    assert not hidden[0, 60:].any() and not hidden[2, 60:].any()
    assert not unseen_behind(disparity, np.zeros_like(near)).any()


def test_rendered_walls_boxes_and_poles_from_30_cm_never_read_farther() -> None:
    # Seeded scenes (distance 0.3..1.2 m, bearing +-30 deg, sizes, tilt and attitude drawn by
    # the generator, never picked): every bin holding an obstacle reads it within 10% or
    # nearer, or says unknown. Without the near-field pass a wall at 0.3 m read 2.4 m and
    # one bin 16 m (see docs/perception.md, `avoidd eval-perception --near-scenes`).
    results = [run_near_case(case) for case in near_suite(24, seed=3030)]
    print(format_near(results))
    farther = [(r.name, f) for r in results for f in r.farther]
    assert farther == []
    # And it is not all unknown: most occupied bins carry a reading.
    occupied = sum(r.occupied_bins for r in results)
    unknown = sum(r.unknown_bins for r in results)
    assert unknown < 0.25 * occupied
    nearest_errors = [
        abs(r.measured_m / r.truth_m - 1.0) for r in results if r.measured_m is not None
    ]
    assert len(nearest_errors) == len(results)
    assert max(nearest_errors) < 0.10
    assert all(math.isfinite(r.truth_m) for r in results)
