"""Obstacle points reduced to counts per (bearing, disparity) cell, and the searches on them.

A wall filling the view makes most pixels obstacle points. Everything the sector scan and the
obstacle list need is therefore computed from counts per cell: every point is visited by a few
vectorised passes (its cell, one histogram), and the searches then run on the cells, whose
number does not depend on how many points there are. Disparity cells are a sixteenth of the
cluster window wide; a distance read from them is rounded toward nearer, never farther (see
:func:`nearest_cells`).
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt

from avoidd.perception.bearing import bearing_rad
from avoidd.perception.workspace import Workspace
from avoidd.types import SECTOR_COUNT, BoolArray, FloatArray

IntArray = npt.NDArray[np.int64]

CELLS_PER_WINDOW = 16
"""Disparity cells per cluster window (the last cell read is at most a sixteenth of it nearer)."""
FINE_PER_DEGREE = 64
"""Fine bearing cells per degree (a 640 px wide, 77 degree view has 8.3 pixels per degree)."""
FINE_PER_BIN = 5 * FINE_PER_DEGREE
_FINE_SHIFT = 6  # log2(FINE_PER_DEGREE)
_FIRST_TURN = 36
"""Fine bearings count from -182.5 degrees (36 bins below the +72.5 bin offset)."""
MAX_CELLS = 4096
"""At most this many disparity cells: beyond that they widen (a wider disparity range)."""


class SizeRule(NamedTuple):
    """What makes a cluster (see :func:`avoidd.perception.sectors.nearest_cluster`)."""

    min_pixels: int
    window_px: float
    min_size_px_per_px: float
    slab_px_per_px2: float

    def slab_px(self, disparity_px: npt.NDArray[np.floating]) -> npt.NDArray[np.float64]:
        """Disparity depth of the size slab at each disparity (at least the window)."""
        d = np.asarray(disparity_px, dtype=np.float64)
        return np.maximum(self.window_px, self.slab_px_per_px2 * d * d)

    def area_px(self, disparity_px: npt.NDArray[np.floating]) -> npt.NDArray[np.float64]:
        """Pixel area of the size square at each disparity."""
        side = self.min_size_px_per_px * np.asarray(disparity_px, dtype=np.float64)
        return side * side


class PointCells(NamedTuple):
    """Obstacle points binned by bearing (whole degrees) and disparity.

    Attributes:
        turns: (N,) fine bearing of every point: ``FINE_PER_DEGREE`` per degree, counted from
            -182.5 degrees (so that five whole degrees make a sector bin); its floor is the
            point's fine cell.
        key: (N,) flat index of every point's cell in ``counts``; ``counts.size`` for a point
            that is not kept.
        counts: (degrees, cells) points per cell.
        first_degree: Degree (counted from -182.5) of the first row of ``counts``.
        first_cell: Disparity cell of the first column of ``counts``.
        cell_px: Width of a disparity cell in pixels.
        focal_baseline: ``f * B`` of the head (disparity = ``f * B / range``).
    """

    turns: FloatArray
    key: IntArray
    counts: IntArray
    first_degree: int
    first_cell: int
    cell_px: float
    focal_baseline: float

    def edges_px(self) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """(cells,) lower and upper disparity edges of the columns of ``counts``."""
        index = np.arange(self.first_cell, self.first_cell + self.counts.shape[1], dtype=np.float64)
        return index * self.cell_px, (index + 1.0) * self.cell_px

    def table(self, values: npt.NDArray[Any], fill: Any) -> npt.NDArray[Any]:
        """A per-cell table (flat, one entry per cell) with ``fill`` for not-kept points."""
        return np.append(values.ravel(), np.asarray([fill], dtype=values.dtype))


def point_cells(
    forward_m: FloatArray,
    right_m: FloatArray,
    focal_baseline: float,
    window_px: float,
    workspace: Workspace | None = None,
    kept: BoolArray | None = None,
    horizontal2_m2: FloatArray | None = None,
) -> PointCells:
    """Bin points by bearing and disparity (``f * B / horizontal range``).

    Args:
        forward_m: Level-frame forward coordinates, (N,).
        right_m: Level-frame right coordinates, (N,).
        focal_baseline: ``f * B`` of the head in pixel metres.
        window_px: The cluster window; disparity cells are a sixteenth of it.
        workspace: Where the per-point arrays live (overwritten by its next frame); arrays
            of their own when None.
        kept: (N,) which points count (all when None); the others get no cell, and NaN in
            their forward and right coordinates is overwritten with a finite number.
        horizontal2_m2: (N,) ``forward**2 + right**2`` when known (for the kept points).

    Returns:
        The cells of the points.
    """
    ws = workspace or Workspace()
    count = forward_m.size
    f32 = np.float32
    kept_or_nan = None
    if kept is not None:
        # NaN (unmeasured pixels) has no bearing: it becomes a finite number here (a
        # masked copy would cost more on a scattered mask). Unkept entries turn NaN again
        # below by one product with 1 (kept) or NaN (not).
        np.fmax(forward_m, f32(-1e30), out=forward_m)
        np.fmax(right_m, f32(-1e30), out=right_m)
        kept_or_nan = one_or_nan(kept, ws.array("kept_or_nan", count, f32))
    per_radian = f32(SECTOR_COUNT * FINE_PER_BIN / (2.0 * math.pi))
    turns = bearing_rad(right_m, forward_m, ws.array("turns", count, f32), ws)
    turns *= per_radian
    turns += f32((SECTOR_COUNT + 0.5 - _FIRST_TURN) * FINE_PER_BIN)
    degree = np.multiply(turns, f32(1.0 / FINE_PER_DEGREE), out=ws.array("degree", count, f32))
    np.floor(degree, out=degree)
    disparity = ws.array("disparity", count, f32)
    if horizontal2_m2 is None:
        np.multiply(forward_m, forward_m, out=disparity)
        disparity += np.square(right_m, out=ws.array("right2", count, f32))
        np.sqrt(disparity, out=disparity)
    else:
        with np.errstate(invalid="ignore"):
            np.sqrt(horizontal2_m2, out=disparity)
    np.maximum(disparity, f32(1e-3), out=disparity)
    np.divide(f32(focal_baseline), disparity, out=disparity)
    if kept_or_nan is not None:
        # Out of the extremes (fmin and fmax skip NaN) and, below, out of the counts.
        disparity *= kept_or_nan
        degree *= kept_or_nan
    low_px = float(np.fmin.reduce(disparity, initial=np.inf))
    high_px = float(np.fmax.reduce(disparity, initial=-np.inf))
    if math.isfinite(low_px) and math.isfinite(high_px):
        first_degree = int(np.fmin.reduce(degree))
        last_degree = int(np.fmax.reduce(degree))
    else:
        low_px = high_px = 1.0
        first_degree = last_degree = 0
    cell_px = max(window_px / CELLS_PER_WINDOW, (high_px - low_px) / (MAX_CELLS - 2))
    first_cell = math.floor(low_px / cell_px) - 1
    cells = math.floor(high_px / cell_px) + 2 - first_cell
    rows = last_degree - first_degree + 1
    # Float rounding may put a point a cell off its true one: the first and last columns
    # are spare, and the searches count one more cell on each side of every window. The key
    # is exact in float32 (below 2**24).
    disparity *= f32(1.0 / cell_px)
    np.floor(disparity, out=disparity)
    disparity -= f32(first_cell)
    degree -= f32(first_degree)
    degree *= f32(cells)
    degree += disparity
    if kept_or_nan is not None:
        np.fmin(degree, f32(rows * cells), out=degree)  # NaN (not kept): the spare cell
    key = ws.array("key", count, np.int64)
    key[...] = degree
    counts = np.bincount(key, minlength=rows * cells + 1)[: rows * cells].reshape(rows, cells)
    return PointCells(turns, key, counts, first_degree, first_cell, cell_px, float(focal_baseline))


def one_or_nan(mask: BoolArray, out: FloatArray) -> FloatArray:
    """1.0 where ``mask`` holds, NaN elsewhere, in one pass (x / x of its 0 and 1 bytes)."""
    byte = mask.view(np.uint8)
    with np.errstate(invalid="ignore"):
        np.true_divide(byte, byte, out=out, dtype=np.float32)
    return out


def sector_counts(cells: PointCells) -> tuple[IntArray, IntArray]:
    """Points per (sector bin, disparity cell).

    Returns:
        (bins, cells) counts for the bins that hold points, and (bins,) their bin index.
    """
    first = cells.first_degree // 5 * 5
    rows = cells.counts.shape[0]
    pad_before = cells.first_degree - first
    total = -(-(pad_before + rows) // 5) * 5
    padded = np.zeros((total, cells.counts.shape[1]), dtype=np.int64)
    padded[pad_before : pad_before + rows] = cells.counts
    per_bin = padded.reshape(total // 5, 5, -1).sum(axis=1)
    index = np.mod(np.arange(total // 5) + first // 5 + _FIRST_TURN, SECTOR_COUNT)
    return per_bin, index


def nearest_cells(
    counts: IntArray,
    first_cell: int,
    cell_px: float,
    rule: SizeRule,
    min_pixels: npt.NDArray[np.integer] | None = None,
) -> NearestCells:
    """:func:`~avoidd.perception.sectors.nearest_cluster` on counts per disparity cell.

    Each row (a bin or an obstacle) holds its points' counts per disparity cell. The search on
    the points starts its cluster at a seed point and reports the point a quarter of the
    seed's window below it. Here a cell is dense when the counts around it *could* hold a seed
    (its window and slab counted one cell wider than they are, the size rule taken at the
    cell's lower edge): the highest such cell is at or above the seed's. A cell is surely
    dense when its lowest point's window and slab hold enough even counted one cell narrower;
    the seed is at or above the highest of those. Between the two, the reported point's rank
    from the top is at least the fewest points above a candidate seed cell plus a quarter of
    the fewest its window surely holds, and the cell holding that rank bounds the reported
    disparity from above: the disparity returned (that cell's upper edge) is never below what
    the search on the points reports, so the distance is never farther. It is nearer by at
    most about a cell when one surface fills the window.

    Args:
        counts: (rows, cells) points per disparity cell.
        first_cell: Cell index of column 0 (cell ``c`` spans ``[c, c + 1) * cell_px``).
        cell_px: Cell width in disparity pixels.
        rule: The cluster rule.
        min_pixels: (rows,) points a cluster needs, per row (default ``rule.min_pixels``).

    Returns:
        Per row, the cell holding the bound and the rank in it (see :func:`refine`, which
        places the bound inside the cell), and the lowest and highest cells the seed may lie
        in (lowest -1: no cell is surely dense, the seed may lie anywhere below the highest).
    """
    rows, columns = counts.shape
    needed = (
        np.full(rows, rule.min_pixels, dtype=np.int64)
        if min_pixels is None
        else np.asarray(min_pixels, dtype=np.int64)
    )
    if rows == 0 or columns == 0:
        none = np.full(rows, -1, dtype=np.int64)
        return NearestCells(none, none.copy(), none.copy(), none.copy())
    running = np.cumsum(counts, axis=1)
    # at[:, j + 1] = running[:, j]; at[:, 0] = 0: running "before" any column, clipped.
    at = np.concatenate([np.zeros((rows, 1), dtype=np.int64), running], axis=1)
    column = np.arange(columns, dtype=np.int64)

    def before(offsets: IntArray) -> IntArray:
        """Points in the columns below ``column - offsets`` (inclusive of that column)."""
        return at[:, np.clip(column - offsets, -1, columns - 1) + 1]

    index = np.arange(first_cell, first_cell + columns, dtype=np.float64)
    low_px, high_px = index * cell_px, (index + 1.0) * cell_px
    window_cells = rule.window_px / cell_px
    occupied = counts > 0
    # Could a point of the cell be a seed? (one spare cell below every window and slab)
    wide = np.full(columns, math.ceil(window_cells) + 2, dtype=np.int64)
    could = occupied & (running - before(wide) >= needed[:, None])
    if rule.min_size_px_per_px > 0:
        slab_wide = np.ceil(rule.slab_px(high_px) / cell_px).astype(np.int64) + 2
        could &= running - before(slab_wide) >= rule.area_px(low_px * (1 - 1e-6))[None, :]
    # Is the lowest point of the cell surely one? (cells wholly inside its window, one less)
    narrow = np.full(columns, math.floor(window_cells) - 1, dtype=np.int64)
    below = before(np.ones(columns, dtype=np.int64))
    surely_count = 1 + below - before(narrow)
    surely = occupied & (surely_count >= needed[:, None])
    if rule.min_size_px_per_px > 0:
        slab_narrow = np.floor(rule.slab_px(low_px) / cell_px).astype(np.int64) - 1
        surely &= 1 + below - before(slab_narrow) >= rule.area_px(high_px * (1 + 1e-6))[None, :]
    found = could.any(axis=1)
    highest = columns - 1 - np.argmax(could[:, ::-1], axis=1)
    lowest = np.where(surely.any(axis=1), columns - 1 - np.argmax(surely[:, ::-1], axis=1), 0)
    # Rank (from the top, 0-based) of the reported point if the seed lies in each cell.
    total = running[:, -1:]
    rank = (total - running) + (np.maximum(needed[:, None], surely_count) - 1) // 4
    candidate = occupied & (column >= lowest[:, None]) & (column <= highest[:, None])
    fewest = np.where(candidate, rank, np.iinfo(np.int64).max).min(axis=1)
    # The cell holding that rank: points in it and above exceed the rank, above it they don't.
    at_or_above = total - at[:, :-1]
    picked = np.count_nonzero(at_or_above > fewest[:, None], axis=1) - 1
    picked = np.where(found, picked, -1)
    above = total[:, 0] - running[np.arange(rows), np.maximum(picked, 0)]
    has_surely = surely.any(axis=1)
    lowest = np.where(found & has_surely, lowest, np.where(found, -1, -1))
    return NearestCells(
        picked, np.where(found, fewest - above, -1), lowest, np.where(found, highest, -1)
    )


class NearestCells(NamedTuple):
    """Where each row's reading lies: its cell and its rank in it.

    Attributes:
        cell: (rows,) column of the cell holding the reported point's bound (-1: no cluster).
        rank: (rows,) rank from the top inside that cell (0: its nearest point) of a point at
            least as near as the reported one.
    """

    cell: IntArray
    rank: IntArray
    lowest: IntArray | None = None
    highest: IntArray | None = None

    def ambiguous(self) -> npt.NDArray[np.bool_]:
        """Rows whose seed may lie in more than two cells (a cell or more apart)."""
        if self.lowest is None or self.highest is None:
            return np.zeros(self.cell.size, dtype=np.bool_)
        return np.asarray((self.cell >= 0) & (self.highest - self.lowest > 1), dtype=np.bool_)


SUB_CELLS = 64
"""A cell read is split this many times to place the reading inside it."""


def row_targets(cells: PointCells, row_group: IntArray, nearest: NearestCells) -> IntArray:
    """The target table of :func:`refine` when each bearing row belongs to one group.

    Args:
        cells: The binned points.
        row_group: (degrees,) group of every row of ``cells.counts``.
        nearest: Each group's cell (groups index its rows).

    Returns:
        (cells.counts.size,) group of each cell read, -1 elsewhere.
    """
    degrees, columns = cells.counts.shape
    target = np.full(degrees * columns, -1, dtype=np.int32)
    wanted = nearest.cell[row_group]
    rows = np.flatnonzero(wanted >= 0)
    target[rows * columns + wanted[rows]] = row_group[rows]
    return target


def refine(
    cells: PointCells,
    forward_m: FloatArray,
    right_m: FloatArray,
    target: npt.NDArray[np.integer],
    nearest: NearestCells,
    workspace: Workspace | None = None,
) -> tuple[npt.NDArray[np.float64], IntArray]:
    """Place each group's reading inside its cell, and pick a measured point there.

    The points of every group's cell are counted in ``SUB_CELLS`` slices of disparity; the
    slice holding the rank of :class:`NearestCells` bounds the reported disparity from above
    (its upper edge), a ``SUB_CELLS``-th of a cell at most above it.

    Args:
        cells: The binned points.
        forward_m: Their forward coordinates.
        right_m: Their right coordinates.
        target: (cells.counts.size,) the group whose reading each cell holds (-1: none).
        nearest: Each group's cell and rank (groups index its rows).
        workspace: Where the per-point temporaries live.

    Returns:
        (groups,) disparity bound in pixels (NaN: no reading) and (groups,) the index of a
        measured point of the slice (-1: none).
    """
    ws = workspace or Workspace()
    groups = nearest.cell.size
    disparity = np.full(groups, np.nan)
    chosen = np.full(groups, -1, dtype=np.int64)
    if not (nearest.cell >= 0).any():
        return disparity, chosen
    count = cells.key.size
    table = cells.table(np.asarray(target, dtype=np.int32), -1)
    point_group = np.take(table, cells.key, out=ws.array("point_group", count, np.int32))
    hits = np.flatnonzero(np.greater_equal(point_group, 0, out=ws.array("hit", count, np.bool_)))
    if hits.size == 0:
        return disparity, chosen
    group = point_group[hits].astype(np.int64)
    forward, right = forward_m[hits], right_m[hits]
    range_m = np.maximum(np.sqrt(forward * forward + right * right), np.float32(1e-3))
    scaled = (np.float32(cells.focal_baseline) / range_m) * np.float32(1.0 / cells.cell_px)
    base = cells.first_cell + nearest.cell[group]
    slice_index = np.clip(((scaled - base) * SUB_CELLS).astype(np.int64), 0, SUB_CELLS - 1)
    counts = np.bincount(group * SUB_CELLS + slice_index, minlength=groups * SUB_CELLS)
    from_top = np.cumsum(counts.reshape(groups, SUB_CELLS)[:, ::-1], axis=1)
    # The slice (from the top) where the points at or above it first exceed the rank.
    top_slice = np.minimum(
        np.count_nonzero(from_top <= nearest.rank[:, None], axis=1), SUB_CELLS - 1
    )
    slice_up = SUB_CELLS - 1 - top_slice  # counted from the bottom
    found = nearest.cell >= 0
    edge_cells = cells.first_cell + nearest.cell + (slice_up + 1 + 1e-2) / SUB_CELLS
    disparity = np.where(found, edge_cells * cells.cell_px, np.nan)
    # A measured point of the slice (the first in pixel order).
    in_slice = np.flatnonzero(slice_index == slice_up[group])
    picked_groups, first = np.unique(group[in_slice], return_index=True)
    chosen[picked_groups] = hits[in_slice[first]]
    return disparity, chosen
