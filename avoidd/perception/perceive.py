"""One head's depth map to obstacle points, its sector scan and (optionally) its obstacle list."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from avoidd.config import GroundConfig, HistogramConfig, PerceptionConfig, SectorsConfig
from avoidd.errors import BrokenFrame
from avoidd.perception.frames import Matrix, Pose, axis_per_depth, body_to_level, camera_to_level
from avoidd.perception.grid import point_cells
from avoidd.perception.ground import obstacle_points
from avoidd.perception.ground_match import Views, explained_by_ground
from avoidd.perception.obstacles import Obstacle, cluster_obstacles
from avoidd.perception.sectors import Candidates, sector_scan
from avoidd.perception.workspace import Workspace
from avoidd.types import BoolArray, FloatArray, FramePose, Mount, RectifiedRig, SectorScan

_GATHER_BELOW = 0.4
"""Below this share of kept pixels the points are gathered before binning (cheaper then)."""


class Perception(NamedTuple):
    """What one head saw in one frame.

    Attributes:
        scan: Its 72-bin scan.
        obstacles: Its obstacles, nearest first (empty unless asked for).
        candidates: Obstacle points (after ground and band rejection).
        pose: The attitude and height the frame was interpreted with.
        candidate_mask: (H, W) True at the pixels of those obstacle points.
    """

    scan: SectorScan
    obstacles: list[Obstacle]
    candidates: int
    pose: FramePose
    candidate_mask: BoolArray | None = None


def unseen_patch_px(
    rig: RectifiedRig, sectors: SectorsConfig, max_range_m: float
) -> tuple[int, int]:
    """The smallest unmeasured patch that keeps a bin from clear, rows by columns.

    ``sectors.unseen_patch_m`` seen at the maximum range, and never under 3 x 3 pixels (single
    holes and two-pixel seams are the matcher's noise, not surfaces). Each side is odd: an
    opening with an even kernel moves what it keeps by a pixel.

    Args:
        rig: The rig of the depth map.
        sectors: Sector parameters.
        max_range_m: The range a clear bin vouches for.
    """

    def side(focal_px: float, limit_px: int) -> int:
        wanted = sectors.unseen_patch_m * focal_px / max(max_range_m, 1e-3)
        return max(3, min(limit_px, math.ceil(wanted))) | 1

    return side(rig.fy, rig.height), side(rig.fx, rig.width)


def rectified_to_level(
    mount: Mount, pose: FramePose, rectified_from_raw: Matrix | None = None
) -> Pose:
    """Pose of the rectified left view in the level frame (mount, attitude, rectification).

    Args:
        mount: The head's mount (it describes the physical camera).
        pose: Vehicle roll and pitch at capture.
        rectified_from_raw: Rotation from the physical left camera to the rectified view;
            identity when None.

    Returns:
        Rectified-camera-to-level pose.
    """
    to_level = camera_to_level(mount, pose.roll_deg, pose.pitch_deg)
    if rectified_from_raw is not None:
        # Rectified points turn back into the physical camera's frame first.
        to_level = Pose(to_level.rotation @ rectified_from_raw.T, to_level.translation)
    return to_level


def perceive(
    depth_m: FloatArray,
    rig: RectifiedRig,
    mount: Mount,
    pose: FramePose,
    config: PerceptionConfig,
    sectors: SectorsConfig,
    histogram: HistogramConfig,
    max_range_m: float,
    t_capture_ns: int,
    with_obstacles: bool = False,
    rectified_from_raw: Matrix | None = None,
    unresolved_per_column: npt.NDArray[np.integer] | None = None,
    views: Views | None = None,
) -> Perception:
    """Turn a measured depth map into the head's sector scan (and obstacles).

    Args:
        depth_m: Depth along the optical axis of measured pixels (NaN elsewhere).
        rig: The rig of the depth map.
        mount: The head's mount.
        pose: Vehicle roll, pitch and height above ground at capture.
        config: Ground, band and clustering parameters.
        sectors: Per-bin robustness parameters.
        histogram: Edges of the obstacles' range histograms.
        max_range_m: Readings at or beyond this horizontal range are clear.
        t_capture_ns: Capture time of the frame.
        with_obstacles: Also cluster the points into obstacles.
        rectified_from_raw: Rotation from the physical left camera to the rectified view
            (the mount describes the physical camera); identity when None.
        unresolved_per_column: (W,) textured pixels per column left without a measurement
            (a bin with many is not clear); None: none.
        views: The views the depth map was matched on: obstacle points below the horizon
            that match the ground plane's disparity as well are dropped (see
            :mod:`avoidd.perception.ground_match`); None: no such check.

    Returns:
        The head's perception of the frame.

    Raises:
        BrokenFrame: The pose or the mount holds a number that is not finite.
    """
    numbers = (pose.roll_deg, pose.pitch_deg, pose.height_m, *mount.position_m)
    if not all(math.isfinite(value) for value in numbers) or not np.isfinite(rig.fx * rig.fy):
        # Impossible geometry must not turn into "nothing in the way": the frame is dropped,
        # and a head that only yields such frames goes stale.
        raise BrokenFrame(
            f"frame at {t_capture_ns} ns: pose roll {pose.roll_deg}, pitch {pose.pitch_deg}, "
            f"height {pose.height_m} ({pose.source}/{pose.height_source}) or mount position "
            f"{mount.position_m} is not a finite number; dropped"
        )
    to_level = rectified_to_level(mount, pose, rectified_from_raw)
    # The thread's workspace keeps the temporaries (and the points) from frame to frame.
    workspace = Workspace.for_thread()
    # Every pixel comes back as a point (the mask says which are kept). When most are kept
    # (a wall filling the view), they are binned in place: no gather, and the cost is that of
    # the whole image whatever share of it is obstacle. When few are, gathering them first
    # is cheaper.
    points = obstacle_points(
        depth_m,
        rig,
        to_level,
        pose.height_m,
        config.ground,
        config.band,
        max_range_m,
        workspace,
        whole_image=True,
        unseen_patch_px=unseen_patch_px(rig, sectors, max_range_m),
    )
    if views is not None and config.ground.match_band_px > 0:
        _drop_what_the_ground_explains(
            points.mask, views, rig, to_level, pose.height_m, config.ground, workspace
        )
    forward, right, down = points.level
    mask = points.mask.ravel()
    candidates = int(np.count_nonzero(mask))
    kept: npt.NDArray[np.bool_] | None = mask
    horizontal2 = points.horizontal2_m2
    if candidates < _GATHER_BELOW * mask.size:
        index = np.flatnonzero(mask)
        f32 = np.float32
        forward = np.take(forward, index, out=workspace.array("kept_forward", candidates, f32))
        right = np.take(right, index, out=workspace.array("kept_right", candidates, f32))
        down = np.take(down, index, out=workspace.array("kept_down", candidates, f32))
        kept = horizontal2 = None
    # The points are binned once, for the scan and the obstacle list.
    cells = point_cells(
        forward,
        right,
        rig.fx * rig.baseline_m,
        sectors.cluster_window_px,
        workspace,
        kept,
        horizontal2,
    )
    level_from_body = body_to_level(pose.roll_deg, pose.pitch_deg).rotation
    unmeasured = np.isnan(depth_m, out=workspace.array("unmeasured", depth_m.shape, np.bool_))
    valid_per_column = depth_m.shape[0] - np.count_nonzero(unmeasured, axis=0)  # inf: far
    scan = sector_scan(
        Candidates(forward, right, down, level_from_body),
        valid_per_column,
        points.free_per_column,
        points.unseen_per_column,
        unresolved_per_column
        if unresolved_per_column is not None
        else np.zeros(depth_m.shape[1], dtype=np.int64),
        depth_m.shape[0],
        rig,
        mount,
        sectors,
        t_capture_ns,
        cells,
        workspace,
    )
    obstacles: list[Obstacle] = []
    if with_obstacles:
        above_ground = np.subtract(
            np.float32(pose.height_m), down, out=workspace.array("above", down.size, np.float32)
        )
        obstacles = cluster_obstacles(
            forward,
            right,
            above_ground,
            rig.fx * rig.baseline_m,
            rig.baseline_m,
            config.obstacles,
            sectors,
            histogram,
            cells,
            workspace,
        )
    return Perception(scan, obstacles, candidates, pose, points.mask)


def _drop_what_the_ground_explains(
    mask: BoolArray,
    views: Views,
    rig: RectifiedRig,
    to_level: Pose,
    height_m: float,
    ground_config: GroundConfig,
    workspace: Workspace,
) -> None:
    """Clear the candidates of ``mask`` that the ground plane's disparity explains as well."""
    camera_height_m = height_m - float(to_level.translation[2])
    if not camera_height_m > 0.0 or not mask.any():
        return
    # A pixel's point lies Z * down_map below the camera: it meets the ground at
    # Z = camera height / down_map, where its disparity is f B / Z - doffs.
    shape = mask.shape
    ground = axis_per_depth(
        rig, shape, to_level, 2, workspace.array("ground_disparity", shape, np.float32)
    )
    ground *= np.float32(rig.fx * rig.baseline_m / camera_height_m)
    if rig.doffs_px:
        # Where the ray misses the ground the product is at most 0: it stays so.
        np.subtract(ground, np.float32(rig.doffs_px), out=ground, where=ground > 0)
    mask &= ~explained_by_ground(views, ground, mask, workspace, ground_config.match_band_px)
