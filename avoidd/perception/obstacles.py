"""Obstacle points clustered into obstacles: distance, bearing, lateral offset, size, histogram."""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from avoidd.config import HistogramConfig, ObstaclesConfig, SectorsConfig
from avoidd.perception.sectors import nearest_cluster
from avoidd.types import FloatArray
from avoidd.vision.depth import depth_histogram


@dataclass(frozen=True)
class Obstacle:
    """One obstacle seen by one head in one frame (level frame, from the body origin).

    Attributes:
        distance_m: Horizontal distance to its near side (robust, see ``nearest_cluster``).
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
) -> list[Obstacle]:
    """Group obstacle points into obstacles, nearest first.

    Points are binned on a grid of bearing by disparity (``f * B / range``, where stereo noise is
    about constant), occupied cells are joined by 8-connectivity, and each component with at
    least ``min_points`` points becomes an obstacle. A component never wraps across the
    bearing of +-180 degrees.

    Args:
        forward_m: Level-frame forward coordinates of the points, (N,).
        right_m: Level-frame right coordinates, (N,).
        above_ground_m: Height of each point above the ground plane, (N,).
        focal_baseline: The head's ``f * B`` (pixel metres).
        baseline_m: The head's baseline (for the cluster size rule).
        params: Clustering parameters.
        sectors: The robust near-distance parameters (as for the sector bins).
        histogram: Range histogram edges.

    Returns:
        Up to ``params.max_count`` obstacles, nearest first.
    """
    if forward_m.size < params.min_points:
        return []
    range_m = np.maximum(np.hypot(forward_m, right_m), np.float32(1e-3))
    bearing_deg = np.degrees(np.arctan2(right_m, forward_m))
    disparity_px = (np.float32(focal_baseline) / range_m).astype(np.float32)
    bearing_cells = math.ceil(360.0 / params.bearing_cell_deg) + 1
    b_index = np.floor((bearing_deg + 180.0) / params.bearing_cell_deg).astype(np.int64)
    d_index = np.floor(disparity_px / params.disparity_cell_px).astype(np.int64)
    d_cells = int(d_index.max()) + 2
    occupied = np.zeros((bearing_cells, d_cells), dtype=np.uint8)
    occupied[b_index, d_index] = 1
    count, labels = cv2.connectedComponents(occupied, connectivity=8, ltype=cv2.CV_32S)
    point_label = labels[b_index, d_index]
    sizes = np.bincount(point_label, minlength=count)
    kept = [label for label in range(1, count) if sizes[label] >= params.min_points]
    if not kept:
        return []
    order = np.argsort(point_label, kind="stable")
    starts = np.searchsorted(point_label[order], np.arange(count + 1))
    obstacles = []
    for label in kept:
        members = order[starts[label] : starts[label + 1]]
        obstacle = _describe(
            members,
            forward_m,
            right_m,
            above_ground_m,
            disparity_px,
            focal_baseline,
            baseline_m,
            sectors,
            histogram,
        )
        if obstacle is not None:
            obstacles.append(obstacle)
    obstacles.sort(key=lambda o: o.distance_m)
    return obstacles[: params.max_count]


def _describe(
    members: np.ndarray,
    forward_m: FloatArray,
    right_m: FloatArray,
    above_ground_m: FloatArray,
    disparity_px: FloatArray,
    focal_baseline: float,
    baseline_m: float,
    sectors: SectorsConfig,
    histogram: HistogramConfig,
) -> Obstacle | None:
    """Measure one cluster; None when it has no dense near side."""
    distance, chosen = nearest_cluster(
        np.zeros(members.size, dtype=np.int64),
        disparity_px[members],
        focal_baseline,
        min(sectors.min_pixels, members.size),
        sectors.cluster_window_px,
        sectors.min_size_m / baseline_m,
        sectors.min_size_m / focal_baseline,
    )
    if not np.isfinite(distance[0]):
        return None
    near = members[chosen[0]]
    forward, right = forward_m[members], right_m[members]
    centre = math.atan2(float(np.median(right)), float(np.median(forward)))
    across = -math.sin(centre) * forward + math.cos(centre) * right
    low, high = np.percentile(across, [2.0, 98.0])
    heights = above_ground_m[members]
    bottom, top = np.percentile(heights, [2.0, 98.0])
    ranges = np.hypot(forward, right)
    edges, counts = depth_histogram(ranges, histogram.min_m, histogram.max_m, histogram.bins)
    return Obstacle(
        distance_m=float(distance[0]),
        bearing_deg=math.degrees(math.atan2(float(right_m[near]), float(forward_m[near]))),
        lateral_m=float(right_m[near]),
        width_m=float(high - low),
        height_m=float(top - bottom),
        top_m=float(top),
        points=int(members.size),
        histogram_edges_m=tuple(float(e) for e in edges),
        histogram_counts=tuple(int(c) for c in counts),
    )
