"""The ground model: which points are ground or out of the height band; the ground-plane fit."""

from __future__ import annotations

import math
from typing import NamedTuple

import cv2
import numpy as np
import numpy.typing as npt

from avoidd.config import BandConfig, GroundConfig
from avoidd.perception.frames import Components, Pose, axis_per_depth
from avoidd.perception.workspace import Workspace
from avoidd.types import BoolArray, FloatArray, RectifiedRig

Vector = npt.NDArray[np.float64]


class ObstaclePoints(NamedTuple):
    """The pixels of a depth map that may belong to an obstacle, and their level-frame points.

    Attributes:
        mask: (H, W), True at those pixels.
        level: Their level-frame coordinates, (N,) each, in row-major pixel order.
        free_per_column: (W,) pixels per column that show free space (see
            :func:`free_space_evidence`).
        unseen_per_column: (W,) pixels per column in unmeasured patches where a surface may
            stand (see :func:`unseen_surfaces`).
        horizontal2_m2: With ``whole_image``: (H * W,) squared horizontal range of every
            pixel's point (None otherwise).
    """

    mask: BoolArray
    level: Components
    free_per_column: npt.NDArray[np.int64]
    unseen_per_column: npt.NDArray[np.int64]
    horizontal2_m2: FloatArray | None = None


def obstacle_points(
    depth_m: FloatArray,
    rig: RectifiedRig,
    to_level: Pose,
    height_m: float,
    ground: GroundConfig,
    band: BandConfig,
    max_range_m: float,
    workspace: Workspace | None = None,
    whole_image: bool = False,
    unseen_patch_px: tuple[int, int] = (3, 3),
) -> ObstaclePoints:
    """Pixels whose point may belong to an obstacle, with their level-frame points.

    A point is kept when it lies within the height band around the body origin, nearer than
    ``max_range_m`` horizontally, and stands at least ``ground.margin_m`` above the ground plane
    (``height_m`` below the body origin in the level frame) even when its disparity is taken
    ``ground.disparity_tolerance_px`` smaller. That tolerance matters far away: one pixel of
    disparity is a third of the depth at 16 m for a 48 px m rig, so far ground measured a
    pixel too near rises half a metre above the plane; moved back by the tolerance along its
    ray it sinks into the ground, while a real obstacle stays above it. A point measured at a
    disparity at or below the tolerance cannot be placed at all and is never kept.

    Every coordinate is ``Z * c[v, u] + t`` (see
    :func:`~avoidd.perception.frames.axis_per_depth`): a product of the depth with one
    per-pixel map. The tests run on whole images and the kept points are gathered once at the
    end; in a room most pixels are obstacle candidates, and gathering pixel by pixel (index
    arithmetic, then coordinates of the survivors) cost twice as much there.

    Args:
        depth_m: Optical depth of every pixel (NaN unmeasured, ``inf`` measured far).
        rig: The rig of the depth map.
        to_level: Camera-to-level pose of the frame.
        height_m: Height of the body origin above the ground.
        ground: Ground model parameters.
        band: Height band parameters.
        max_range_m: Points at or beyond this horizontal range are left out (they are clear).
        workspace: Where the temporaries and the points live (see
            :mod:`avoidd.perception.workspace`: the points are overwritten by its next frame);
            arrays of their own when None. The mask is always a new array.
        whole_image: Give the points of every pixel (``level`` and ``horizontal2_m2`` are
            (H * W,), the mask says which are kept) instead of gathering the kept ones: the
            sector scan and the obstacle list then cost the same whatever share of the image
            is obstacle, and no gather is paid when most of it is.
        unseen_patch_px: The smallest unmeasured patch that keeps a bin from reading clear,
            rows by columns (see :func:`unseen_surfaces`).

    Returns:
        The kept pixels and their points.
    """
    ws = workspace or Workspace()
    shape = depth_m.shape
    f32 = np.float32
    camera_down = float(to_level.translation[2])
    forward_map = axis_per_depth(rig, shape, to_level, 0, ws.array("forward_map", shape, f32))
    right_map = axis_per_depth(rig, shape, to_level, 1, ws.array("right_map", shape, f32))
    down_map = axis_per_depth(rig, shape, to_level, 2, ws.array("down_map", shape, f32))
    # Every step writes into a kept array: a fresh whole-image array costs more to map than
    # the arithmetic in it.
    scratch = ws.array("scratch", shape, f32)
    test = ws.array("test", shape, np.bool_)
    # Down coordinate relative to the camera: how far the point lies below the camera (NaN
    # for a far reading on a level ray: inf times 0; it is not kept either way).
    with np.errstate(invalid="ignore"):
        rise = np.multiply(depth_m, down_map, out=ws.array("rise", shape, f32))
    # Moved back along its ray to disparity d - tol, a point's offset from the camera scales
    # by 1 / s with s = 1 - tol * Z / fB; its ground test rise / s <= K (K: clearance of the
    # camera over the ground less the margin) is, for s > 0, rise + K * tol / fB * Z <= K.
    clearance = height_m - ground.margin_m - camera_down
    per_depth = ground.disparity_tolerance_px / (rig.fx * rig.baseline_m)
    with np.errstate(invalid="ignore"):
        keep = np.greater_equal(rise, f32(-band.above_m - camera_down))  # returned: a new one
        keep &= np.less_equal(rise, f32(band.below_m - camera_down), out=test)
        if per_depth > 0:
            farthest = min(1.0 / per_depth, float(np.finfo(f32).max))
            keep &= np.less(depth_m, f32(farthest), out=test)
            np.multiply(depth_m, f32(clearance * per_depth), out=scratch)
            scratch += rise
            keep &= np.less_equal(scratch, f32(clearance), out=test)
        else:
            keep &= np.less_equal(rise, f32(clearance), out=test)
        forward = np.multiply(depth_m, forward_map, out=ws.array("forward", shape, f32))
        forward += f32(to_level.translation[0])
        right = np.multiply(depth_m, right_map, out=ws.array("right", shape, f32))
        right += f32(to_level.translation[1])
        np.multiply(forward, forward, out=scratch)
        # The right map is not needed after this frame's free-space test: reuse it last.
        keep &= np.less(
            np.add(scratch, np.square(right, out=ws.array("right2", shape, f32)), out=scratch),
            f32(max_range_m * max_range_m),
            out=test,
        )
    rise += f32(camera_down)  # now the down coordinate
    free, watched = _free_space(
        depth_m, forward_map, right_map, down_map, camera_down, band, max_range_m, ws
    )
    free_per_column = np.count_nonzero(free, axis=0).astype(np.int64)
    unseen = _unseen_patches(depth_m, watched, unseen_patch_px, ws)
    unseen_per_column = np.count_nonzero(unseen, axis=0).astype(np.int64)
    if whole_image:
        level = Components(forward.ravel(), right.ravel(), rise.ravel())
        return ObstaclePoints(keep, level, free_per_column, unseen_per_column, scratch.ravel())
    # Gathering by index is several times faster than a boolean mask on a scattered one.
    kept = np.flatnonzero(keep)
    count = kept.size
    return ObstaclePoints(
        keep,
        Components(
            np.take(forward.ravel(), kept, out=ws.array("kept_forward", count, f32)),
            np.take(right.ravel(), kept, out=ws.array("kept_right", count, f32)),
            np.take(rise.ravel(), kept, out=ws.array("kept_down", count, f32)),
        ),
        free_per_column,
        unseen_per_column,
    )


def free_space_evidence(
    depth_m: FloatArray, rig: RectifiedRig, to_level: Pose, band: BandConfig, max_range_m: float
) -> BoolArray:
    """Pixels that show free space out to the maximum range within the height band.

    A pixel is evidence that its direction is clear when it was measured (a finite or
    infinite depth: NaN is not a measurement), its point lies at or beyond ``max_range_m``
    horizontally, and its ray is still inside the height band there, so it crossed the band
    all the way without meeting anything. A bin is reported clear only with enough of these;
    obstacle points that form no cluster, unmeasured pixels and impossible geometry (NaN in
    the pose) are no evidence of anything.

    Args:
        depth_m: Optical depth of every pixel (NaN unmeasured, ``inf`` measured far).
        rig: The rig of the depth map.
        to_level: Camera-to-level pose of the frame.
        band: Height band parameters.
        max_range_m: The range beyond which a direction counts as clear.

    Returns:
        (H, W) boolean mask.
    """
    return _free_space_of(depth_m, rig, to_level, band, max_range_m).free.copy()


def unseen_surfaces(
    depth_m: FloatArray,
    rig: RectifiedRig,
    to_level: Pose,
    band: BandConfig,
    max_range_m: float,
    patch_px: tuple[int, int],
) -> BoolArray:
    """Unmeasured patches where a surface standing in the height band may be.

    A ray *watches* the band when it points at or above the level and is still inside the
    band at ``max_range_m`` (the band is a slab the camera sits in, so it is inside all the
    way there): whatever stands in the band within that range and reaches the camera's height
    meets such rays. A patch of unmeasured watching rays at least ``patch_px`` (rows, columns)
    in size may be a surface too plain to match, or one the matcher gave up on, at any range
    up to the maximum: a bin that holds one is never clear. Sky above the band at the maximum
    range watches nothing, and neither do rays below the level: far ground at a grazing angle
    and dark noisy ground leave holes there that are no surface (so a plain obstacle lower
    than the camera escapes this test). Smaller holes are matcher noise.

    Args:
        depth_m: Optical depth of every pixel (NaN unmeasured).
        rig: The rig of the depth map.
        to_level: Camera-to-level pose of the frame.
        band: Height band parameters.
        max_range_m: The range a clear bin vouches for.
        patch_px: The smallest patch that counts, rows by columns.

    Returns:
        (H, W) boolean mask of the pixels in such patches.
    """
    watched = _free_space_of(depth_m, rig, to_level, band, max_range_m).watched
    return _unseen_patches(depth_m, watched, patch_px, Workspace()).astype(bool)


def _free_space_of(
    depth_m: FloatArray, rig: RectifiedRig, to_level: Pose, band: BandConfig, max_range_m: float
) -> FreeSpace:
    """:func:`_free_space` of a depth map, its pixel maps made here (in arrays of their own)."""
    forward, right, down = (axis_per_depth(rig, depth_m.shape, to_level, i) for i in range(3))
    camera_down_m = float(to_level.translation[2])
    return _free_space(depth_m, forward, right, down, camera_down_m, band, max_range_m, Workspace())


def _unseen_patches(
    depth_m: FloatArray, watched: BoolArray, patch_px: tuple[int, int], workspace: Workspace
) -> npt.NDArray[np.uint8]:
    """Unmeasured watching pixels that lie in a patch of at least ``patch_px`` (1 inside)."""
    unseen = workspace.array("unseen", depth_m.shape, np.uint8)
    np.logical_and(watched, np.isnan(depth_m), out=unseen.view(np.bool_))
    # An opening keeps the pixels of every patch the kernel fits in; outside the image counts
    # as measured, so a strip along the border is no larger than it looks.
    kernel = np.ones(patch_px, dtype=np.uint8)
    opened = cv2.morphologyEx(
        unseen, cv2.MORPH_OPEN, kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0
    )
    return np.asarray(opened, dtype=np.uint8)


class FreeSpace(NamedTuple):
    """Per pixel: free-space evidence, and whether the ray watches the band.

    Attributes:
        free: Measured at or beyond the range with the ray still inside the band there.
        watched: The ray points at or above the level and is inside the band at the range
            (measured or not): see :func:`unseen_surfaces`.
    """

    free: BoolArray
    watched: BoolArray


def _free_space(
    depth_m: FloatArray,
    forward_map: FloatArray,
    right_map: FloatArray,
    down_map: FloatArray,
    camera_down_m: float,
    band: BandConfig,
    max_range_m: float,
    workspace: Workspace | None = None,
) -> FreeSpace:
    """:func:`free_space_evidence` and the far band from the maps of :func:`axis_per_depth`.

    The results are arrays of ``workspace`` (overwritten by its next frame).
    """
    ws = workspace or Workspace()
    shape = depth_m.shape
    f32 = np.float32
    horizontal = np.multiply(forward_map, forward_map, out=ws.array("horizontal", shape, f32))
    horizontal += np.square(right_map, out=ws.array("right2", shape, f32))
    np.sqrt(horizontal, out=horizontal)
    scratch = ws.array("free_scratch", shape, f32)
    test = ws.array("free_test", shape, np.bool_)
    with np.errstate(invalid="ignore", divide="ignore"):
        beyond: BoolArray = np.greater_equal(
            np.multiply(depth_m, horizontal, out=scratch),
            f32(max_range_m),
            out=ws.array("free", shape, np.bool_),
        )
        # Height of the ray where it reaches the maximum range (the camera's own offset from
        # the body origin is small next to that range and is taken at the camera).
        down_there = np.divide(down_map, horizontal, out=scratch)
        down_there *= f32(max_range_m)
        down_there += f32(camera_down_m)
        watched = np.greater_equal(
            down_there, f32(-band.above_m), out=ws.array("watched", shape, np.bool_)
        )
        watched &= np.less_equal(down_there, f32(band.below_m), out=test)
        beyond &= watched
        watched &= np.less_equal(down_map, f32(0.0), out=test)
    return FreeSpace(beyond, watched)


def height_from_rangefinder(distance_m: float, roll_deg: float, pitch_deg: float) -> float:
    """Height above flat ground from a downward rangefinder fixed to the body.

    The beam follows the body's down axis, so a tilted vehicle measures a longer slant.

    Args:
        distance_m: The rangefinder's reading.
        roll_deg: Vehicle roll.
        pitch_deg: Vehicle pitch.

    Returns:
        The vertical height.
    """
    return distance_m * math.cos(math.radians(roll_deg)) * math.cos(math.radians(pitch_deg))


class Plane(NamedTuple):
    """A plane ``normal . p = offset`` (unit normal) and the share of points that fit it.

    Attributes:
        normal: Unit normal, oriented so that ``offset`` is positive (pointing away from the
            origin, i.e. from the camera toward the plane).
        offset_m: Distance of the plane from the origin.
        inlier_fraction: Share of the points within the fit's threshold.
        rms_m: RMS distance of the inliers from the plane.
    """

    normal: Vector
    offset_m: float
    inlier_fraction: float
    rms_m: float


def fit_plane(
    points_m: npt.ArrayLike,
    threshold_m: float,
    iterations: int = 300,
    seed: int = 0,
) -> Plane:
    """Fit a plane to 3D points robustly: RANSAC on triples, then least squares on the inliers.

    Args:
        points_m: (N, 3) points, N >= 3.
        threshold_m: A point within this distance of the plane is an inlier. Distances grow
            with range in stereo data, so the RANSAC test scales it by the point's range over
            the median range.
        iterations: RANSAC trials.
        seed: Seed of the trial sampling (the fit is deterministic for given points).

    Returns:
        The plane.

    Raises:
        ValueError: Fewer than 3 points or no plane through them.
    """
    points = np.asarray(points_m, dtype=np.float64).reshape(-1, 3)
    points = points[np.all(np.isfinite(points), axis=1)]
    if points.shape[0] < 3:
        raise ValueError(f"a plane needs at least 3 points, got {points.shape[0]}")
    ranges = np.linalg.norm(points, axis=1)
    tolerance = threshold_m * np.maximum(ranges / max(float(np.median(ranges)), 1e-9), 0.25)
    rng = np.random.default_rng(seed)
    best: BoolArray | None = None
    best_count = -1
    for _ in range(iterations):
        a, b, c = points[rng.choice(points.shape[0], 3, replace=False)]
        normal = np.cross(b - a, c - a)
        length = float(np.linalg.norm(normal))
        if length < 1e-12:
            continue
        normal /= length
        inliers = np.abs(points @ normal - float(normal @ a)) <= tolerance
        count = int(np.count_nonzero(inliers))
        if count > best_count:
            best, best_count = inliers, count
    if best is None or best_count < 3:
        raise ValueError("no plane fits these points (are they all on one line?)")
    for _ in range(3):
        normal, offset = _least_squares_plane(points[best])
        best = np.abs(points @ normal - offset) <= tolerance
    normal, offset = _least_squares_plane(points[best])
    residual = points[best] @ normal - offset
    return Plane(
        normal,
        offset,
        float(np.count_nonzero(best)) / points.shape[0],
        float(np.sqrt(np.mean(residual * residual))),
    )


def _least_squares_plane(points: Vector) -> tuple[Vector, float]:
    """Total least squares plane through points: normal is the smallest singular vector."""
    centre = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - centre, full_matrices=False)
    normal = vt[-1]
    offset = float(normal @ centre)
    if offset < 0:
        normal, offset = -normal, -offset
    return normal, offset
