"""Obstacle points clustered into obstacles: distance, bearing, lateral offset, size, histogram."""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from avoidd.config import HistogramConfig, ObstaclesConfig, SectorsConfig
from avoidd.perception.grid import (
    PointCells,
    SizeRule,
    nearest_cells,
    one_or_nan,
    point_cells,
    refine,
)
from avoidd.perception.workspace import Workspace
from avoidd.types import FloatArray


@dataclass(frozen=True)
class Obstacle:
    """One obstacle seen by one head in one frame (level frame, from the body origin).

    Attributes:
        distance_m: Horizontal distance to its near side (robust, see
            :func:`~avoidd.perception.sectors.nearest_cluster`; never farther).
        bearing_deg: Bearing of that near point, degrees, positive right, (-180, 180].
        lateral_m: Right offset of that near point from the heading axis.
        width_m: Extent across the line of sight (2nd to 98th percentile).
        height_m: Visible vertical extent (2nd to 98th percentile).
        top_m: Height of its visible top above the ground.
        points: Points it holds.
        histogram_edges_m: Edges of its range histogram (the head's histogram settings).
        histogram_counts: Points per histogram bin.
    """

    distance_m: float
    bearing_deg: float
    lateral_m: float
    width_m: float
    height_m: float
    top_m: float
    points: int
    histogram_edges_m: tuple[float, ...]
    histogram_counts: tuple[int, ...]

    def to_json(self) -> dict[str, object]:
        """A JSON-ready record (rounded to millimetres and hundredths of a degree)."""
        return {
            "distance_m": round(self.distance_m, 3),
            "bearing_deg": round(self.bearing_deg, 2),
            "lateral_m": round(self.lateral_m, 3),
            "width_m": round(self.width_m, 3),
            "height_m": round(self.height_m, 3),
            "top_m": round(self.top_m, 3),
            "points": self.points,
            "histogram": {
                "edges_m": [round(e, 3) for e in self.histogram_edges_m],
                "counts": list(self.histogram_counts),
            },
        }


def cluster_obstacles(
    forward_m: FloatArray,
    right_m: FloatArray,
    above_ground_m: FloatArray,
    focal_baseline: float,
    baseline_m: float,
    params: ObstaclesConfig,
    sectors: SectorsConfig,
    histogram: HistogramConfig,
    cells: PointCells | None = None,
    workspace: Workspace | None = None,
) -> list[Obstacle]:
    """Group obstacle points into obstacles, nearest first.

    Points are counted on a grid of bearing by disparity (``f * B / range``, where stereo noise is
    about constant): whole degrees (``bearing_cell_deg`` rounded, at least one) by
    ``disparity_cell_px``. Occupied cells are joined by 8-connectivity, and each component with
    at least ``min_points`` points becomes an obstacle. A component never wraps across the
    bearing of +-180 degrees. Everything but the heights is measured on the counts per cell
    (the distance as the sector bins', never farther; the width from the bearings in whole
    degrees, interpolated inside them; the range histogram from the disparity cells); the
    heights take one pass over the points.

    Args:
        forward_m: Level-frame forward coordinates of the points, (N,).
        right_m: Level-frame right coordinates, (N,).
        above_ground_m: Height of each point above the ground plane, (N,).
        focal_baseline: The head's ``f * B`` (pixel metres).
        baseline_m: The head's baseline (for the cluster size rule).
        params: Clustering parameters.
        sectors: The robust near-distance parameters (as for the sector bins).
        histogram: Range histogram edges.
        cells: The points binned by :func:`~avoidd.perception.grid.point_cells` (binned here
            when None; then every point counts).
        workspace: Where per-point temporaries live.

    Returns:
        Up to ``params.max_count`` obstacles, nearest first.
    """
    if cells is None:
        cells = point_cells(forward_m, right_m, focal_baseline, sectors.cluster_window_px)
    counts = cells.counts
    if int(counts.sum()) < params.min_points:
        return []
    degrees, columns = counts.shape
    ws = workspace or Workspace()
    per_row = max(1, round(params.bearing_cell_deg))
    per_column = max(1, round(params.disparity_cell_px / cells.cell_px))
    rows_c = -(-degrees // per_row)
    columns_c = -(-columns // per_column)
    # Everything below runs on the occupied cells only (a few thousand at most).
    occupied_cells = np.flatnonzero(counts)
    cell_row, cell_column = np.divmod(occupied_cells, columns)
    cell_count = counts.ravel()[occupied_cells]
    occupied = np.zeros((rows_c, columns_c), dtype=np.uint8)
    occupied[cell_row // per_row, cell_column // per_column] = 1
    count, labels = cv2.connectedComponents(occupied, connectivity=8, ltype=cv2.CV_32S)
    cell_label = labels[cell_row // per_row, cell_column // per_column]
    sizes = np.bincount(cell_label, weights=cell_count, minlength=count)
    kept = [label for label in range(1, count) if sizes[label] >= params.min_points]
    if not kept:
        return []
    which = np.full(count, -1, dtype=np.int64)
    which[kept] = np.arange(len(kept))
    cell_component = which[cell_label]  # kept component of each occupied cell, or -1
    member = cell_component >= 0
    groups = len(kept)
    comp_index = cell_component[member]
    per_disparity = np.zeros((groups, columns), dtype=np.int64)
    np.add.at(per_disparity, (comp_index, cell_column[member]), cell_count[member])
    per_degree = np.zeros((groups, degrees), dtype=np.int64)
    np.add.at(per_degree, (comp_index, cell_row[member]), cell_count[member])
    points = per_disparity.sum(axis=1)
    rule = SizeRule(
        sectors.min_pixels,
        sectors.cluster_window_px,
        sectors.min_size_m / baseline_m,
        sectors.min_size_m / focal_baseline,
    )
    nearest = nearest_cells(
        per_disparity,
        cells.first_cell,
        cells.cell_px,
        rule,
        np.minimum(sectors.min_pixels, points),
    )
    component = ws.array("component", degrees * columns, np.int32)
    component.fill(-1)
    component[occupied_cells] = cell_component
    target = ws.array("component_target", degrees * columns, np.int32)
    target.fill(-1)
    read = member & (cell_column == nearest.cell[np.maximum(cell_component, 0)])
    target[occupied_cells[read]] = cell_component[read]
    near_px, chosen = refine(cells, forward_m, right_m, target, nearest, ws)
    bottom, top = _height_extents(cells, component, above_ground_m, groups, ws)
    component = component.reshape(degrees, columns)
    low_px, high_px = cells.edges_px()
    middle_px = (low_px + high_px) / 2
    # Each disparity cell's range lands in one bin of the range histogram.
    edges = np.linspace(histogram.min_m, histogram.max_m, histogram.bins + 1)
    with np.errstate(divide="ignore"):
        cell_range = focal_baseline / middle_px
    bin_of = np.searchsorted(edges, cell_range, side="right") - 1
    bin_of[cell_range == edges[-1]] = histogram.bins - 1
    inside = (bin_of >= 0) & (bin_of < histogram.bins)
    obstacles = []
    for k in range(groups):
        if not np.isfinite(near_px[k]) or chosen[k] < 0:
            continue
        distance = float(np.float32(focal_baseline) / np.float32(near_px[k]))
        near = int(chosen[k])
        forward, right = float(forward_m[near]), float(right_m[near])
        scale = distance / max(math.hypot(forward, right), 1e-9)
        low_deg, centre_deg, high_deg = _weighted_quantiles(
            np.arange(degrees, dtype=np.float64) + cells.first_degree - 182.0,
            per_degree[k],
            (2.0, 50.0, 98.0),
        )
        # Across the line of sight: each extreme bearing at the component's median range in
        # that degree (a face square to the view spreads its range with the bearing).
        width = 0.0
        for sign, bearing in ((-1.0, low_deg), (1.0, high_deg)):
            row = min(max(math.floor(bearing + 182.5) - cells.first_degree, 0), degrees - 1)
            in_row = np.where(component[row] == k, counts[row], 0)
            if not in_row.any():
                in_row = per_disparity[k]
            median_px = _weighted_quantiles(middle_px, in_row, (50.0,))[0]
            range_m = focal_baseline / max(median_px, 1e-9)
            width += sign * range_m * math.sin(math.radians(bearing - centre_deg))
        counts_h = np.bincount(
            bin_of[inside], weights=per_disparity[k][inside], minlength=histogram.bins
        )
        obstacles.append(
            Obstacle(
                distance_m=distance,
                bearing_deg=math.degrees(math.atan2(right, forward)),
                lateral_m=right * scale,
                width_m=float(width),
                height_m=float(top[k] - bottom[k]),
                top_m=float(top[k]),
                points=int(points[k]),
                histogram_edges_m=tuple(float(e) for e in edges),
                histogram_counts=tuple(int(c) for c in counts_h),
            )
        )
    obstacles.sort(key=lambda o: o.distance_m)
    return obstacles[: params.max_count]


_HEIGHT_CELL_M = 0.01


def _weighted_quantiles(
    centres: npt.NDArray[np.float64], weights: npt.NDArray[np.integer], q: tuple[float, ...]
) -> list[float]:
    """Percentiles of values counted per cell, each cell's points spread evenly across it.

    ``centres`` are the centres of equally wide cells; a percentile is interpolated inside
    the cell that holds it.
    """
    total = float(weights.sum())
    step = float(centres[1] - centres[0]) if centres.size > 1 else 1.0
    running = np.cumsum(weights, dtype=np.float64)
    out = []
    for value in q:
        target = value / 100.0 * total
        index = min(int(np.searchsorted(running, target, side="left")), centres.size - 1)
        before = running[index - 1] if index > 0 else 0.0
        inside = float(weights[index])
        fraction = (target - before) / inside if inside > 0 else 0.5
        out.append(float(centres[index] - step / 2 + fraction * step))
    return out


def _height_extents(
    cells: PointCells,
    component: npt.NDArray[np.int32],
    above_ground_m: FloatArray,
    groups: int,
    workspace: Workspace,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """2nd and 98th percentile height of every component, on centimetre cells (one pass)."""
    count = cells.key.size
    ws = workspace
    table = cells.table(component, -1)
    owner = np.take(table, cells.key, out=ws.array("owner", count, np.int32))
    # 1 where a point belongs to a kept component, NaN elsewhere (no masked copies: slow on
    # a scattered mask).
    owned = one_or_nan(
        np.greater_equal(owner, 0, out=ws.array("owned", count, np.bool_)),
        ws.array("owned_or_nan", count, np.float32),
    )
    heights = np.multiply(above_ground_m, owned, out=ws.array("heights", count, np.float32))
    low = float(np.fmin.reduce(heights, initial=np.inf))
    high = float(np.fmax.reduce(heights, initial=-np.inf))
    if not (math.isfinite(low) and math.isfinite(high)):
        return np.zeros(groups), np.zeros(groups)
    cells_h = int((high - low) / _HEIGHT_CELL_M) + 2
    heights -= np.float32(low)
    heights *= np.float32(1.0 / _HEIGHT_CELL_M)
    np.floor(heights, out=heights)
    scaled = ws.array("owner_key", count, np.float32)
    np.multiply(owner, np.float32(cells_h), out=scaled)
    scaled += heights
    scaled *= owned
    np.fmin(scaled, np.float32(groups * cells_h), out=scaled)  # NaN: the spare cell
    key = ws.array("height_key", count, np.int64)
    key[...] = scaled
    per_height = np.bincount(key, minlength=groups * cells_h + 1)[: groups * cells_h]
    per_height = per_height.reshape(groups, cells_h)
    centres = low + (np.arange(cells_h, dtype=np.float64) + 0.5) * _HEIGHT_CELL_M
    bottom = np.zeros(groups)
    top = np.zeros(groups)
    for k in range(groups):
        bottom[k], top[k] = _weighted_quantiles(centres, per_height[k], (2.0, 98.0))
    return bottom, top
