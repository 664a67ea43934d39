"""Check a rectification on real images: vertical offset of features matched across the views.

Only unambiguous matches count. A calibration board's corners all look alike, so a tracker or a
nearest-descriptor match happily pairs a corner with its neighbour one square away and reports
that square as |dy|. When the board is found in both views its own corner ids give the matches.
Otherwise a descriptor match must pass a ratio test (against the other view and against
look-alikes in its own view), be a mutual nearest neighbour, keep its orientation and scale, and
have a horizontal offset in the disparity range; it is then refined to subpixel and must agree
with the dy of its neighbouring matches.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from avoidd.calibrate.board import Board, detect
from avoidd.types import Image
from avoidd.vision.calibration import Calibration

Dy = npt.NDArray[np.float64]

_MAX_FEATURES = 2000
_SUBPIX = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 40, 0.01)
# Lowe's ratio: the best descriptor match must be clearly better than the second best.
_RATIO = 0.7
# A refinement that moves a match further than this from its descriptor position, or that does
# not track back to its start within _ROUND_TRIP_PX, is not trusted.
_REFINE_MAX_PX = 2.0
_ROUND_TRIP_PX = 0.3
# Wide enough that a window on a blob-like SIFT feature still holds the gradients to track.
_LK_WINDOW = (31, 31)
# The two views of a rig look the same way: a feature does not turn or grow much between them.
_MAX_TURN_DEG = 15.0
_MAX_SCALE = 1.3
# A match is compared with this many of its nearest matches and must agree within this dy.
_NEIGHBOURS = 6
_NEIGHBOUR_DY_PX = 1.0
# Features this close to the edge of the remapped content are ignored.
_RIM_PX = 12


def rectify_pair(calibration: Calibration, left: Image, right: Image) -> tuple[Image, Image]:
    """Remap a raw pair into the rectified views (unchanged when the rig is rectified)."""
    maps = calibration.maps
    if maps is None:
        return left, right
    return (
        np.asarray(cv2.remap(left, *maps.left, cv2.INTER_LINEAR), np.uint8),
        np.asarray(cv2.remap(right, *maps.right, cv2.INTER_LINEAR), np.uint8),
    )


def valid_masks(calibration: Calibration, shape: tuple[int, ...]) -> tuple[Image, Image] | None:
    """Where each rectified view holds image content, eroded away from the edge of the content.

    The rim of the remapped area is a strong, different edge in each view; features on it are not
    scene points. None when the rig is already rectified (all of each view is content).
    """
    maps = calibration.maps
    if maps is None:
        return None
    full = np.full(shape[:2], 255, np.uint8)
    kernel = np.ones((2 * _RIM_PX + 1, 2 * _RIM_PX + 1), np.uint8)

    def mask(map_x: npt.NDArray[Any], map_y: npt.NDArray[Any]) -> Image:
        inside = cv2.remap(full, map_x, map_y, cv2.INTER_NEAREST, borderValue=0)
        return np.asarray(cv2.erode(inside, kernel), np.uint8)

    return mask(*maps.left), mask(*maps.right)


def board_dy_px(board: Board, left: Image, right: Image) -> Dy | None:
    """|dy| of the board corners found in both rectified views, paired by corner id.

    Returns:
        One |y_left - y_right| per corner seen in both views, or None when either view does not
        show the board.
    """
    found_left, found_right = detect(board, left), detect(board, right)
    if found_left is None or found_right is None:
        return None
    _ids, at_left, at_right = np.intersect1d(
        found_left.ids, found_right.ids, assume_unique=True, return_indices=True
    )
    if at_left.size == 0:
        return None
    y_left = found_left.image_px[at_left, 1].astype(np.float64)
    y_right = found_right.image_px[at_right, 1].astype(np.float64)
    return np.asarray(np.abs(y_left - y_right), np.float64)


def matched_dy_px(
    left: Image,
    right: Image,
    max_disparity_px: float,
    valid: tuple[Image, Image] | None = None,
) -> Dy:
    """|dy| of unambiguous features matched between the rectified views, to subpixel.

    SIFT features are matched by descriptor; a match is kept only when it passes the ratio test,
    is the mutual nearest neighbour, has no near twin in either view, keeps its orientation and
    scale, and its horizontal offset lies in [0, ``max_disparity_px``].
    Nothing here assumes the rectification being checked: the vertical offset is not bounded.
    Survivors are refined with Lucas-Kanade in both x and y and dropped if the refinement wanders
    or does not track back to its start.

    Args:
        left: Rectified left view, 8-bit grey.
        right: Rectified right view, 8-bit grey.
        max_disparity_px: Matches whose horizontal offset is outside [0, this] are discarded.
        valid: Masks of the image content of each view (``valid_masks``); features elsewhere are
            ignored.

    Returns:
        One |y_left - y_right| per surviving match (empty when nothing matched).
    """
    mask_l, mask_r = valid if valid is not None else (None, None)
    sift = cv2.SIFT.create(nfeatures=_MAX_FEATURES)
    keys_l, desc_l = sift.detectAndCompute(left, mask_l)
    keys_r, desc_r = sift.detectAndCompute(right, mask_r)
    if desc_l is None or desc_r is None or len(keys_l) < 2 or len(keys_r) < 2:
        return np.zeros(0)
    matcher = cv2.BFMatcher(cv2.NORM_L2)
    forward = matcher.knnMatch(desc_l, desc_r, k=2)
    backward = matcher.knnMatch(desc_r, desc_l, k=1)
    best_back = {m[0].queryIdx: m[0].trainIdx for m in backward if m}
    alike_l, alike_r = _nearest_other(matcher, desc_l), _nearest_other(matcher, desc_r)
    pairs = []
    for candidates in forward:
        if len(candidates) < 2:
            continue
        best, second = candidates
        limit = _RATIO * min(second.distance, alike_l[best.queryIdx], alike_r[best.trainIdx])
        if best.distance >= limit or best_back.get(best.trainIdx) != best.queryIdx:
            continue
        key_l, key_r = keys_l[best.queryIdx], keys_r[best.trainIdx]
        if not _same_look(key_l, key_r):
            continue
        pairs.append((key_l.pt, key_r.pt))
    if not pairs:
        return np.zeros(0)
    # SIFT gives a point one feature per dominant orientation: count each point once, or its
    # copies vouch for each other in the neighbour check.
    pts = np.unique(np.round(np.asarray(pairs, np.float64), 2), axis=0)
    disparity = pts[:, 0, 0] - pts[:, 1, 0]
    pts = pts[(disparity >= 0) & (disparity <= max_disparity_px)]
    if len(pts) == 0:
        return np.zeros(0)
    return _refined_dy(left, right, pts[:, 0].astype(np.float64), pts[:, 1].astype(np.float64))


def _same_look(key_l: cv2.KeyPoint, key_r: cv2.KeyPoint) -> bool:
    """Whether two features turn and scale as one scene point does between two parallel views.

    SIFT descriptors do not see rotation, so without this a board's top-left corner can match its
    bottom-right one turned half a turn.
    """
    turn_deg = abs((key_l.angle - key_r.angle + 180.0) % 360.0 - 180.0)
    scale = max(key_l.size, key_r.size) / max(min(key_l.size, key_r.size), 1e-6)
    return turn_deg <= _MAX_TURN_DEG and scale <= _MAX_SCALE


def _nearest_other(
    matcher: cv2.BFMatcher, descriptors: npt.NDArray[Any]
) -> npt.NDArray[np.float64]:
    """Descriptor distance from each feature to the most alike other feature of the same view.

    A feature with a near twin in its own view (a board corner, a window in a facade) is not one a
    match can be trusted on, however good the match looks.
    """
    twins = matcher.knnMatch(descriptors, descriptors, k=2)
    return np.array([t[1].distance if len(t) > 1 else np.inf for t in twins], np.float64)


def _refined_dy(
    left: Image, right: Image, pts_l: npt.NDArray[np.float64], pts_r: npt.NDArray[np.float64]
) -> Dy:
    """Refine descriptor matches with Lucas-Kanade, then keep those their neighbours agree with."""
    start = np.asarray(pts_l, np.float32).reshape(-1, 1, 2)
    guess = np.asarray(pts_r, np.float32).reshape(-1, 1, 2)
    flags = cv2.OPTFLOW_USE_INITIAL_FLOW
    forward, ok_f, _ = cv2.calcOpticalFlowPyrLK(
        left, right, start, guess.copy(), None, None, _LK_WINDOW, 2, _SUBPIX, flags
    )
    back, ok_b, _ = cv2.calcOpticalFlowPyrLK(
        right, left, forward, start.copy(), None, None, _LK_WINDOW, 2, _SUBPIX, flags
    )
    at_l = start.reshape(-1, 2).astype(np.float64)
    at_r = np.asarray(forward, np.float64).reshape(-1, 2)
    moved = np.linalg.norm(at_r - pts_r, axis=1)
    round_trip = np.linalg.norm(np.asarray(back, np.float64).reshape(-1, 2) - at_l, axis=1)
    keep = (
        ok_f.ravel().astype(bool)
        & ok_b.ravel().astype(bool)
        & (moved < _REFINE_MAX_PX)
        & (round_trip < _ROUND_TRIP_PX)
    )
    at_l, at_r = at_l[keep], at_r[keep]
    signed_dy = at_l[:, 1] - at_r[:, 1]
    agreed = _agrees_with_neighbours(at_l, signed_dy)
    return np.asarray(np.abs(signed_dy[agreed]), np.float64)


def _agrees_with_neighbours(
    at_px: npt.NDArray[np.float64], signed_dy: npt.NDArray[np.float64]
) -> npt.NDArray[np.bool_]:
    """Matches whose dy is within _NEIGHBOUR_DY_PX of the median dy of their nearest matches.

    A rectification error makes dy vary smoothly across the image, a mismatch makes one match jump
    away from those around it; this keeps the first and drops the second without assuming any
    particular rectification. With too few matches to compare, none is trusted.
    """
    count = len(signed_dy)
    if count <= _NEIGHBOURS:
        return np.zeros(count, bool)
    distance = np.linalg.norm(at_px[:, None, :] - at_px[None, :, :], axis=2)
    np.fill_diagonal(distance, np.inf)
    nearest = np.argsort(distance, axis=1)[:, :_NEIGHBOURS]
    local_dy = np.median(signed_dy[nearest], axis=1)
    return np.asarray(np.abs(signed_dy - local_dy) <= _NEIGHBOUR_DY_PX, bool)
