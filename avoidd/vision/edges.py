"""Foreground fattening at depth edges: pixels beside a silhouette that took its disparity.

A matcher's window straddles a depth edge, and the texture of the nearer surface decides the
cost there: pixels of the background (sky, a far wall, the ground beside a box) a few columns
past the silhouette come out at the foreground's disparity. Near the camera that strip stands
up as an obstacle, in the neighbouring bin when the silhouette lies near a bin boundary.

The check looks at each pixel alone, not through a window: a pixel within ``radius_px`` of a
disparity jump, on the near side, keeps its disparity only if its own grey level (averaged
down a short column, which stays on the same side of a vertical edge) matches the right view
at that disparity clearly better than at the far side's disparity. A background pixel carries
the background's grey level: at the foreground's disparity the right view shows something else
(or, against sky, the same sky at either disparity: ambiguous, so dropped), while a
foreground pixel matches its own surface and not what lies behind. A thin pole keeps its
pixels, since the far side's disparity lands on different texture for every one of them.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from avoidd.types import BoolArray, FloatArray, Image

_COLUMN_PX = 5
"""Height of the column a pixel's grey level is averaged over (noise down, edge kept)."""


def fattened_pixels(
    left: Image,
    right: Image,
    disparity_px: FloatArray,
    radius_px: int,
    jump_px: float,
    noise_sigma: float,
    margin_sigmas: float = 2.0,
) -> BoolArray:
    """Pixels near a depth edge whose near disparity their own grey level does not support.

    Args:
        left: Rectified left grey view (the disparity's reference).
        right: Rectified right grey view.
        disparity_px: Disparity of the left view (NaN invalid).
        radius_px: How far from a jump a pixel is checked (the matcher's half window plus
            the smoothing that follows it).
        jump_px: Smallest disparity step that counts as a depth edge; a step into an invalid
            pixel counts too (against 0, infinitely far).
        noise_sigma: Sensor noise of the views in grey levels.
        margin_sigmas: How much better, in noise units of the column mean, the near
            disparity must match than the far one.

    Returns:
        (H, W) mask of the pixels to drop.
    """
    width = disparity_px.shape[1]
    valid = ~np.isnan(disparity_px)
    measured = np.where(valid, disparity_px, np.float32(np.inf)).astype(np.float32)
    valid_u8 = valid.astype(np.uint8)
    jump = np.float32(jump_px)

    def row_min(image: npt.NDArray[Any], half: int) -> npt.NDArray[Any]:
        kernel = np.ones((1, 2 * half + 1), dtype=np.uint8)
        return np.asarray(cv2.erode(image, kernel, borderType=cv2.BORDER_REPLICATE))

    # Near the edge only: within the radius of a jump down or of an unmeasured pixel.
    with np.errstate(invalid="ignore"):  # inf - inf where nothing is measured: not a step
        step = measured - row_min(measured, radius_px) >= jump
    step |= row_min(valid_u8, radius_px) == 0
    rows, columns = np.nonzero(valid & step)
    if rows.size == 0:
        return np.zeros(valid.shape, dtype=np.bool_)
    d = disparity_px[rows, columns].astype(np.float32)
    # Far side: the smallest measured disparity along the row within twice the radius, when
    # it lies a jump below the pixel's own (the background beyond a strip the matcher left
    # unmeasured); else infinitely far (0) when only unmeasured pixels are there (sky).
    reach = 2 * radius_px
    lowest = row_min(measured, reach)[rows, columns]
    blank = row_min(valid_u8, reach)[rows, columns] == 0
    far = np.where(lowest <= d - jump, lowest, np.where(blank, np.float32(0.0), d))
    checked = d - far >= jump
    rows, columns, d, far = rows[checked], columns[checked], d[checked], far[checked]
    # Grey levels averaged down a short column (noise down, a vertical edge kept).
    left_mean = cv2.blur(left, (1, _COLUMN_PX)).astype(np.float32)
    right_mean = cv2.blur(right, (1, _COLUMN_PX)).astype(np.float32)

    def right_at(x: FloatArray) -> FloatArray:
        """The right view's column mean at (rows, x), linearly between columns."""
        x = np.clip(x, np.float32(0.0), np.float32(width - 1.001))
        x0 = x.astype(np.int64)
        a = (x - x0).astype(np.float32)
        return np.asarray((1.0 - a) * right_mean[rows, x0] + a * right_mean[rows, x0 + 1])

    own = left_mean[rows, columns]
    at = columns.astype(np.float32)
    near_cost = np.abs(own - right_at(at - d))
    far_cost = np.abs(own - right_at(at - far))
    margin = np.float32(margin_sigmas * noise_sigma / np.sqrt(_COLUMN_PX))
    unsupported = near_cost + margin >= far_cost
    out = np.zeros(valid.shape, dtype=np.bool_)
    out[rows[unsupported], columns[unsupported]] = True
    return out


def hidden_from_right(disparity_px: FloatArray) -> BoolArray:
    """Pixels that a nearer pixel to their right hides from the right camera.

    Pixel ``u`` lands at ``u - d(u)`` in the right view. Where a pixel ``u + k`` to its right
    lands at or left of that spot (``d(u + k) - d(u) >= k - 0.5``), it is nearer and covers
    ``u``: the right camera sees ``u + k`` there, not ``u``, so ``u`` has no match and its
    disparity is a guess (often the nearer surface's, smeared onto the background beside it).

    Args:
        disparity_px: Disparity of the left view (NaN invalid).

    Returns:
        (H, W) mask of the hidden pixels.
    """
    valid = ~np.isnan(disparity_px)
    columns = np.arange(disparity_px.shape[1], dtype=np.float32)[None, :]
    # Where each pixel lands in the right view; unmeasured pixels land nowhere.
    lands = np.where(valid, columns - disparity_px, np.float32(np.inf)).astype(np.float32)
    # The leftmost landing of every pixel to the right of each one.
    after = np.full(lands.shape, np.inf, dtype=np.float32)
    after[:, :-1] = np.minimum.accumulate(lands[:, :0:-1], axis=1)[:, ::-1]
    hidden = after <= lands + np.float32(0.5)
    return hidden & valid


def short_occlusion_gaps(disparity_px: FloatArray, jump_px: float, max_columns: int) -> BoolArray:
    """The near side of a silhouette where the right camera's blind strip is too narrow.

    Left of a surface at disparity ``d_near`` whose background has ``d_far``, the left view
    shows ``d_near - d_far`` columns that the right camera cannot see: the matcher must leave
    them unmeasured. Where the unmeasured gap before a nearer run is narrower than that, the
    run starts too early: its first columns are background that took the nearer disparity.
    They are returned (at most ``max_columns`` per edge).

    Args:
        disparity_px: Disparity of the left view (NaN invalid).
        jump_px: Smallest step between the two sides that counts as a silhouette.
        max_columns: Most columns dropped per edge.

    Returns:
        (H, W) mask of the columns to drop.
    """
    height, width = disparity_px.shape
    valid = ~np.isnan(disparity_px)
    # A measured pixel right after an unmeasured one starts a run; only those can be edges.
    starts = valid.copy()
    starts[:, 1:] &= ~valid[:, :-1]
    starts[:, 0] = False
    rows, columns = np.nonzero(starts)
    drop = np.zeros((height, width), dtype=np.bool_)
    if rows.size == 0:
        return drop
    # The previous measured pixel along each row (-1: none), at the run starts.
    marks = np.where(valid, np.arange(width, dtype=np.int32)[None, :], np.int32(-1))
    previous = np.maximum.accumulate(marks, axis=1)[rows, columns - 1]
    known = previous >= 0
    rows, columns, previous = rows[known], columns[known], previous[known]
    step = disparity_px[rows, columns] - disparity_px[rows, previous]
    gap = columns - previous - 1
    deficit = np.minimum(np.ceil(step - gap), max_columns).astype(np.int64)
    edge = (step >= np.float32(jump_px)) & (deficit > 0)
    for row, column, count in zip(rows[edge], columns[edge], deficit[edge], strict=True):
        run = valid[row, column : column + count]
        # Only the measured run itself (it may be shorter than the deficit).
        length = int(np.argmin(run)) if not run.all() else run.size
        drop[row, column : column + length] = True
    return drop
