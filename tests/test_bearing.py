"""The vectorised bearing against float64 arctan2, in every quadrant and at the awkward points."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from avoidd.perception.bearing import bearing_rad
from avoidd.perception.workspace import Workspace


def _error_rad(got: np.ndarray, y: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Angular distance to the exact bearing (pi and -pi are one direction)."""
    exact = np.arctan2(y.astype(np.float64), x.astype(np.float64))
    difference = got.astype(np.float64) - exact
    return np.abs(np.remainder(difference + math.pi, 2.0 * math.pi) - math.pi)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_random_points_in_every_quadrant(seed: int) -> None:
    rng = np.random.default_rng(seed)
    count = 50_000
    scale = rng.choice([1e-3, 1.0, 30.0, 1e4], count)
    y = (rng.uniform(-1.0, 1.0, count) * scale).astype(np.float32)
    x = (rng.uniform(-1.0, 1.0, count) * scale).astype(np.float32)
    got = bearing_rad(y, x, np.empty(count, np.float32), Workspace())
    assert got.dtype == np.float32
    assert float(_error_rad(got, y, x).max()) < 1e-6
    # The range grid.py counts fine cells in: (-pi, pi], give or take a float32 step.
    assert float(got.min()) >= -math.pi - 1e-6
    assert float(got.max()) <= math.pi + 1e-6


def test_axes_diagonals_origin_and_huge_coordinates() -> None:
    pairs = [
        (0.0, 1.0),
        (1.0, 0.0),
        (-1.0, 0.0),
        (0.0, -1.0),
        (-0.0, -1.0),
        (1.0, 1.0),
        (-1.0, -1.0),
        (1.0, -1.0),
        (-1e30, -1e30),  # grid.py's stand-in for an unmeasured pixel
        (1e-30, -1e30),
        (3.0, -1e30),
        (1e-7, 5.0),
        (-1e-7, 5.0),
        (-1e-7, -5.0),
        (1e-7, -5.0),
    ]
    y = np.array([p[0] for p in pairs], np.float32)
    x = np.array([p[1] for p in pairs], np.float32)
    got = bearing_rad(y, x, np.empty(len(pairs), np.float32), Workspace())
    assert np.all(np.isfinite(got))
    assert float(_error_rad(got, y, x).max()) < 1e-6
    # The origin has no bearing: it comes out 0, not NaN.
    origin = bearing_rad(
        np.zeros(3, np.float32), np.zeros(3, np.float32), np.empty(3, np.float32), Workspace()
    )
    assert origin.tolist() == [0.0, 0.0, 0.0]


def test_writes_into_out_and_takes_strided_rows() -> None:
    rng = np.random.default_rng(7)
    level = rng.uniform(-10.0, 10.0, (3, 4000)).astype(np.float32)
    out = np.full(4000, np.nan, np.float32)
    got = bearing_rad(level[1], level[0], out, Workspace())
    assert got is out
    assert float(_error_rad(out, level[1], level[0]).max()) < 1e-6
    # A column of a (N, 3) array is strided: the same angles come out.
    points = np.ascontiguousarray(level.T)
    again = bearing_rad(points[:, 1], points[:, 0], np.empty(4000, np.float32), Workspace())
    assert np.array_equal(again, out)


def test_infinite_and_nan_coordinates_give_nan_without_a_warning() -> None:
    # grid.py passes every pixel; a far reading it does not keep has an infinite coordinate.
    y = np.array([np.inf, 1.0, -np.inf, np.nan, 1.0], np.float32)
    x = np.array([np.inf, -np.inf, 3.0, 1.0, 2.0], np.float32)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = bearing_rad(y, x, np.empty(5, np.float32), Workspace())
    assert np.isnan(got[:4]).all()
    assert float(got[4]) == pytest.approx(math.atan2(1.0, 2.0), abs=1e-6)


def test_no_points_and_an_unfit_out() -> None:
    empty = np.empty(0, np.float32)
    assert bearing_rad(empty, empty, np.empty(0, np.float32), Workspace()).size == 0
    points = np.ones(4, np.float32)
    with pytest.raises(ValueError, match="float32"):
        bearing_rad(points, points, np.empty(4, np.float64), Workspace())
    with pytest.raises(ValueError, match="1-D"):
        bearing_rad(points, points, np.empty((2, 4), np.float32)[:, 0], Workspace())
