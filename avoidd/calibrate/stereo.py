"""Stereo calibration from board detections: per camera, then jointly, outlier pairs dropped."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from avoidd.calibrate.board import Board, Detection
from avoidd.errors import AvoiddError
from avoidd.types import RectifiedRig
from avoidd.vision.calibration import StereoModel, rectification, rectify_stereo

MIN_PAIRS = 5
# A pair is an outlier when its stereo reprojection error exceeds both of these.
OUTLIER_FACTOR = 4.0
OUTLIER_FLOOR_PX = 1.0
# Before the joint solve, a pair whose own left-to-right pose is this far from the consensus
# of all pairs cannot be a simultaneous view of a rigid board.
POSE_SPREAD_BASELINE = 0.1
POSE_SPREAD_DEG = 2.0
_CRITERIA = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-9)


class CalibrationFailed(AvoiddError):
    """The images do not support a calibration (too few usable pairs)."""


@dataclass(frozen=True)
class PairObservation:
    """The corners both views of one pair share."""

    name: str
    object_m: npt.NDArray[np.float32]
    left_px: npt.NDArray[np.float32]
    right_px: npt.NDArray[np.float32]


@dataclass(frozen=True)
class PairReport:
    """What became of one pair: used (with its error) or dropped (with the reason)."""

    name: str
    used: bool
    reason: str = ""
    error_px: float | None = None
    corners: int = 0


@dataclass(frozen=True)
class StereoCalibration:
    """The result of ``calibrate``.

    Attributes:
        model: The calibration in the project's file format.
        rig: The rectified rig it gives.
        rms_px: Stereo RMS reprojection error over the used pairs.
        left_rms_px: Left camera alone.
        right_rms_px: Right camera alone.
        pairs: One report per input pair, in input order.
        dy_mean_px: Mean |dy| of matched corners after rectification.
        dy_max_px: Largest |dy| of matched corners after rectification.
    """

    model: StereoModel
    rig: RectifiedRig
    rms_px: float
    left_rms_px: float
    right_rms_px: float
    pairs: list[PairReport]
    dy_mean_px: float
    dy_max_px: float


def observe_pair(
    board: Board, name: str, left: Detection | None, right: Detection | None
) -> PairObservation | PairReport:
    """Match the corners of both views of one pair.

    Returns:
        The shared corners, or a report saying why the pair cannot be used.
    """
    if left is None or right is None:
        side = (
            "either image"
            if left is None and right is None
            else ("the left image" if left is None else "the right image")
        )
        return PairReport(name, False, f"board not found in {side}")
    shared, left_at, right_at = np.intersect1d(left.ids, right.ids, return_indices=True)
    minimum = 8 if board.pattern == "charuco" else len(board.object_points())
    if len(shared) < minimum:
        return PairReport(name, False, f"only {len(shared)} corners seen by both cameras")
    return PairObservation(
        name,
        board.object_points()[shared],
        left.image_px[left_at],
        right.image_px[right_at],
    )


def calibrate(
    size: tuple[int, int], observations: Sequence[PairObservation | PairReport]
) -> StereoCalibration:
    """Calibrate a stereo rig, dropping pairs whose error stands out, one at a time.

    Args:
        size: Image width and height, pixels.
        observations: One entry per input pair, from ``observe_pair``.

    Returns:
        The calibration, its errors and the rectification check.

    Raises:
        CalibrationFailed: Fewer than ``MIN_PAIRS`` usable pairs.
    """
    reports: dict[str, PairReport] = {o.name: o for o in observations if isinstance(o, PairReport)}
    used = [o for o in observations if isinstance(o, PairObservation)]
    if len(used) >= MIN_PAIRS:
        for index, reason in reversed(_disagreeing_pairs(size, used)):
            reports[used[index].name] = PairReport(used[index].name, False, reason)
            del used[index]
    while True:
        if len(used) < MIN_PAIRS:
            raise CalibrationFailed(
                f"only {len(used)} usable pairs (at least {MIN_PAIRS} needed); capture 15 or "
                "more pairs with the whole board in both images, tilted and in every part of "
                "the view"
            )
        solution = _solve(size, used)
        errors = solution.per_pair_px
        median = float(np.median(errors))
        worst = int(np.argmax(errors))
        limit = max(OUTLIER_FACTOR * median, OUTLIER_FLOOR_PX)
        if errors[worst] <= limit:
            break
        reason = (
            f"reprojection error {errors[worst]:.2f} px > {limit:.2f} px "
            "(moved between the two shots, blurred, or not the same moment?)"
        )
        name = used[worst].name
        reports[name] = PairReport(name, False, reason, float(errors[worst]))
        del used[worst]
    for observation, error in zip(used, solution.per_pair_px, strict=True):
        reports[observation.name] = PairReport(
            observation.name, True, error_px=float(error), corners=len(observation.object_m)
        )
    model = solution.model
    rig, _maps, _rotation = rectify_stereo(model)
    dy = _rectified_dy(model, used)
    return StereoCalibration(
        model=model,
        rig=rig,
        rms_px=solution.rms_px,
        left_rms_px=solution.left_rms_px,
        right_rms_px=solution.right_rms_px,
        pairs=[reports[o.name] for o in observations],
        dy_mean_px=float(dy.mean()),
        dy_max_px=float(dy.max()),
    )


def _disagreeing_pairs(
    size: tuple[int, int], pairs: Sequence[PairObservation]
) -> list[tuple[int, str]]:
    """Pairs whose two views give a camera-to-camera pose far from the median of all pairs.

    Each camera is calibrated alone (a mismatched pair is still self-consistent per camera), so
    every pair yields its own estimate of R and T; the median T is robust to up to half the pairs
    being bad, unlike a joint solve that every bad pair pulls.
    """
    objects = [p.object_m for p in pairs]
    _, _, _, left_r, left_t = cv2.calibrateCamera(
        objects, [p.left_px.reshape(-1, 1, 2) for p in pairs], size, None, None
    )
    _, _, _, right_r, right_t = cv2.calibrateCamera(
        objects, [p.right_px.reshape(-1, 1, 2) for p in pairs], size, None, None
    )
    rotations, translations = [], []
    for rl, tl, rr, tr in zip(left_r, left_t, right_r, right_t, strict=True):
        rot_l, _ = cv2.Rodrigues(rl)
        rot_r, _ = cv2.Rodrigues(rr)
        rot = rot_r @ rot_l.T
        rotations.append(rot)
        translations.append(np.ravel(tr) - rot @ np.ravel(tl))
    t_all = np.asarray(translations)
    t_median = np.median(t_all, axis=0)
    spread = np.linalg.norm(t_all - t_median, axis=1) / max(float(np.linalg.norm(t_median)), 1e-6)
    reference = rotations[int(np.argmin(spread))]
    found = []
    for index, rot in enumerate(rotations):
        cos = (np.trace(reference.T @ rot) - 1.0) / 2.0
        angle_deg = float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
        if spread[index] > POSE_SPREAD_BASELINE or angle_deg > POSE_SPREAD_DEG:
            found.append(
                (
                    index,
                    f"its views put the right camera {100 * spread[index]:.0f}% of the baseline "
                    f"and {angle_deg:.1f} deg away from the other pairs' consensus (board moved "
                    "between the two shots, or the images are not a pair?)",
                )
            )
    return found


@dataclass(frozen=True)
class _Solution:
    model: StereoModel
    rms_px: float
    left_rms_px: float
    right_rms_px: float
    per_pair_px: npt.NDArray[np.float64]


def _solve(size: tuple[int, int], pairs: Sequence[PairObservation]) -> _Solution:
    objects = [p.object_m for p in pairs]
    lefts = [p.left_px.reshape(-1, 1, 2) for p in pairs]
    rights = [p.right_px.reshape(-1, 1, 2) for p in pairs]
    left_rms, k1, d1, *_ = cv2.calibrateCamera(objects, lefts, size, None, None)
    right_rms, k2, d2, *_ = cv2.calibrateCamera(objects, rights, size, None, None)
    result = cv2.stereoCalibrateExtended(
        objects,
        lefts,
        rights,
        k1,
        d1,
        k2,
        d2,
        size,
        np.eye(3),
        np.zeros((3, 1)),
        flags=cv2.CALIB_USE_INTRINSIC_GUESS,
        criteria=_CRITERIA,
    )
    rms, k1, d1, k2, d2, rot, trans = result[:7]
    per_view = np.asarray(result[11], np.float64).reshape(len(pairs), 2)
    model = StereoModel(
        width=size[0],
        height=size[1],
        K1=_matrix(k1),
        D1=[float(v) for v in np.ravel(d1)],
        K2=_matrix(k2),
        D2=[float(v) for v in np.ravel(d2)],
        R=_matrix(rot),
        T_m=(float(trans[0, 0]), float(trans[1, 0]), float(trans[2, 0])),
    )
    return _Solution(model, float(rms), float(left_rms), float(right_rms), per_view.max(axis=1))


def _matrix(
    value: npt.ArrayLike,
) -> tuple[tuple[float, float, float], tuple[float, float, float], tuple[float, float, float]]:
    m = np.asarray(value, np.float64).reshape(3, 3)
    rows = [(float(r[0]), float(r[1]), float(r[2])) for r in m]
    return rows[0], rows[1], rows[2]


def _rectified_dy(model: StereoModel, pairs: Sequence[PairObservation]) -> npt.NDArray[np.float64]:
    """|dy| between the two views of every shared corner after rectification."""
    (k1, d1, r1, p1), (k2, d2, r2, p2) = rectification(model)
    left = np.concatenate([p.left_px for p in pairs]).reshape(-1, 1, 2).astype(np.float64)
    right = np.concatenate([p.right_px for p in pairs]).reshape(-1, 1, 2).astype(np.float64)
    left_rect = cv2.undistortPoints(left, k1, d1, R=r1, P=p1).reshape(-1, 2)
    right_rect = cv2.undistortPoints(right, k2, d2, R=r2, P=p2).reshape(-1, 2)
    return np.abs(np.asarray(left_rect[:, 1] - right_rect[:, 1], np.float64))
