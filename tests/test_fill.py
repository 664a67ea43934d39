"""The fill for autopilots that read an unknown bin as nothing (avoidd.mavlink.fill)."""

from __future__ import annotations

import numpy as np

from avoidd.mavlink.fill import fill_from_neighbours
from avoidd.types import SECTOR_COUNT

NAN, CLEAR = np.nan, np.inf


def _scan(values: dict[int, float]) -> np.ndarray:
    distance = np.full(SECTOR_COUNT, NAN, dtype=np.float32)
    for index, value in values.items():
        distance[index] = value
    return distance


def _view(first: int, last: int) -> np.ndarray:
    view = np.zeros(SECTOR_COUNT, dtype=np.bool_)
    view[first : last + 1] = True
    return view


def test_an_unknown_bin_beside_readings_takes_the_nearer_one() -> None:
    scan = _scan({3: 4.0, 4: NAN, 5: 2.5, 6: CLEAR})
    filled = fill_from_neighbours(scan, _view(0, 10))
    assert filled[4] == np.float32(2.5)
    assert filled.dtype == scan.dtype and np.isnan(scan[4])  # the input is left as it was


def test_clear_lends_nothing_and_a_bin_with_no_reading_beside_it_stays_unknown() -> None:
    scan = _scan({2: CLEAR, 3: NAN, 4: CLEAR, 6: 3.0})
    filled = fill_from_neighbours(scan, _view(0, 10))
    assert np.isnan(filled[3])  # between clear bins: unknown, never clear
    assert filled[5] == np.float32(3.0) and filled[7] == np.float32(3.0)
    assert np.isnan(filled[8])  # a filled bin lends nothing: the fill never spreads
    assert np.isposinf(filled[2]) and np.isposinf(filled[4]) and filled[6] == np.float32(3.0)


def test_bins_outside_every_view_stay_unknown() -> None:
    scan = _scan({10: 2.0, 11: NAN})
    filled = fill_from_neighbours(scan, _view(5, 10))
    assert filled[9] == np.float32(2.0)  # in view
    assert np.isnan(filled[11])


def test_the_bins_wrap_round_behind() -> None:
    scan = _scan({0: NAN, 71: 1.5, 70: NAN})
    view = np.ones(SECTOR_COUNT, dtype=np.bool_)
    filled = fill_from_neighbours(scan, view)
    assert filled[0] == np.float32(1.5) and filled[70] == np.float32(1.5)
    assert np.isnan(filled[1])
