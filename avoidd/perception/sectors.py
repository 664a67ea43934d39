"""Depth map to the 72 x 5 degree sector grid in body FRD; merging the grids of several heads."""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from avoidd.config import SectorsConfig
from avoidd.perception.grid import (
    FINE_PER_BIN,
    NearestCells,
    PointCells,
    SizeRule,
    nearest_cells,
    point_cells,
    refine,
    row_targets,
    sector_counts,
)
from avoidd.perception.workspace import Workspace
from avoidd.types import (
    SECTOR_COUNT,
    SECTOR_WIDTH_DEG,
    FloatArray,
    Mount,
    RectifiedRig,
    SectorScan,
)

IntArray = npt.NDArray[np.int64]


def column_bearings_deg(rig: RectifiedRig, mount: Mount) -> FloatArray:
    """Body-frame bearing of the viewing ray of every image column (level camera, mount yaw).

    Args:
        rig: The rectified rig.
        mount: The head's mount; only its yaw is used by this first version.

    Returns:
        (W,) bearings in degrees, increasing to the right, unwrapped around the mount yaw.
    """
    u = np.arange(rig.width, dtype=np.float64)
    return (np.degrees(np.arctan((u - rig.cx) / rig.fx)) + mount.yaw_deg).astype(np.float32)


def covered_bins(rig: RectifiedRig, mount: Mount) -> npt.NDArray[np.bool_]:
    """Bins whose centre bearing lies inside the head's horizontal field of view.

    Args:
        rig: The rectified rig.
        mount: The head's mount.

    Returns:
        (72,) boolean mask.
    """
    bearings = column_bearings_deg(rig, mount)
    first, last = float(bearings[0]), float(bearings[-1])
    centres = np.arange(SECTOR_COUNT) * SECTOR_WIDTH_DEG
    offset = np.mod(centres - first, 360.0)
    return np.asarray(offset <= (last - first), dtype=np.bool_)


def bin_of_bearing(bearing_deg: npt.NDArray[np.floating] | float) -> IntArray:
    """Sector index of a bearing (bin i covers i*5 +- 2.5 degrees)."""
    index = np.floor(np.asarray(bearing_deg, dtype=np.float64) / SECTOR_WIDTH_DEG + 0.5)
    return np.mod(index, SECTOR_COUNT).astype(np.int64)


def _bins_of_points(forward_m: FloatArray, right_m: FloatArray) -> tuple[IntArray, FloatArray]:
    """:func:`bin_of_bearing` of many float32 points, in float32 (half the passes of float64).

    The bearing in bins plus 72.5 is positive, so truncation is the floor.

    Returns:
        The bins, and the bearings in bin widths (plus 72.5), for lateral extents.
    """
    bins_per_radian = np.float32(SECTOR_COUNT / (2.0 * math.pi))
    turns = np.arctan2(right_m, forward_m) * bins_per_radian
    turns += np.float32(SECTOR_COUNT + 0.5)
    return np.remainder(turns.astype(np.int64), SECTOR_COUNT), turns


def _narrow_cells(
    cells: PointCells,
    near_px: npt.NDArray[np.float64],
    distance_m: FloatArray,
    fx: float,
    window_px: float,
    min_size_m: float,
    visible_columns: npt.NDArray[np.integer],
    workspace: Workspace | None = None,
    min_pixels: int = 20,
) -> npt.NDArray[np.bool_]:
    """Bins whose nearest cluster is narrower, across the line of sight, than the smallest obstacle.

    Such a cluster is a strip of background beside a silhouette that took its disparity, or
    a sliver of an object whose body lies in the next bin (which reports it). A cluster's
    points are those of its bin within its slab (see :func:`nearest_cluster`): here the points
    of the bin's disparity cells that meet ``[near - slab, near + window]``. The middle 90% of
    their bearings (scaled back to the whole, so that a few stray points do not widen a strip)
    must span ``min_size_m`` at the cluster's distance, less one pixel, or most of the bin
    where the bin itself is narrower than that (near the camera, or at the edge of the field
    of view, where ``visible_columns`` of the bin are in the image). The 5th and 95th
    percentile bearings are first read on whole degrees
    (the rows of ``cells.counts``): that bounds the span within two degrees, which decides
    almost every bin (a bin filled by a surface is far wider than the smallest obstacle). Only
    the bins left undecided count their members' bearings in 64ths of a degree, one pass over
    the points. Percentiles are read at the outer edges of their cells, so a span is never
    underestimated (a reading is not dropped as narrow when its points are not).
    """
    found = np.isfinite(distance_m)
    if not found.any() or min_size_m <= 0:
        return np.zeros(SECTOR_COUNT, dtype=np.bool_)
    focal_baseline = cells.focal_baseline
    near = np.where(found, near_px, 0.0)
    slab_px = np.maximum(window_px, min_size_m / focal_baseline * near * near)
    low_px, high_px = cells.edges_px()
    degree_bin = _degree_bins(cells)
    bottom = (near - slab_px - cells.cell_px)[degree_bin]
    top = (near + window_px + cells.cell_px)[degree_bin]
    member = (high_px[None, :] > bottom[:, None]) & (low_px[None, :] <= top[:, None])
    member &= found[degree_bin][:, None]
    per_degree = np.where(member, cells.counts, 0).sum(axis=1)
    range_m = np.where(found, distance_m, 0.0)
    needed_m = np.minimum(min_size_m - range_m / fx, 0.3 * visible_columns / fx * range_m)
    metres_per_turn = (2.0 * math.pi / SECTOR_COUNT) * range_m
    # Whole degrees: the span lies within (high - low - 1, high - low + 1) degrees.
    per_bin_degree = np.zeros((SECTOR_COUNT, 5), dtype=np.int64)
    np.add.at(
        per_bin_degree,
        (degree_bin, (np.arange(degree_bin.size) + cells.first_degree) % 5),
        per_degree,
    )
    low, high = _percentile_cells(per_bin_degree)
    least_m = np.maximum(high - low - 1, 0) / 5 / 0.9 * metres_per_turn
    most_m = (high - low + 1) / 5 / 0.9 * metres_per_turn
    narrow: npt.NDArray[np.bool_] = np.asarray(found & (most_m < needed_m), dtype=np.bool_)
    undecided = found & ~narrow & (least_m < needed_m)
    ws = workspace or Workspace()
    if undecided.any():  # the undecided bins, in 64ths of a degree
        per_fine = _fine_counts(cells, member & undecided[degree_bin][:, None], ws)
        low, high = _percentile_cells(per_fine)
        span_m = (high - low) / FINE_PER_BIN / 0.9 * metres_per_turn
        narrow[undecided] = span_m[undecided] < needed_m[undecided]
    if narrow.any():
        # A face seen at a grazing angle recedes through many disparities: its slab holds a
        # strip of it only. Followed back while its points run on without a gap (a strip of
        # background beside a silhouette has none behind it), such a face is as wide as it is.
        receding = _receding_bottom_px(cells, degree_bin, narrow, bottom, window_px, min_pixels)
        grows = narrow & (receding < bottom_by_bin(bottom, degree_bin))
        if grows.any():
            deeper = receding[degree_bin]
            member_deeper = (high_px[None, :] > deeper[:, None]) & (low_px[None, :] <= top[:, None])
            member_deeper &= grows[degree_bin][:, None]
            per_fine = _fine_counts(cells, member_deeper, ws)
            low, high = _percentile_cells(per_fine)
            span_m = (high - low) / FINE_PER_BIN / 0.9 * metres_per_turn
            narrow[grows] = span_m[grows] < needed_m[grows]
    # An object just wider than the smallest one, split by a bin boundary, leaves a narrow
    # cluster on each side: together they are the object, and both bins hold part of it. A
    # narrow cluster beside a wide one stays narrow (a strip of background beside a
    # silhouette, or a sliver of a body the next bin reports).
    after = np.roll(np.arange(SECTOR_COUNT), -1)
    pair = narrow & narrow[after] & (np.abs(near - near[after]) <= window_px)
    if not pair.any():
        return narrow
    pair_bins = pair | pair[np.roll(np.arange(SECTOR_COUNT), 1)]  # each pair's both bins
    per_fine = _fine_counts(cells, member & pair_bins[degree_bin][:, None], ws)
    joined = np.concatenate((per_fine, per_fine[after]), axis=1)  # bin b, then b + 1
    low, high = _percentile_cells(joined)
    own_low, own_high = _percentile_cells(per_fine)
    # The two clusters meet at the boundary: at most two pixels between them.
    gap_cells = (FINE_PER_BIN - own_high) + own_low[after]
    touching = gap_cells <= math.degrees(2.0 / fx) * FINE_PER_BIN / 5.0
    pair_m = np.minimum(range_m, range_m[after])
    pair_needed_m = min_size_m - pair_m / fx
    span_m = (high - low) / FINE_PER_BIN / 0.9 * (2.0 * math.pi / SECTOR_COUNT) * pair_m
    whole = pair & touching & (span_m >= pair_needed_m)
    narrow[whole] = False
    narrow[after[whole]] = False
    return narrow


def bottom_by_bin(bottom: npt.NDArray[np.float64], degree_bin: IntArray) -> npt.NDArray[np.float64]:
    """(72,) the lower disparity edge of each bin's cluster slab, from its degree rows' edges."""
    out = np.full(SECTOR_COUNT, np.inf)
    np.minimum.at(out, degree_bin, bottom)
    return out


def _receding_bottom_px(
    cells: PointCells,
    degree_bin: IntArray,
    narrow: npt.NDArray[np.bool_],
    bottom: npt.NDArray[np.float64],
    window_px: float,
    min_pixels: int,
) -> npt.NDArray[np.float64]:
    """(72,) how far down in disparity the points below each narrow cluster run on unbroken.

    Going down (farther) from the cluster's slab, every window of ``window_px`` must hold at
    least ``min_pixels`` of the bin's points; the first window that does not ends the run.
    Bins that are not narrow keep their slab's edge.
    """
    slab_bottom = bottom_by_bin(bottom, degree_bin)
    result = slab_bottom.copy()
    per_bin = np.zeros((SECTOR_COUNT, cells.counts.shape[1]), dtype=np.int64)
    rows = np.flatnonzero(narrow[degree_bin])
    np.add.at(per_bin, degree_bin[rows], cells.counts[rows])
    k = max(1, round(window_px / cells.cell_px))
    if per_bin.shape[1] < k:
        return result
    running = np.concatenate(
        (np.zeros((SECTOR_COUNT, 1), np.int64), np.cumsum(per_bin, axis=1)), axis=1
    )
    windows = running[:, k:] - running[:, :-k]  # window starting at each cell, upward
    sparse = windows < min_pixels
    for index in np.flatnonzero(narrow):
        start = math.floor(slab_bottom[index] / cells.cell_px) - cells.first_cell
        start = min(start, sparse.shape[1])
        if start <= 0:
            continue
        gaps = np.flatnonzero(sparse[index, :start])
        first_kept = int(gaps[-1]) + 1 if gaps.size else 0
        result[index] = min(slab_bottom[index], (first_kept + cells.first_cell) * cells.cell_px)
    return result


def _fine_counts(
    cells: PointCells, member: npt.NDArray[np.bool_], workspace: Workspace
) -> IntArray:
    """(72, FINE_PER_BIN) counts of the member cells' points in 64ths of a degree; row i: bin i."""
    count = cells.key.size
    chosen = np.take(
        cells.table(member, False), cells.key, out=workspace.array("member", count, np.bool_)
    )
    fine = cells.turns[np.flatnonzero(chosen)].astype(np.int64)
    per_fine = np.bincount(fine, minlength=(SECTOR_COUNT + 1) * FINE_PER_BIN)
    per_fine = per_fine[: (SECTOR_COUNT + 1) * FINE_PER_BIN].reshape(SECTOR_COUNT + 1, -1)
    per_fine[0] += per_fine[SECTOR_COUNT]  # both hold bin 36 (+-180 degrees)
    return np.roll(per_fine[:SECTOR_COUNT], 36, axis=0)


def _percentile_cells(counts: IntArray) -> tuple[IntArray, IntArray]:
    """Per row, the lower edge of the cell of the 5th percentile and the upper of the 95th.

    ``np.percentile`` interpolates between the values at ranks ``floor`` and ``ceil`` of
    ``q (n - 1)``: those lie within the cells returned. Rows without points give (0, 0).
    """
    running = np.cumsum(counts, axis=1)
    total = running[:, -1]
    low_rank = np.floor(0.05 * (total - 1)).astype(np.int64)
    high_rank = np.ceil(0.95 * (total - 1)).astype(np.int64)
    low = np.count_nonzero(running <= low_rank[:, None], axis=1)
    high = np.count_nonzero(running <= high_rank[:, None], axis=1) + 1
    empty = total == 0
    return np.where(empty, 0, low), np.where(empty, 0, high)


_SEARCH_MAX_POINTS = 8192
"""At most this many points are searched one by one in a frame (the bins with the fewest)."""


def _worth_searching(
    cells: PointCells, found_rows: NearestCells, counts: IntArray, rule: SizeRule
) -> npt.NDArray[np.bool_]:
    """Rows whose reading the points decide (see :func:`_search_points`).

    Every bin with a reading whose points near its seed fit, fewest first, within
    ``_SEARCH_MAX_POINTS`` a frame, those whose seed the counts leave open first (no cell is
    surely dense, or the seed may lie in more than two cells). A row left out keeps its
    reading from the counts: never farther, nearer by about a cell at most when one surface
    fills the window. A surface filling the view leaves its bins to the counts, so the cost
    stays bounded.
    """
    found = found_rows.cell >= 0
    if not found.any():
        return found
    assert found_rows.lowest is not None and found_rows.highest is not None
    high_px = cells.edges_px()[1]
    no_seed = found_rows.lowest < 0
    # Points to search per row: its cells from the lowest candidate down by a slab, up.
    reach_cells = np.ceil(
        rule.slab_px(high_px[np.maximum(found_rows.highest, 0)]) / cells.cell_px
    ).astype(np.int64)
    start = np.where(no_seed, 0, np.maximum(found_rows.lowest - reach_cells - 2, 0))
    running = np.cumsum(counts, axis=1)
    end = np.maximum(found_rows.highest, 0) + 1
    rows = np.arange(counts.shape[0])
    size = running[rows, np.minimum(end, counts.shape[1] - 1)] - np.where(
        start > 0, running[rows, np.maximum(start - 1, 0)], 0
    )
    unsure = found_rows.ambiguous()
    order = np.lexsort((size, ~unsure))  # the open ones first, then by size
    chosen = np.zeros(found.size, dtype=np.bool_)
    total = 0
    for row in order:
        if found[row] and total + size[row] <= _SEARCH_MAX_POINTS:
            chosen[row] = True
            total += int(size[row])
    return chosen


def _search_points(
    cells: PointCells,
    candidates: Candidates,
    rule: SizeRule,
    unsure_bins: IntArray,
    found_rows: NearestCells,
    rows_unsure: npt.NDArray[np.bool_],
    near_px: npt.NDArray[np.float64],
    picked: IntArray,
) -> None:
    """:func:`nearest_cluster` on the points that can decide the unsure bins (in place).

    A bin's seed lies at or below its highest possible cell and at or above its lowest surely
    dense one (the bottom when there is none); a seed's window and slab reach at most the
    slab below it, and points above never count in a window (it looks farther only). The
    points of those cells are exactly the ones the search on all points would weigh.
    """
    assert found_rows.lowest is not None and found_rows.highest is not None
    low_px, high_px = cells.edges_px()
    top = np.full(SECTOR_COUNT, -np.inf)
    bottom = np.full(SECTOR_COUNT, np.inf)
    highest = found_rows.highest[rows_unsure]
    lowest = found_rows.lowest[rows_unsure]
    top_px = high_px[highest] + cells.cell_px
    low_seed_px = np.where(lowest >= 0, low_px[np.maximum(lowest, 0)], -np.inf)
    reach_px = rule.slab_px(np.asarray(top_px)) + 2 * cells.cell_px
    top[unsure_bins] = top_px
    bottom[unsure_bins] = low_seed_px - reach_px
    degree_bin = _degree_bins(cells)
    table = (low_px[None, :] <= top[degree_bin][:, None]) & (
        high_px[None, :] >= bottom[degree_bin][:, None]
    )
    chosen = np.flatnonzero(cells.table(table, False)[cells.key])
    forward = candidates.forward_m[chosen]
    right = candidates.right_m[chosen]
    range_m = np.maximum(np.sqrt(forward * forward + right * right), np.float32(1e-3))
    disparity = np.asarray(np.float32(cells.focal_baseline) / range_m, np.float32)
    bins = degree_bin[cells.key[chosen] // cells.counts.shape[1]]
    distance, index = nearest_cluster(bins, disparity, cells.focal_baseline, *rule)
    for b in unsure_bins:
        if np.isfinite(distance[b]) and index[b] >= 0:
            near_px[b] = float(disparity[index[b]])
            picked[b] = chosen[index[b]]
        else:
            near_px[b] = np.nan
            picked[b] = -1


def _degree_bins(cells: PointCells) -> IntArray:
    """Sector bin of every bearing row of ``cells.counts``."""
    degrees = cells.counts.shape[0]
    return np.mod((np.arange(degrees) + cells.first_degree) // 5 + 36, SECTOR_COUNT)


def _reported_points(
    candidates: Candidates, picked: IntArray, distance_m: FloatArray
) -> FloatArray:
    """(72, 3) level-frame point of each bin's reading (NaN where none).

    The measured point picked in the reading's slice of disparity, moved along its bearing to
    the reported distance (nearer than the point by at most the slice): its bearing and its
    height.
    """
    level = np.full((SECTOR_COUNT, 3), np.nan, dtype=np.float32)
    bins = np.flatnonzero(picked >= 0)
    index = picked[bins]
    forward = candidates.forward_m[index].astype(np.float64)
    right = candidates.right_m[index].astype(np.float64)
    scale = distance_m[bins] / np.maximum(np.hypot(forward, right), 1e-9)
    level[bins, 0] = forward * scale
    level[bins, 1] = right * scale
    level[bins, 2] = candidates.down_m[index]
    return level


class Candidates(NamedTuple):
    """Obstacle points of one frame of one head (ground and out-of-band points removed).

    Attributes:
        forward_m: Level-frame forward coordinate from the body origin, (N,).
        right_m: Level-frame right coordinate, (N,).
        down_m: Level-frame down coordinate, (N,).
        level_from_body: Rotation from body FRD to the level frame (the attitude), to give
            the reported points in body FRD.
    """

    forward_m: FloatArray
    right_m: FloatArray
    down_m: FloatArray
    level_from_body: npt.NDArray[np.float64]


def sector_scan(
    candidates: Candidates,
    valid_per_column: npt.NDArray[np.integer],
    free_per_column: npt.NDArray[np.integer],
    unseen_per_column: npt.NDArray[np.integer],
    unresolved_per_column: npt.NDArray[np.integer],
    rows: int,
    rig: RectifiedRig,
    mount: Mount,
    params: SectorsConfig,
    t_capture_ns: int,
    cells: PointCells | None = None,
    workspace: Workspace | None = None,
) -> SectorScan:
    """Reduce one head's obstacle points to the 72-bin distance grid.

    Every point counts. A bin reports its nearest cluster of at least ``min_pixels`` points
    (see :func:`nearest_cluster`), measured horizontally from the body origin in the level
    frame. The search runs on counts per (bin, disparity cell)
    (:func:`~avoidd.perception.grid.nearest_cells`), so its cost does not grow with the points;
    its distance is rounded toward nearer by at most about a sixteenth of the cluster window
    in disparity, never farther. The bin's body point is a measured point of the cell read,
    moved along its bearing to the reported distance (at its own height). Without one it is
    clear only on positive evidence: at least ``min_valid_fraction``
    of the pixels of its image columns were measured, at least ``min_free_fraction`` of them
    show free space out to the maximum range (see
    :func:`avoidd.perception.ground.free_space_evidence`), at most
    ``max_unresolved_fraction`` are textured but unmeasured (where an occluded, too near or
    too oblique surface may stand), and none lies in an unmeasured patch where a surface too
    plain to match may stand (:func:`avoidd.perception.ground.unseen_surfaces`); otherwise it
    is unknown. Bins outside the field of view
    are unknown; a bin at its edge (its middle outside) keeps a reading but is never clear.

    Args:
        candidates: The obstacle points (already limited to the sensor's maximum range).
        valid_per_column: (W,) measured pixels per image column (any surface, ground too).
        free_per_column: (W,) pixels per column that show free space to the maximum range.
        unseen_per_column: (W,) pixels per column in unmeasured patches that may be a surface.
        unresolved_per_column: (W,) textured pixels per column without a measurement.
        rows: Pixels per column.
        rig: The rectified rig of the depth map.
        mount: The head's mount.
        params: Robustness parameters.
        t_capture_ns: Capture time of the frame, carried into the scan.
        cells: The points binned by :func:`~avoidd.perception.grid.point_cells` (binned here
            when None).
        workspace: Where per-point temporaries live (see :mod:`avoidd.perception.workspace`).

    Returns:
        The scan: metres, NaN unknown, ``inf`` clear, with the body point of each finite bin.
    """
    columns = _column_geometry(rig, mount)
    total = np.bincount(columns.bins, minlength=SECTOR_COUNT) * rows
    valid_count = np.bincount(columns.bins, weights=valid_per_column, minlength=SECTOR_COUNT)
    free_count = np.bincount(columns.bins, weights=free_per_column, minlength=SECTOR_COUNT)
    unresolved_count = np.bincount(
        columns.bins, weights=unresolved_per_column, minlength=SECTOR_COUNT
    )
    unseen_count = np.bincount(columns.bins, weights=unseen_per_column, minlength=SECTOR_COUNT)

    focal_baseline = float(rig.fx * rig.baseline_m)
    if cells is None:
        cells = point_cells(
            candidates.forward_m, candidates.right_m, focal_baseline, params.cluster_window_px
        )
    rule = SizeRule(
        params.min_pixels,
        params.cluster_window_px,
        params.min_size_m / rig.baseline_m,
        params.min_size_m / focal_baseline,
    )
    per_bin, bin_index = sector_counts(cells)
    # A bin is one row; a row 72 bins from another is the same bin seen across +-180 degrees
    # (a view wider than 355 degrees): its counts join the other's.
    bins, row_of = np.unique(bin_index, return_inverse=True)
    merged = np.zeros((bins.size, per_bin.shape[1]), dtype=np.int64)
    np.add.at(merged, row_of, per_bin)
    found_rows = nearest_cells(merged, cells.first_cell, cells.cell_px, rule)
    where = NearestCells(
        np.full(SECTOR_COUNT, -1, dtype=np.int64), np.full(SECTOR_COUNT, -1, dtype=np.int64)
    )
    where.cell[bins], where.rank[bins] = found_rows.cell, found_rows.rank
    near_px, picked = refine(
        cells,
        candidates.forward_m,
        candidates.right_m,
        row_targets(cells, _degree_bins(cells), where),
        where,
        workspace,
    )
    rows_unsure = _worth_searching(cells, found_rows, merged, rule)
    if rows_unsure.any():
        # Where the counts leave the seed's cell open (scattered points that nearly make a
        # nearer cluster), the points of those bins' candidate cells decide, as the search on
        # all points would.
        _search_points(
            cells, candidates, rule, bins[rows_unsure], found_rows, rows_unsure, near_px, picked
        )
    found = np.isfinite(near_px)
    nearest = np.full(SECTOR_COUNT, np.nan, dtype=np.float32)
    nearest[found] = (np.float32(focal_baseline) / near_px[found]).astype(np.float32)
    # A cluster narrower than the smallest obstacle is a strip of background beside a
    # silhouette, or a sliver of an object reported in the next bin: the bin cannot vouch for
    # a reading (never look behind it: that would read farther), nor for clear space.
    narrow = _narrow_cells(
        cells,
        np.where(found, near_px, np.nan),
        nearest,
        rig.fx,
        params.cluster_window_px,
        params.min_size_m,
        np.bincount(columns.bins, minlength=SECTOR_COUNT),
        workspace,
        params.min_pixels,
    )
    nearest[narrow] = np.nan
    picked[narrow] = -1
    # Obstacle points nearer than the reading that made no cluster (a surface too near, too
    # oblique or too sparsely matched: a pole a few tenths of a metre away) stand between the
    # vehicle and it: the reading would show a farther surface through them. The bin reads
    # where they are instead (without a body point: no one point stands for them).
    nearer_px = _nearer_points_px(merged, bins, cells, np.where(narrow, np.nan, near_px), params)
    behind = np.isfinite(nearer_px)
    nearest[behind] = (np.float32(focal_baseline) / nearer_px[behind]).astype(np.float32)
    picked[behind] = -1
    has_reading = np.isfinite(nearest)
    distance = nearest.astype(np.float32)
    points = np.full((SECTOR_COUNT, 3), np.nan, dtype=np.float32)
    level = _reported_points(candidates, picked, nearest)
    # A reading of nearer points has no point of its own: the bin's middle at level.
    middle = np.radians(np.arange(SECTOR_COUNT) * SECTOR_WIDTH_DEG)
    level[behind, 0] = nearest[behind] * np.cos(middle[behind])
    level[behind, 1] = nearest[behind] * np.sin(middle[behind])
    level[behind, 2] = 0.0
    # Body = transpose(level_from_body) @ level; with row vectors that is level @ R.
    points[has_reading] = (level[has_reading] @ candidates.level_from_body).astype(np.float32)

    valid_fraction = valid_count / np.maximum(total, 1)
    free_fraction = free_count / np.maximum(total, 1)
    # Obstacle points enough for a cluster that spread over too wide a range of disparities to
    # make one (a round pole's corner, a slanted surface): something stands there, at no
    # distance the bin can vouch for. Unknown, never clear.
    points_per_bin = np.zeros(SECTOR_COUNT, dtype=np.int64)
    points_per_bin[bins] = merged.sum(axis=1)
    clear = ~has_reading & ~narrow & (total > 0) & (points_per_bin < params.min_pixels)
    clear &= valid_fraction >= params.min_valid_fraction
    clear &= free_fraction >= params.min_free_fraction
    clear &= unresolved_count / np.maximum(total, 1) <= params.max_unresolved_fraction
    # A plain surface (a painted box, a wall in shade) leaves a patch no matcher can measure:
    # the free space around it is no evidence for the bin's whole view.
    clear &= unseen_count == 0
    distance[clear] = np.inf
    # A bin whose middle lies outside the view but whose edge is in it keeps a reading (its
    # nearest surface is there or nearer), never clear (the rest of the bin was not seen).
    outside = ~columns.covered & ~has_reading
    distance[outside] = np.nan
    points[outside] = np.nan
    return SectorScan(t_capture_ns, distance, points)


def _nearer_points_px(
    merged: IntArray,
    bins: IntArray,
    cells: PointCells,
    near_px: npt.NDArray[np.float64],
    params: SectorsConfig,
) -> npt.NDArray[np.float64]:
    """Where a bin's reading lies behind at least ``min_pixels`` points, the disparity of those.

    A point counts as nearer when its disparity cell lies wholly above the reading's cluster
    window (more than ``cluster_window_px`` above the reported disparity), so the reading's
    own cluster and its noise never count. Counted from the nearest down, the cell where the
    count reaches ``min_pixels`` is read at its upper edge: that many points stand at least
    that near.

    Args:
        merged: (rows, cells) points per disparity cell of the bins that hold points.
        bins: (rows,) the bin of each row.
        cells: The binned points (for the cells' disparity edges).
        near_px: (72,) the disparity each bin reads (NaN where none).
        params: ``min_pixels`` and ``cluster_window_px``.

    Returns:
        (72,) that disparity in pixels where a reading cannot be vouched for, NaN elsewhere.
    """
    result = np.full(SECTOR_COUNT, np.nan)
    reading = near_px[bins]
    with_reading = np.isfinite(reading)
    if not with_reading.any():
        return result
    low_px, high_px = cells.edges_px()
    limit = np.where(with_reading, reading, np.inf) + params.cluster_window_px
    nearer = np.where(low_px[None, :] > limit[:, None], merged, 0)
    from_near = np.cumsum(nearer[:, ::-1], axis=1)  # from the nearest cell down
    enough = from_near[:, -1] >= params.min_pixels
    rows = np.flatnonzero(with_reading & enough)
    if rows.size:
        reached = np.argmax(from_near[rows] >= params.min_pixels, axis=1)
        result[bins[rows]] = high_px[::-1][reached]
    return result


class _Columns(NamedTuple):
    ray_forward: FloatArray
    ray_right: FloatArray
    bins: IntArray
    covered: npt.NDArray[np.bool_]


@functools.lru_cache(maxsize=32)
def _column_geometry(rig: RectifiedRig, mount: Mount) -> _Columns:
    """Horizontal viewing ray, bin and coverage of every column: fixed for a head, so cached."""
    yaw = math.radians(mount.yaw_deg)
    normalised_x = (np.arange(rig.width, dtype=np.float32) - np.float32(rig.cx)) / np.float32(
        rig.fx
    )
    ray_forward = np.float32(math.cos(yaw)) - np.float32(math.sin(yaw)) * normalised_x
    ray_right = np.float32(math.sin(yaw)) + np.float32(math.cos(yaw)) * normalised_x
    bins = bin_of_bearing(np.degrees(np.arctan2(ray_right, ray_forward)))
    columns = _Columns(ray_forward, ray_right, bins, covered_bins(rig, mount))
    for array in columns:
        array.flags.writeable = False
    return columns


def nearest_cluster(
    bins: IntArray,
    disparity_px: FloatArray,
    focal_baseline: float | np.float32,
    min_pixels: int,
    window_px: float,
    min_size_px_per_px: float = 0.0,
    slab_px_per_px2: float = 0.0,
) -> tuple[FloatArray, IntArray]:
    """Distance of the nearest dense cluster of points in every bin, and the point it reports.

    Working in disparity (where stereo noise is about constant), a bin's cluster starts at the
    largest disparity ``d`` that has at least ``min_pixels`` points within ``window_px`` below
    it, and at least the pixel area of a square ``min_size_px_per_px * d`` pixels on a side
    within a slab as deep as that square is wide. The square is an object of a fixed size in
    metres (its side in pixels is ``f * size / Z = size / B * d``), so near clusters must be
    as large as a small real object there, and a few stray or edge-smeared pixels cannot pass
    for one. The slab (``size`` in depth: ``size / (f B) * d**2`` pixels of disparity, at least
    ``window_px``) lets a face seen nearly edge-on count as what it is: its pixels spread over
    many disparities, and near the camera a window of ``window_px`` holds a single column of
    it. The bin reports the point a quarter of the way into the window from its near end: close
    to the nearest surface when the window spans an oblique face, and barely moved by noise
    when it holds one surface.

    Args:
        bins: Sector index of every point.
        disparity_px: Disparity-equivalent ``f * B / range`` of every point (> 0).
        focal_baseline: ``f * B`` in pixel metres, to turn disparity back into range.
        min_pixels: Points a cluster needs at any distance.
        window_px: Width of the cluster window in disparity pixels.
        min_size_px_per_px: ``size / B``: the side, in pixels per pixel of disparity, of the
            square a cluster must cover (0: no size rule).
        slab_px_per_px2: ``size / (f B)``: the depth of that square in disparity is this times
            ``d**2`` (0: the window).

    Returns:
        (72,) distances in metres (NaN where a bin has no cluster) and (72,) the index of the
        reported point in the input (-1 where none).
    """
    if bins.size < min_pixels:
        return _no_clusters()
    rule = _SizeRule(min_pixels, window_px, min_size_px_per_px, slab_px_per_px2)
    kept = _beyond_reach(bins, disparity_px, rule)
    if kept is None:
        return _sorted_search(bins, disparity_px, focal_baseline, rule)
    distance, chosen = _sorted_search(bins[kept], disparity_px[kept], focal_baseline, rule)
    found = chosen >= 0
    chosen[found] = kept[chosen[found]]
    return distance, chosen


_SizeRule = SizeRule


def _no_clusters() -> tuple[FloatArray, IntArray]:
    return (
        np.full(SECTOR_COUNT, np.nan, dtype=np.float32),
        np.full(SECTOR_COUNT, -1, dtype=np.int64),
    )


_PREFILTER_MIN_POINTS = 2000
"""Below this many points one sort is cheaper than the histogram that would shorten it."""
_CELLS_PER_WINDOW = 4
_MAX_CELLS = 4096
_MIN_DROPPED_SHARE = 0.25
"""The cut is used when it drops at least this share of the points (else it costs more)."""
_CELL_SHRINK = 1.0 - 1e-4
"""Cells are a hair narrower, so float rounding never stretches a run of them past a window."""


def _beyond_reach(
    bins: IntArray, disparity_px: FloatArray, rule: _SizeRule
) -> npt.NDArray[np.intp] | None:
    """The points that can take part in their bin's nearest cluster (None: all of them).

    Points are counted in cells a little narrower than a quarter of ``window_px``. Four
    consecutive cells that together hold as many points as a cluster needs at their near edge
    make their nearest point a cluster seed, since that point's window (and its slab, which is
    never narrower) covers all four. The bin's nearest cluster therefore starts in those cells
    or nearer, and its window and slab reach at most five cells plus the slab lower (a slab
    ``k d**2`` deep ends lower the lower it starts, for any ``d`` below ``1 / 2k``): every point
    below that cannot change the result and is dropped before the sort. Most points of a frame
    lie behind the first dense surface of their bin.
    """
    if bins.size < _PREFILTER_MIN_POINTS:
        return None
    min_pixels = rule.min_pixels
    per_window = _CELLS_PER_WINDOW
    width_px = rule.window_px * _CELL_SHRINK / per_window
    cells = min(int(float(np.max(disparity_px)) / width_px) + 1, _MAX_CELLS)
    index = (disparity_px * np.float32(1.0 / width_px)).astype(np.int64)
    np.minimum(index, cells - 1, out=index)  # the top cell also holds everything nearer
    index += bins * cells
    counts = np.bincount(index, minlength=SECTOR_COUNT * cells).reshape(SECTOR_COUNT, cells)
    # Points in the run of cells ending at each cell (the cell and the ones below it).
    running = np.cumsum(counts, axis=1)
    runs = running.copy()
    runs[:, per_window:] -= running[:, :-per_window]
    # A little past each cell's near edge, to stay on the safe side of float rounding.
    near_edge_px = (np.arange(cells, dtype=np.float64) + 1.001) * width_px
    needed = np.maximum(float(min_pixels), rule.area_px(near_edge_px))
    needed[-1] = np.inf  # the top cell has no near edge
    dense = runs >= needed[None, :]
    nearest_dense = cells - 1 - np.argmax(dense[:, ::-1], axis=1)
    slab_cells = np.ceil(rule.slab_px(near_edge_px[nearest_dense]) / width_px).astype(np.int64)
    reach = 2 * per_window + 1 + slab_cells
    lowest_kept = np.where(dense.any(axis=1), np.maximum(nearest_dense - reach, 0), 0)
    dropped = running[np.arange(SECTOR_COUNT), np.maximum(lowest_kept - 1, 0)]
    dropped[lowest_kept == 0] = 0
    if int(dropped.sum()) < bins.size * _MIN_DROPPED_SHARE:
        return None  # the sort saved would not pay for selecting the points
    lowest_kept += np.arange(SECTOR_COUNT) * cells
    return np.flatnonzero(index >= lowest_kept[bins])


def _sorted_search(
    bins: IntArray, disparity_px: FloatArray, focal_baseline: float | np.float32, rule: _SizeRule
) -> tuple[FloatArray, IntArray]:
    """:func:`nearest_cluster` by one sort of all the points it is given."""
    distance, chosen = _no_clusters()
    if bins.size < rule.min_pixels:
        return distance, chosen
    # One sort orders points by bin, then by decreasing disparity (nearest first); a key
    # that grows along that order lets a binary search count each point's window.
    top_px = float(np.max(disparity_px))
    span = top_px + float(rule.slab_px(np.array([top_px]))[0]) + 1.0
    keys = bins.astype(np.float64) * span + (span - disparity_px.astype(np.float64))
    # Ties (equal bin and disparity) are interchangeable, so an unstable sort is fine and
    # about four times faster than a stable one here.
    order = np.argsort(keys)
    keys = keys[order]
    sorted_bins = bins[order]
    sorted_disp = disparity_px[order].astype(np.float64)
    first_index = np.arange(keys.size)
    counts = np.searchsorted(keys, keys + rule.window_px, side="right") - first_index
    dense_enough = counts >= rule.min_pixels
    if rule.min_size_px_per_px > 0:
        slab = rule.slab_px(sorted_disp)
        in_slab = counts
        if rule.slab_px_per_px2 > 0:
            in_slab = np.searchsorted(keys, keys + slab, side="right") - first_index
        dense_enough &= in_slab >= rule.area_px(sorted_disp)
    dense = np.flatnonzero(dense_enough)
    if dense.size == 0:
        return distance, chosen
    dense_bins = sorted_bins[dense]
    first = np.flatnonzero(np.diff(dense_bins, prepend=-1) != 0)
    seeds = dense[first]
    seed_bins = dense_bins[first]
    picked = seeds + (counts[seeds] - 1) // 4
    distance[seed_bins] = (np.float32(focal_baseline) / sorted_disp[picked]).astype(np.float32)
    chosen[seed_bins] = order[picked]
    return distance, chosen


def merge_scans(scans: list[SectorScan]) -> SectorScan:
    """Merge the scans of several heads: the nearest reading per bin, unknown where none sees.

    Args:
        scans: One scan per head (at least one).

    Returns:
        The merged scan, stamped with the newest capture time of its inputs; each bin keeps
        the capture time of the reading it took.
    """
    if not scans:
        return SectorScan.unknown()
    if len(scans) == 1:
        return scans[0]
    stacked = np.stack([scan.distance_m for scan in scans])
    # NaN sorts last, so the nearest reading wins and unknown only where every head is.
    winner = np.argmin(np.where(np.isnan(stacked), np.inf, stacked), axis=0)
    winner = np.where(np.all(np.isnan(stacked), axis=0), 0, winner)
    columns = np.arange(SECTOR_COUNT)
    merged = stacked[winner, columns].astype(np.float32)
    # inf (clear) beats NaN (unknown) where no head has a reading.
    merged = np.where(np.isnan(merged), np.fmin.reduce(stacked, axis=0), merged)
    times = np.stack([scan.times_ns() for scan in scans])[winner, columns]
    points = None
    if all(scan.points_frd_m is not None for scan in scans):
        stacked_points = np.stack([scan.points_frd_m for scan in scans])  # type: ignore[misc]
        points = stacked_points[winner, columns].astype(np.float32)
    return SectorScan(max(scan.t_capture_ns for scan in scans), merged, points, times)
