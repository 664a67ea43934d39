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

import math
from typing import Any, NamedTuple

import cv2
import numpy as np
import numpy.typing as npt

from avoidd.types import BoolArray, FloatArray, Image
from avoidd.vision.fixed import FIXED_INF, FIXED_LIMIT, to_sixteenths
from avoidd.vision.scratch import scratch

IndexArray = npt.NDArray[np.intp]
"""Flat (row-major) pixel indices."""

_COLUMN_PX = 5
"""Height of the column a pixel's grey level is averaged over (noise down, edge kept)."""

_UNSEEN_FAR_PX = 2
"""Where nothing is measured beyond a silhouette, the background is taken to lie between
infinitely far and this disparity (whole pixels; see :func:`fattened_indices`)."""

_VOTE_ROWS = 6
"""Rows each way whose checked pixels vote on a pixel's verdict (see :func:`_column_vote`)."""


class ColumnMeans(NamedTuple):
    """Both views' grey levels averaged down a short column (:func:`column_means`), flat."""

    left: npt.NDArray[np.uint8]
    right: npt.NDArray[np.uint8]


def column_means(
    left: Image, right: Image, left_out: Image | None = None, right_out: Image | None = None
) -> ColumnMeans:
    """Each view's grey levels averaged down ``_COLUMN_PX`` rows: noise down, an edge kept.

    The depth-edge checks compare these. Computed once per frame, they can be handed to
    each check.

    Args:
        left: Rectified left grey view.
        right: Rectified right grey view.
        left_out: Where to write the left means (same shape and type as ``left``), if given.
        right_out: Likewise for the right.

    Returns:
        Both means, flattened (views of the arrays written).
    """
    size = (1, _COLUMN_PX)
    left_mean = cv2.blur(left, size, dst=left_out)
    right_mean = cv2.blur(right, size, dst=right_out)
    return ColumnMeans(
        np.asarray(left_mean, dtype=np.uint8).ravel(),
        np.asarray(right_mean, dtype=np.uint8).ravel(),
    )


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
    flat = fattened_indices(
        left, right, disparity_px, radius_px, jump_px, noise_sigma, margin_sigmas
    )
    return _mask(disparity_px.shape, flat)


def fattened_indices(
    left: Image,
    right: Image,
    disparity_px: FloatArray,
    radius_px: int,
    jump_px: float,
    noise_sigma: float,
    margin_sigmas: float = 2.0,
    means: ColumnMeans | None = None,
) -> IndexArray:
    """:func:`fattened_pixels` as flat (row-major) indices of the pixels to drop, ascending.

    ``means``: the views' :func:`column_means`, when already computed for this frame.
    """
    shape = disparity_px.shape
    width = shape[1]
    disparity = np.ascontiguousarray(disparity_px, dtype=np.float32)
    valid = cv2.compare(disparity, disparity, cv2.CMP_EQ, dst=_scratch("valid", shape, np.uint8))
    jump = np.float32(jump_px)
    kernel = np.ones((1, 2 * radius_px + 1), dtype=np.uint8)
    replicate = cv2.BORDER_REPLICATE
    step = _scratch("step", shape, np.bool_)
    other = _scratch("other", shape, np.bool_)
    # Row minima within the radius of each pixel (`lowest_near`) and within twice the radius
    # (`lowest`: the same minimum taken twice). Unmeasured pixels are infinitely near for
    # them: never the far side. Near the edge: within the radius of a jump down.
    jump16 = math.ceil(16.0 * float(jump))  # k / 16 >= jump for whole k
    fixed = None
    if jump16 <= FIXED_LIMIT:
        fixed = to_sixteenths(disparity, FIXED_INF, "edges.fattened.sixteenths")
    if fixed is not None:  # in whole sixteenths: the same minima, in 16-bit integers
        lowest_near = cv2.erode(
            fixed, kernel, dst=_scratch("lowest_near16", shape, np.int16), borderType=replicate
        )
        lowest = cv2.erode(
            lowest_near, kernel, dst=_scratch("lowest16", shape, np.int16), borderType=replicate
        )
        # Saturating: a step beyond the 16-bit range still counts.
        np.greater_equal(cv2.subtract(fixed, lowest_near, dst=lowest_near), jump16, out=step)
    else:
        measured = _scratch("measured", shape, np.float32)
        np.copyto(measured, disparity)
        cv2.patchNaNs(measured, np.inf)
        lowest_near = cv2.erode(
            measured, kernel, dst=_scratch("lowest_near", shape, np.float32), borderType=replicate
        )
        lowest = cv2.erode(
            lowest_near, kernel, dst=_scratch("lowest", shape, np.float32), borderType=replicate
        )
        with np.errstate(invalid="ignore"):  # inf - inf where nothing is measured: no step
            np.greater_equal(cv2.subtract(measured, lowest_near, dst=lowest_near), jump, out=step)
    all_near = cv2.erode(
        valid, kernel, dst=_scratch("all_near", shape, np.uint8), borderType=replicate
    )
    all_measured = cv2.erode(
        all_near, kernel, dst=_scratch("all_measured", shape, np.uint8), borderType=replicate
    )
    # Or within the radius of an unmeasured pixel; and measured itself.
    step |= np.equal(all_near, 0, out=other)
    step &= np.not_equal(valid, 0, out=other)
    flat = np.flatnonzero(step)
    if flat.size == 0:
        return flat
    d = disparity.ravel()[flat]
    # Far side: the smallest measured disparity along the row within twice the radius, when
    # it lies a jump below the pixel's own (the background beyond a strip the matcher left
    # unmeasured); else infinitely far (0) when only unmeasured pixels are there (sky).
    low = lowest.ravel()[flat].astype(np.float32)
    if fixed is not None:
        low *= np.float32(1.0 / 16.0)  # exact: a candidate's own value bounds its minimum
    blank = all_measured.ravel()[flat] == 0
    measured_far = low <= d - jump
    far = np.where(measured_far, low, np.where(blank, np.float32(0.0), d))
    checked = d - far >= jump
    flat, d, far, unseen = flat[checked], d[checked], far[checked], ~measured_far[checked]
    rows_start = flat - flat % width  # flat index of each pixel's row start
    columns = (flat - rows_start).astype(np.float32)
    # Grey levels averaged down a short column (noise down, a vertical edge kept).
    left_mean, right_mean = means or _own_means(left, right)
    own = left_mean[flat].astype(np.float32)
    near_cost = np.abs(own - _row_sample(right_mean, rows_start, columns - d, width))
    far_cost = np.abs(own - _row_sample(right_mean, rows_start, columns - far, width))
    # An unmeasured far side is not always infinitely far: a tree line at 45 m is a pixel
    # away. Its cost is the best over the far disparities from 0 to _UNSEEN_FAR_PX (where
    # that lies a jump below the pixel's own, so never on the near surface itself). Between
    # whole columns the right view is sampled linearly, so over that span it takes every
    # value between the least and the largest of its columns there.
    spots = np.flatnonzero(unseen & (d >= jump + np.float32(_UNSEEN_FAR_PX)))
    at = flat[spots]
    # Least and largest of the right view's columns u - _UNSEEN_FAR_PX .. u (clipped to the
    # row), as whole-image row filters: cheaper than gathering each column per pixel.
    span = np.ones((1, _UNSEEN_FAR_PX + 1), dtype=np.uint8)
    right_2d = right_mean.reshape(shape)
    lowest_right, highest_right = (
        row_filter(
            right_2d,
            span,
            dst=_scratch(name, shape, np.uint8),
            anchor=(_UNSEEN_FAR_PX, 0),
            borderType=cv2.BORDER_REPLICATE,
        )
        .ravel()[at]
        .astype(np.float32)
        for row_filter, name in ((cv2.erode, "unseen_low"), (cv2.dilate, "unseen_high"))
    )
    mine = own[spots]
    outside = np.maximum(lowest_right - mine, mine - highest_right)
    far_cost[spots] = np.minimum(far_cost[spots], np.maximum(outside, np.float32(0.0)))
    margin = np.float32(margin_sigmas * noise_sigma / np.sqrt(_COLUMN_PX))
    keep = near_cost + margin < far_cost
    return np.asarray(flat[~_column_vote(shape, flat, keep, "fattened")], dtype=np.intp)


def ambiguous_left_edges(
    left: Image,
    right: Image,
    disparity_px: FloatArray,
    radius_px: int,
    jump_px: float,
    noise_sigma: float,
    margin_sigmas: float = 3.0,
    means: ColumnMeans | None = None,
) -> IndexArray:
    """Pixels at the start of a nearer run whose grey level the background beside it explains.

    Left of a silhouette the left view shows a strip of background the right camera cannot
    see (as wide as the step in disparity). A matcher often gives that strip the nearer
    surface's disparity; :func:`fattened_indices` then cannot catch it, since the far side's
    disparity lands on the nearer surface in the right view (that is what hidden means) and
    matches badly there. A nearer disparity does not: it lands left of the surface's image in
    the right view, on the background beside the silhouette. Each measured pixel within
    ``radius_px`` of the start of its run (a run starts after an unmeasured pixel or a step up
    of at least ``jump_px``, with nothing measured within twice the radius before it or
    something a jump farther: a run of ground after a few unmeasured pixels, with ground of
    its disparity before them, is no silhouette) is compared with the right view at its own
    disparity and at the spot ``jump_px`` left of where the run's start lands. A surface pixel
    differs from the background there; a pixel of background (sky, weakly textured ground)
    matches it as well, says nothing for the nearer disparity, and is returned.

    Args:
        left: Rectified left grey view (the disparity's reference).
        right: Rectified right grey view.
        disparity_px: Disparity of the left view (NaN invalid).
        radius_px: How far from a run's start a pixel is checked.
        jump_px: Smallest step up (from the left) that starts a run, and how far left of the
            run's start the background is read.
        noise_sigma: Sensor noise of the views in grey levels.
        margin_sigmas: How much better, in noise units of the column mean, the pixel must
            match at its own disparity than the background does. Three: a pixel of
            featureless background passes by chance about 2 % of the time (8 % at two, and
            those survivors, a few dozen in a strip, still made a cluster beside a pole).
        means: The views' :func:`column_means`, when already computed for this frame.

    Returns:
        Flat (row-major) indices of the pixels to drop, ascending.
    """
    width = disparity_px.shape[1]
    disparity = np.ascontiguousarray(disparity_px, dtype=np.float32)
    shape = disparity.shape
    # Neighbours along a row that belong to one run: both measured, less than a jump apart.
    valid = cv2.compare(disparity, disparity, cv2.CMP_EQ, dst=_scratch("valid", shape, np.uint8))
    step = _scratch("left_step", shape, np.float32)
    step[:, 0] = np.nan
    cv2.subtract(disparity[:, 1:], disparity[:, :-1], dst=step[:, 1:])
    jump = np.float32(jump_px)
    with np.errstate(invalid="ignore"):
        joined = np.less(np.abs(step), jump, out=_scratch("joined", shape, np.bool_))
    # Padded with an unjoined column on the right, each row's runs start where a measured
    # pixel is not joined to its left neighbour and end where it is not joined to its right.
    begins = np.flatnonzero((valid != 0) & ~joined)
    if begins.size == 0:
        return begins
    ends_mask = _scratch("ends", shape, np.bool_)
    ends_mask[:, -1] = True
    np.logical_not(joined[:, 1:], out=ends_mask[:, :-1])
    ends_mask &= valid != 0
    ends = np.flatnonzero(ends_mask)
    # A run starts at a silhouette's left side when it comes out of nothing (or the row's
    # start) or steps up; a step down is the right side of something nearer. And only when
    # nothing is measured within twice the radius to its left (sky) or something a jump
    # farther is: a run of ground that starts after a few unmeasured pixels, with ground of
    # its own disparity before them, is no silhouette.
    flat_step = step.ravel()[begins]
    measured = _scratch("left_measured", shape, np.float32)
    np.copyto(measured, disparity)
    cv2.patchNaNs(measured, np.inf)
    reach = 2 * radius_px
    # Row minima over [u - reach + 1, u]; read at u - 1 for a run starting at u.
    lowest_left = cv2.erode(
        measured,
        np.ones((1, reach), dtype=np.uint8),
        dst=_scratch("lowest_left", shape, np.float32),
        anchor=(reach - 1, 0),
        borderType=cv2.BORDER_CONSTANT,
        borderValue=np.inf,
    ).ravel()
    at_row_start = begins % width == 0
    before_start = np.where(at_row_start, np.float32(np.inf), lowest_left[begins - 1])
    d_start = disparity.ravel()[begins]
    with np.errstate(invalid="ignore"):
        rising = ~(flat_step <= -jump)
        rising &= np.isinf(before_start) | (before_start <= d_start - jump)
    first, length = begins[rising], np.minimum(ends[rising] - begins[rising] + 1, radius_px)
    total = int(length.sum())
    if total == 0:
        return np.zeros(0, dtype=np.intp)
    offsets = np.arange(total, dtype=np.intp) - np.repeat(np.cumsum(length) - length, length)
    flat = np.repeat(first, length) + offsets
    first = np.repeat(first, length)
    d = disparity.ravel()[flat]
    rows_start = flat - flat % width
    columns_f = (flat - rows_start).astype(np.float32)
    beside = (first - rows_start).astype(np.float32) - d - np.float32(jump_px)
    inside = beside >= 0.0  # the background's spot is in the right view
    flat, d, rows_start, columns_f, beside = (
        flat[inside],
        d[inside],
        rows_start[inside],
        columns_f[inside],
        beside[inside],
    )
    left_mean, right_mean = means or _own_means(left, right)
    own = left_mean[flat].astype(np.float32)
    near_cost = np.abs(own - _row_sample(right_mean, rows_start, columns_f - d, width))
    background_cost = np.abs(own - _row_sample(right_mean, rows_start, beside, width))
    margin = np.float32(margin_sigmas * noise_sigma / np.sqrt(_COLUMN_PX))
    keep = near_cost + margin < background_cost
    return np.asarray(flat[~_column_vote(shape, flat, keep, "left")], dtype=np.intp)


def _own_means(left: Image, right: Image) -> ColumnMeans:
    """:func:`column_means` into this module's scratch arrays (for one check's own use)."""
    return column_means(
        left,
        right,
        _scratch("left_mean", left.shape, np.uint8),
        _scratch("right_mean", right.shape, np.uint8),
    )


def _column_vote(shape: tuple[int, ...], flat: IndexArray, keep: BoolArray, name: str) -> BoolArray:
    """Each checked pixel's verdict by the majority of the checked pixels up and down its column.

    One pixel's test compares grey levels a few noise units apart: against featureless
    background (sky, smooth ground) about one pixel in ten passes by chance, and a strip of
    such survivors a few hundred rows tall is enough for a cluster. The pixels above and below
    in the same column lie on the same side of a (near vertical) silhouette, so the checked
    pixels within ``_VOTE_ROWS`` rows each way vote, and ties drop (a pixel is kept only on
    evidence). A surface pixel that failed by chance is kept by its neighbours just the same.

    Args:
        shape: (H, W) of the image the flat indices address.
        flat: Flat indices of the checked pixels, ascending.
        keep: Each one's own verdict (True: keeps its disparity).
        name: The caller's name for its scratch array.

    Returns:
        The majority's verdict for each checked pixel.
    """
    votes = _scratch("votes." + name, shape, np.int16)
    votes.fill(0)
    votes.ravel()[flat] = np.where(keep, np.int16(1), np.int16(-1))
    total = cv2.boxFilter(
        votes,
        cv2.CV_16S,
        (1, 2 * _VOTE_ROWS + 1),
        dst=_scratch("vote_total." + name, shape, np.int16),
        normalize=False,
        borderType=cv2.BORDER_CONSTANT,
    )
    return np.asarray(total.ravel()[flat] > 0)


def _row_sample(
    values: npt.NDArray[Any], rows_start: IndexArray, x: FloatArray, width: int
) -> FloatArray:
    """A flat image's values at (row, x), linearly between columns (x clipped to the row)."""
    x = np.clip(x, np.float32(0.0), np.float32(width - 1.001))
    x0 = np.trunc(x)
    a = x - x0  # exact in float32: the fractional part has no more bits than x
    at = rows_start + x0.astype(np.intp)
    v0 = values[at].astype(np.float32)
    v1 = values[at + 1].astype(np.float32)
    return np.asarray((1.0 - a) * v0 + a * v1)


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
    height, width = disparity_px.shape
    disparity = np.ascontiguousarray(disparity_px, dtype=np.float32)
    # Where each pixel lands in the right view (NaN: unmeasured pixels land nowhere).
    shape = (height, width)
    lands: FloatArray = _scratch("lands", shape, np.float32)
    cv2.subtract(_columns(height, width), disparity, dst=lands)
    # NaN: an unmeasured pixel is never hidden.
    spot = np.add(lands, np.float32(0.5), out=_scratch("spot", shape, np.float32))
    cv2.patchNaNs(lands, np.inf)  # nor does it hide anything
    # The leftmost landing of every pixel from each one to the row's end.
    after = row_suffix_min(lands, _scratch("spare", shape, np.float32))
    # Hidden: a pixel strictly to the right lands at or left of this one's spot (plus half a
    # pixel).
    hidden = np.zeros((height, width), dtype=np.bool_)
    with np.errstate(invalid="ignore"):
        np.less_equal(after[:, 1:], spot[:, :-1], out=hidden[:, :-1])
    return hidden


def row_suffix_min(values: FloatArray, spare: FloatArray) -> FloatArray:
    """The minimum of each pixel and every pixel right of it in its row (NaN-free input).

    Computed in ceil(log2(W)) whole-image steps, each folding in the minimum of the next
    ``shift`` columns (numpy's ``minimum.accumulate`` along rows takes one element at a time,
    several times slower). Both arrays are overwritten.

    Args:
        values: (H, W) float32 values, C-contiguous or rows of one.
        spare: An array of the same shape and type to work in.

    Returns:
        ``values`` or ``spare``, whichever holds the result.
    """
    width = values.shape[1]
    after = values
    shift = 1
    while shift < width:
        spare[:, width - shift :] = after[:, width - shift :]
        cv2.min(after[:, : width - shift], after[:, shift:], dst=spare[:, : width - shift])
        after, spare = spare, after
        shift *= 2
    return after


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
    flat = short_gap_indices(disparity_px, jump_px, max_columns)
    return _mask(disparity_px.shape, flat)


def short_gap_indices(disparity_px: FloatArray, jump_px: float, max_columns: int) -> IndexArray:
    """:func:`short_occlusion_gaps` as flat (row-major) indices of the pixels to drop."""
    width = disparity_px.shape[1]
    disparity = np.ascontiguousarray(disparity_px, dtype=np.float32)
    # Runs of measured pixels: each row padded with an unmeasured column on both sides, so
    # that changes come in pairs per run (its first column, the column after its last).
    measured = cv2.compare(disparity, disparity, cv2.CMP_EQ)  # 255 where not NaN
    padded = cv2.copyMakeBorder(measured, 0, 0, 1, 1, cv2.BORDER_CONSTANT, value=0)
    change = np.flatnonzero(padded[:, 1:] != padded[:, :-1])
    if change.size < 4:
        return np.zeros(0, dtype=np.intp)
    row, column = np.divmod(change, width + 1)  # column: in the unpadded image
    starts, ends = column[0::2], column[1::2]
    run_rows = row[0::2]
    # A run with a run before it in the same row; `previous` is that run's last column.
    follows = run_rows[1:] == run_rows[:-1]
    rows = run_rows[1:][follows]
    columns, stops = starts[1:][follows], ends[1:][follows]
    previous = ends[:-1][follows] - 1
    base = rows * width
    step = disparity.ravel()[base + columns] - disparity.ravel()[base + previous]
    gap = columns - previous - 1
    deficit = np.minimum(np.ceil(step - gap), max_columns).astype(np.int64)
    edge = (step >= np.float32(jump_px)) & (deficit > 0)
    # Only the measured run itself (it may be shorter than the deficit).
    length = np.minimum(deficit[edge], (stops - columns)[edge])
    first = (base + columns)[edge]
    total = int(length.sum())
    if total == 0:
        return np.zeros(0, dtype=np.intp)
    # first[i], first[i] + 1, ..., first[i] + length[i] - 1 for every edge.
    offsets = np.arange(total, dtype=np.intp) - np.repeat(np.cumsum(length) - length, length)
    return np.asarray(np.repeat(first, length) + offsets, dtype=np.intp)


_COLUMN_GRIDS: dict[tuple[int, int], FloatArray] = {}


def _columns(height: int, width: int) -> FloatArray:
    """Column index of every pixel, float32 (cached per image size)."""
    grid = _COLUMN_GRIDS.get((height, width))
    if grid is None:
        grid = _COLUMN_GRIDS[(height, width)] = np.tile(
            np.arange(width, dtype=np.float32), (height, 1)
        )
    return grid


def _scratch(name: str, shape: tuple[int, ...], dtype: npt.DTypeLike) -> npt.NDArray[Any]:
    """This module's scratch arrays (see :mod:`avoidd.vision.scratch`)."""
    return scratch("edges." + name, shape, dtype)


def _mask(shape: tuple[int, ...], flat: IndexArray) -> BoolArray:
    """A (H, W) mask, True at the flat indices."""
    out = np.zeros(shape, dtype=np.bool_)
    out.ravel()[flat] = True
    return out
