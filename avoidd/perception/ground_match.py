"""Obstacle points the ground explains as well: far ground read too near is not an obstacle.

Ground seen at a grazing angle (far ahead, just below the horizon) carries little texture
along the rows, and a semi-global matcher fills it from its neighbours: under open sky it often
comes out a few pixels of disparity too near. At a 48 px m rig, ground 16 m away read at 9.7 m
rises 0.6 m above the ground plane and stands up as an obstacle. The ground tests in
:mod:`avoidd.perception.ground` cannot tell it from a real one: its measured disparity says so.

The images can. Every pixel below the horizon has a second hypothesis, the disparity the ground
plane would give it, always smaller (an obstacle in front of the ground is nearer than the
ground behind it). A real obstacle's texture matches the right view at its own disparity and
not at the ground's, which lands on other texture. A pixel of ground read too near matches at
the ground's disparity at least as well as at the one the matcher gave it: it does not vouch
for an obstacle, and is dropped. The check only drops obstacle points, never moves or adds
one, and where the ground model is off (a slope, a pose error) the ground hypothesis fits
worse and the point stays: it errs towards seeing an obstacle.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import cv2
import numpy as np

from avoidd.perception.workspace import Workspace
from avoidd.types import BoolArray, FloatArray, Image

WINDOW_PX = 5
"""Side of the square window the two hypotheses' matching costs are summed over."""

_MIN_GAP_PX = 1.0
"""The ground's disparity must lie at least this far below the measured one to be tested."""


class Views(NamedTuple):
    """The rectified views a disparity map was matched on, and their sensor noise.

    Attributes:
        left: Left grey view (the disparity's reference), (H, W) uint8.
        right: Right grey view, same shape.
        disparity_px: The measured disparity of the left view (NaN unmeasured).
        noise_sigma: Standard deviation of the views' sensor noise in grey levels.
    """

    left: Image
    right: Image
    disparity_px: FloatArray
    noise_sigma: float


def explained_by_ground(
    views: Views,
    ground_disparity_px: FloatArray,
    candidates: BoolArray,
    workspace: Workspace,
    band_px: float,
    margin_sigmas: float = 2.0,
) -> BoolArray:
    """Obstacle candidates whose image matches the ground plane's disparity as well.

    Args:
        views: The views and the measured disparity.
        ground_disparity_px: (H, W) disparity the ground plane gives each pixel (zero or
            negative where the pixel's ray does not meet the ground).
        candidates: (H, W) obstacle candidates; not modified.
        workspace: Where the temporaries live.
        band_px: Only candidates at most this much disparity nearer than the ground behind
            them are checked (the matcher's smoothing error; farther from the ground, a
            chance match of weak texture at the ground's disparity would drop real obstacle
            points).
        margin_sigmas: How much worse, in standard deviations of the window's summed
            difference under sensor noise alone, the ground's match may be and still explain
            the pixel.

    Returns:
        (H, W) mask of the candidates to drop (a workspace array: valid until the next frame).
    """
    shape = candidates.shape
    height, width = shape
    out = workspace.array("ground_match.explained", shape, np.bool_)
    out[:] = False
    measured = views.disparity_px
    with np.errstate(invalid="ignore"):
        testable = candidates & (ground_disparity_px > 0.0)
        testable &= ground_disparity_px <= measured - np.float32(_MIN_GAP_PX)
        testable &= ground_disparity_px >= measured - np.float32(band_px)
    rows = np.flatnonzero(testable.any(axis=1))
    if rows.size == 0:
        return np.asarray(out, dtype=np.bool_)
    columns_used = np.flatnonzero(testable[rows[0] : rows[-1] + 1].any(axis=0))
    half = WINDOW_PX // 2
    top, bottom = max(int(rows[0]) - half, 0), min(int(rows[-1]) + half + 1, height)
    first, last = max(int(columns_used[0]) - half, 0), min(int(columns_used[-1]) + half + 1, width)
    region = (slice(top, bottom), slice(first, last))
    region_shape = (bottom - top, last - first)
    f32 = np.float32
    columns = workspace.array("ground_match.columns", region_shape, f32)
    columns[:] = np.arange(first, last, dtype=f32)
    row_map = workspace.array("ground_match.rows", region_shape, f32)
    row_map[:] = np.arange(top, bottom, dtype=f32)[:, None]
    left = views.left[region]
    # Both hypotheses are averaged over the same pixels: the window's measured ones (an
    # unmeasured neighbour has no disparity of its own to be matched at).
    own_disparity = np.ascontiguousarray(measured[region], dtype=f32)
    weight = workspace.array("ground_match.weight", region_shape, f32)
    np.copyto(weight, np.isfinite(own_disparity))
    window = (WINDOW_PX, WINDOW_PX)
    count = cv2.boxFilter(
        weight,
        -1,
        window,
        dst=workspace.array("ground_match.count", region_shape, f32),
        normalize=False,
        borderType=cv2.BORDER_CONSTANT,
    )

    def cost(disparity: FloatArray, name: str) -> FloatArray:
        """Summed absolute difference over the window's measured pixels at ``disparity``."""
        map_x = cv2.subtract(
            columns, disparity, dst=workspace.array(name + ".x", region_shape, f32)
        )
        cv2.patchNaNs(map_x, 0.0)  # unmeasured: weighed out below
        warped = cv2.remap(
            views.right,
            map_x,
            row_map,
            cv2.INTER_LINEAR,
            dst=workspace.array(name + ".warped", region_shape, np.uint8),
            borderMode=cv2.BORDER_REPLICATE,
        )
        difference = cv2.absdiff(
            left, warped, dst=workspace.array(name + ".difference", region_shape, np.uint8)
        )
        weighed = cv2.multiply(
            difference,
            weight,
            dst=workspace.array(name + ".weighed", region_shape, f32),
            dtype=cv2.CV_32F,
        )
        return np.asarray(
            cv2.boxFilter(
                weighed,
                -1,
                window,
                dst=workspace.array(name + ".cost", region_shape, f32),
                normalize=False,
                borderType=cv2.BORDER_CONSTANT,
            ),
            dtype=f32,
        )

    own = cost(own_disparity, "ground_match.own")
    ground = cost(
        np.ascontiguousarray(ground_disparity_px[region], dtype=f32), "ground_match.ground"
    )
    # Pure noise on both views: each absolute difference has a standard deviation of
    # sigma * sqrt(2) * sqrt(1 - 2 / pi); the window's sum of n of them sqrt(n) times that,
    # and the difference of the two sums sqrt(2) times more.
    spread = views.noise_sigma * math.sqrt(2.0 * (1.0 - 2.0 / math.pi)) * math.sqrt(2.0)
    margin = cv2.sqrt(count, dst=workspace.array("ground_match.margin", region_shape, f32))
    margin *= f32(margin_sigmas * spread)
    margin += own
    np.less_equal(ground, margin, out=out[region])
    out &= testable
    return np.asarray(out, dtype=np.bool_)
