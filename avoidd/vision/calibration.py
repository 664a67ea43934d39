"""Calibration files: a full stereo calibration (rectified once at load) or a rectified rig."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import cv2
import numpy as np
import numpy.typing as npt
import yaml
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from avoidd.errors import ConfigError
from avoidd.types import RectifiedRig
from avoidd.yamlfile import load_yaml, validate_document

Matrix3 = tuple[tuple[float, float, float], tuple[float, float, float], tuple[float, float, float]]


class _Strict(BaseModel):
    # NaN and infinity are no calibration value: refused like any other impossible number.
    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)


class RectifiedModel(_Strict):
    """An already-rectified rig (rows aligned, both views share fx, fy and cy).

    Every value must describe a camera that can exist: focal lengths between a tenth and a
    hundred times the image width, the principal point inside the image, and ``doffs`` (the
    right view's principal point minus the left's) within half the width; beyond that, depth
    ``f B / (d + doffs)`` turns negative for ordinary disparities.
    """

    width: int = Field(gt=0, le=16384)
    height: int = Field(gt=0, le=16384)
    fx: float = Field(gt=0.0)
    fy: float = Field(gt=0.0)
    cx: float
    cy: float
    baseline_m: float = Field(gt=0.0, le=10.0)
    doffs: float = 0.0

    @model_validator(mode="after")
    def _physical(self) -> RectifiedModel:
        problems = []
        for name, value in (("fx", self.fx), ("fy", self.fy)):
            if not 0.1 * self.width <= value <= 100.0 * self.width:
                problems.append(
                    f"{name} {value:g} px is not a focal length for a {self.width} px wide "
                    f"image (expected {0.1 * self.width:g} to {100.0 * self.width:g})"
                )
        if not 0.0 <= self.cx <= self.width:
            problems.append(f"cx {self.cx:g} lies outside the image (0 to {self.width})")
        if not 0.0 <= self.cy <= self.height:
            problems.append(f"cy {self.cy:g} lies outside the image (0 to {self.height})")
        if abs(self.doffs) > 0.5 * self.width:
            problems.append(
                f"doffs {self.doffs:g} px is beyond half the image width; it is the right "
                "principal point's column minus the left's (0 for most rectified rigs)"
            )
        if problems:
            raise ValueError("; ".join(problems))
        return self


def _check_camera_matrix(value: Matrix3) -> Matrix3:
    k = np.asarray(value, dtype=np.float64)
    if k[0, 0] <= 0 or k[1, 1] <= 0 or not np.allclose(k[2], (0.0, 0.0, 1.0)):
        raise ValueError("a camera matrix is [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0")
    if k[0, 2] < 0 or k[1, 2] < 0:
        raise ValueError("the principal point (cx, cy) of a camera matrix lies in the image")
    return value


class StereoModel(_Strict):
    """A full stereo calibration as OpenCV's stereoCalibrate returns it.

    ``R`` and ``T_m`` take a point from the left camera frame to the right camera frame
    (``x_right = R @ x_left + T_m``), so a right camera mounted to the right has ``T_m[0] < 0``.
    """

    width: int = Field(gt=0, le=16384)
    height: int = Field(gt=0, le=16384)
    K1: Matrix3
    D1: list[float] = Field(min_length=4, max_length=14)
    K2: Matrix3
    D2: list[float] = Field(min_length=4, max_length=14)
    R: Matrix3
    T_m: tuple[float, float, float]
    alpha: float = Field(0.0, ge=-1.0, le=1.0)

    _camera_matrices = field_validator("K1", "K2")(_check_camera_matrix)

    @field_validator("D1", "D2")
    @classmethod
    def _distortion(cls, value: list[float]) -> list[float]:
        if len(value) not in (4, 5, 8, 12, 14):
            raise ValueError("OpenCV takes 4, 5, 8, 12 or 14 distortion coefficients")
        return value

    @field_validator("R")
    @classmethod
    def _rotation(cls, value: Matrix3) -> Matrix3:
        r = np.asarray(value, dtype=np.float64)
        if not np.allclose(r @ r.T, np.eye(3), atol=1e-3) or abs(np.linalg.det(r) - 1.0) > 1e-3:
            raise ValueError("R is not a rotation matrix (orthonormal, determinant +1)")
        return value

    @field_validator("T_m")
    @classmethod
    def _translation(cls, value: tuple[float, float, float]) -> tuple[float, float, float]:
        norm = float(np.linalg.norm(value))
        if not 0.005 <= norm <= 10.0:
            raise ValueError(f"baseline |T_m| = {norm:.4f} m is implausible; T_m is in metres")
        return value


class CalibrationFile(_Strict):
    """A calibration file: ``version: 1`` and exactly one of ``rectified`` or ``stereo``."""

    version: Literal[1]
    rectified: RectifiedModel | None = None
    stereo: StereoModel | None = None

    @model_validator(mode="after")
    def _exactly_one(self) -> CalibrationFile:
        if (self.rectified is None) == (self.stereo is None):
            raise ValueError("give exactly one of 'rectified' or 'stereo'")
        return self


IntMap = npt.NDArray[np.int16]
FracMap = npt.NDArray[np.uint16]


@dataclass(frozen=True)
class RectifyMaps:
    """OpenCV fixed-point remap tables for both views (computed once, applied per frame)."""

    left: tuple[IntMap, FracMap]
    right: tuple[IntMap, FracMap]


@dataclass(frozen=True)
class Calibration:
    """What the pipeline needs from a calibration file.

    Attributes:
        rig: Intrinsics of the rectified pair.
        maps: Remap tables from raw to rectified images, or None if frames arrive rectified.
        source: The file it was read from.
        rectified_from_raw: Rotation from the raw left camera frame to the rectified one
            (identity when frames arrive rectified); points found in rectified images are
            turned back into the physical camera's frame with its transpose.
    """

    rig: RectifiedRig
    maps: RectifyMaps | None
    source: Path
    rectified_from_raw: npt.NDArray[np.float64] = field(
        default_factory=lambda: np.eye(3, dtype=np.float64)
    )


def write_calibration(
    path: Path, model: RectifiedModel | StereoModel, comments: Sequence[str] = ()
) -> None:
    """Write a calibration file that ``load_calibration`` reads back.

    Args:
        path: Where to write (replaced atomically).
        model: The rig.
        comments: Lines for a ``#`` header (how the calibration was made, its errors).
    """
    key = "rectified" if isinstance(model, RectifiedModel) else "stereo"
    body = {"version": 1, key: model.model_dump(mode="json")}
    header = "".join(f"# {line}\n" for line in comments)
    text = header + yaml.safe_dump(body, sort_keys=False, default_flow_style=None, width=100)
    partial = path.with_name(path.name + ".partial")
    partial.write_text(text, encoding="utf-8")
    partial.replace(path)


def load_calibration(path: Path) -> Calibration:
    """Read a calibration file and compute the rectification once.

    Args:
        path: The calibration YAML file.

    Returns:
        The rectified rig and, for a full stereo calibration, the remap tables.

    Raises:
        ConfigError: The file is invalid or describes an unusable rig.
    """
    doc = load_yaml(path)
    model = validate_document(doc, CalibrationFile, {})
    if model.rectified is not None:
        r = model.rectified
        rig = RectifiedRig(r.width, r.height, r.fx, r.fy, r.cx, r.cy, r.baseline_m, r.doffs)
        return Calibration(rig, None, path)
    assert model.stereo is not None
    try:
        rig, maps, rotation = rectify_stereo(model.stereo)
    except ValueError as exc:
        raise ConfigError([f"{path}: {exc}"]) from exc
    return Calibration(rig, maps, path, rotation)


_F64 = npt.NDArray[np.float64]
CameraRectification = tuple[_F64, _F64, _F64, _F64]


def rectification(stereo: StereoModel) -> tuple[CameraRectification, CameraRectification]:
    """OpenCV's rectification of a stereo calibration (principal points aligned).

    Args:
        stereo: The calibration.

    Returns:
        For the left and the right camera: camera matrix, distortion, rectifying rotation and
        the 3x4 projection matrix of the rectified view.
    """
    k1 = np.asarray(stereo.K1, dtype=np.float64)
    k2 = np.asarray(stereo.K2, dtype=np.float64)
    d1 = np.asarray(stereo.D1, dtype=np.float64)
    d2 = np.asarray(stereo.D2, dtype=np.float64)
    rot = np.asarray(stereo.R, dtype=np.float64)
    trans = np.asarray(stereo.T_m, dtype=np.float64).reshape(3, 1)
    size = (stereo.width, stereo.height)
    r1, r2, p1, p2, _q, _roi1, _roi2 = cv2.stereoRectify(
        k1, d1, k2, d2, size, rot, trans, flags=cv2.CALIB_ZERO_DISPARITY, alpha=stereo.alpha
    )
    return (k1, d1, np.asarray(r1), np.asarray(p1)), (k2, d2, np.asarray(r2), np.asarray(p2))


def rectify_stereo(
    stereo: StereoModel,
) -> tuple[RectifiedRig, RectifyMaps, npt.NDArray[np.float64]]:
    """Compute the rectified rig and remap tables of a full stereo calibration.

    Args:
        stereo: The calibration (OpenCV conventions).

    Returns:
        The rectified intrinsics (principal points aligned, so ``doffs_px`` is 0), the maps and
        the rotation from the raw left camera frame to the rectified left frame.

    Raises:
        ValueError: The rig is vertical or its cameras are swapped.
    """
    size = (stereo.width, stereo.height)
    (k1, d1, r1, p1), (k2, d2, r2, p2) = rectification(stereo)
    if abs(p2[1, 3]) > abs(p2[0, 3]):
        raise ValueError("the cameras are stacked vertically; avoidd needs a horizontal rig")
    baseline_m = -float(p2[0, 3]) / float(p2[0, 0])
    if baseline_m <= 0:
        raise ValueError("the right camera is on the left (T_m[0] > 0); swap left and right")
    rig = RectifiedRig(
        width=stereo.width,
        height=stereo.height,
        fx=float(p1[0, 0]),
        fy=float(p1[1, 1]),
        cx=float(p1[0, 2]),
        cy=float(p1[1, 2]),
        baseline_m=baseline_m,
        doffs_px=float(p2[0, 2] - p1[0, 2]),
    )
    left = cv2.initUndistortRectifyMap(k1, d1, r1, p1, size, cv2.CV_16SC2)
    right = cv2.initUndistortRectifyMap(k2, d2, r2, p2, size, cv2.CV_16SC2)
    maps = RectifyMaps(
        left=(np.asarray(left[0], np.int16), np.asarray(left[1], np.uint16)),
        right=(np.asarray(right[0], np.int16), np.asarray(right[1], np.uint16)),
    )
    return rig, maps, np.asarray(r1, dtype=np.float64)
