"""Check a rectification on real images: vertical offset of features matched across the views."""

from __future__ import annotations

import cv2
import numpy as np
import numpy.typing as npt

from avoidd.types import Image
from avoidd.vision.calibration import Calibration

_MAX_CORNERS = 1500
_SUBPIX = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 40, 0.01)
# A track that does not return within this distance of its start is not trusted.
_ROUND_TRIP_PX = 0.3
# Mismatches are removed with a fundamental matrix fitted by RANSAC to the matches themselves,
# so the filter does not assume the rectification it is checking.
_RANSAC_PX = 1.5


def rectify_pair(calibration: Calibration, left: Image, right: Image) -> tuple[Image, Image]:
    """Remap a raw pair into the rectified views (unchanged when the rig is rectified)."""
    maps = calibration.maps
    if maps is None:
        return left, right
    return (
        np.asarray(cv2.remap(left, *maps.left, cv2.INTER_LINEAR), np.uint8),
        np.asarray(cv2.remap(right, *maps.right, cv2.INTER_LINEAR), np.uint8),
    )


def matched_dy_px(left: Image, right: Image, max_disparity_px: float) -> npt.NDArray[np.float64]:
    """|dy| of corners tracked from the left to the right rectified view, to subpixel.

    Corners are found in the left view, refined to subpixel, and followed into the right view with
    pyramidal Lucas-Kanade, which searches in both x and y and so measures dy rather than assuming
    it. Tracks that do not come back to where they started, or that leave the disparity range,
    are dropped, and so are matches off the epipolar geometry the tracks themselves support.

    Args:
        left: Rectified left view, 8-bit grey.
        right: Rectified right view, 8-bit grey.
        max_disparity_px: Matches whose horizontal offset is outside [0, this] are discarded.

    Returns:
        One |y_left - y_right| per surviving match (empty when nothing matched).
    """
    corners = cv2.goodFeaturesToTrack(left, _MAX_CORNERS, 0.01, 8)
    if corners is None or len(corners) < 8:
        return np.zeros(0)
    start = cv2.cornerSubPix(left, np.asarray(corners, np.float32), (5, 5), (-1, -1), _SUBPIX)
    forward, ok_f, _ = cv2.calcOpticalFlowPyrLK(
        left, right, start, start.copy(), winSize=(21, 21), maxLevel=4, criteria=_SUBPIX
    )
    back, ok_b, _ = cv2.calcOpticalFlowPyrLK(
        right, left, forward, start.copy(), winSize=(21, 21), maxLevel=4, criteria=_SUBPIX
    )
    pts_l = np.asarray(start, np.float64).reshape(-1, 2)
    pts_r = np.asarray(forward, np.float64).reshape(-1, 2)
    round_trip = np.linalg.norm(np.asarray(back, np.float64).reshape(-1, 2) - pts_l, axis=1)
    disparity = pts_l[:, 0] - pts_r[:, 0]
    keep = (
        ok_f.ravel().astype(bool)
        & ok_b.ravel().astype(bool)
        & (round_trip < _ROUND_TRIP_PX)
        & (disparity >= 0)
        & (disparity <= max_disparity_px)
    )
    pts_l, pts_r = pts_l[keep], pts_r[keep]
    if len(pts_l) < 8:
        return np.zeros(0)
    _f, inliers = cv2.findFundamentalMat(pts_l, pts_r, cv2.FM_RANSAC, _RANSAC_PX, 0.999)
    if inliers is None:
        return np.zeros(0)
    good = inliers.ravel().astype(bool)
    return np.abs(np.asarray(pts_l[good, 1] - pts_r[good, 1], np.float64))
