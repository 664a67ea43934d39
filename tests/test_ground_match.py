"""The ground hypothesis: obstacle points that match the ground plane's disparity as well.

On rendered scenes: tests/test_edges.py (open flat ground under sky makes no false bin).
"""

from __future__ import annotations

import cv2
import numpy as np

from avoidd.perception.ground_match import Views, explained_by_ground
from avoidd.perception.workspace import Workspace

HEIGHT, WIDTH = 80, 240
HORIZON_ROW = 10
BAND_PX = 6.0


def ground_disparity() -> np.ndarray:
    """A level ground: disparity grows linearly below the horizon, none above it."""
    rows = np.arange(HEIGHT, dtype=np.float32) - HORIZON_ROW
    return np.repeat((0.12 * rows)[:, None], WIDTH, axis=1).astype(np.float32)


def textured(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    texture = rng.uniform(0.0, 255.0, (HEIGHT, WIDTH)).astype(np.float32)
    return cv2.GaussianBlur(texture, (0, 0), 1.0)


def right_view(left: np.ndarray, disparity: np.ndarray) -> np.ndarray:
    """What the right camera sees of a surface with this disparity at every left pixel."""
    # The right view at column x shows the left view's column x + d (d of the surface there;
    # here d changes along the rows only, so it is the same at both ends).
    columns = np.arange(WIDTH, dtype=np.float32)[None, :] + disparity
    rows = np.repeat(np.arange(HEIGHT, dtype=np.float32)[:, None], WIDTH, axis=1)
    return cv2.remap(left, columns, rows, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)


def noisy(image: np.ndarray, seed: int, sigma: float = 1.5) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.clip(image + rng.normal(0.0, sigma, image.shape), 0, 255).astype(np.uint8)


def explained(left: np.ndarray, right: np.ndarray, measured: np.ndarray) -> np.ndarray:
    candidates = np.zeros((HEIGHT, WIDTH), dtype=np.bool_)
    candidates[20:70, 60:200] = True
    views = Views(noisy(left, 1), noisy(right, 2), measured, 1.5)
    return explained_by_ground(views, ground_disparity(), candidates, Workspace(), BAND_PX)


def test_ground_read_a_few_pixels_too_near_is_explained_by_the_ground() -> None:
    ground = ground_disparity()
    left = textured(3)
    right = right_view(left, ground)
    measured = ground + np.float32(3.0)  # the matcher's error: 3 px too near
    drop = explained(left, right, measured)
    assert drop[20:70, 60:200].mean() > 0.95
    assert not drop[:20].any() and not drop[70:].any()  # never outside the candidates


def test_a_textured_obstacle_near_the_grounds_disparity_is_kept() -> None:
    # A surface 3 px of disparity nearer than the ground behind it, with its own texture:
    # the right view shows it at its own disparity; at the ground's it lands elsewhere.
    ground = ground_disparity()
    surface = ground + np.float32(3.0)
    left = textured(4)
    right = right_view(left, surface)
    drop = explained(left, right, surface)
    assert drop.mean() < 0.01


def test_only_pixels_below_the_horizon_and_within_the_band_are_tested() -> None:
    ground = ground_disparity()
    left = textured(5)
    right = right_view(left, ground)
    # Beyond the band (ground read 10 px too near) the ground's disparity is not tried: a
    # chance match of weak texture there would drop a real obstacle's points.
    assert not explained(left, right, ground + np.float32(10.0)).any()
    # Above the horizon there is no ground to explain anything; unmeasured pixels neither.
    measured = ground + np.float32(3.0)
    measured[:, 100:120] = np.nan
    drop = explained(left, right, measured)
    assert not drop[: HORIZON_ROW + 1].any()
    assert not drop[:, 100:120].any()
