"""Import dataset calibrations: EuRoC ``sensor.yaml`` and Middlebury ``calib.txt``."""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from avoidd.errors import ConfigError
from avoidd.fileread import UnreadableFile, read_bounded
from avoidd.vision.calibration import RectifiedModel, StereoModel
from avoidd.yamlfile import load_yaml


@dataclass(frozen=True)
class MiddleburyCalib:
    """The fields of a Middlebury 2014 ``calib.txt`` (depth Z = baseline * f / (d + doffs))."""

    cam0: npt.NDArray[np.float64]
    doffs_px: float
    baseline_m: float
    ndisp: int
    cam1: npt.NDArray[np.float64] | None = None
    width: int | None = None
    height: int | None = None


def _matrix_text(text: str) -> npt.NDArray[np.float64]:
    rows = [row.split() for row in text.strip(" []").split(";")]
    matrix = np.asarray(rows, dtype=np.float64)
    if matrix.shape != (3, 3):
        raise ValueError(f"expected a 3x3 matrix, got shape {matrix.shape}")
    return matrix


def read_middlebury(path: Path) -> MiddleburyCalib:
    """Read a Middlebury ``calib.txt``.

    Raises:
        ConfigError: The file is missing a field or a value does not parse.
    """
    try:
        text = read_bounded(path, 64_000).decode("utf-8", "replace")
    except OSError as exc:
        raise ConfigError([f"{path}: cannot read ({exc.strerror})"]) from exc
    except UnreadableFile as exc:
        raise ConfigError([f"{path}: {exc.reason}; give a Middlebury calib.txt"]) from None
    values: dict[str, str] = dict(re.findall(r"(\w+)\s*=\s*([^\n]+)", text))
    try:
        return MiddleburyCalib(
            cam0=_matrix_text(values["cam0"]),
            doffs_px=float(values.get("doffs", "0")),
            baseline_m=float(values["baseline"]) / 1000.0,
            ndisp=int(values["ndisp"]),
            cam1=_matrix_text(values["cam1"]) if "cam1" in values else None,
            width=int(values["width"]) if "width" in values else None,
            height=int(values["height"]) if "height" in values else None,
        )
    except KeyError as exc:
        raise ConfigError([f"{path}: not a Middlebury calib.txt (no {exc.args[0]}=)"]) from exc
    except ValueError as exc:
        raise ConfigError([f"{path}: not a Middlebury calib.txt ({exc})"]) from exc


def middlebury_rectified(path: Path) -> RectifiedModel:
    """A Middlebury ``calib.txt`` as a rectified rig (its images are rectified already).

    Raises:
        ConfigError: The file is invalid or its two cameras are not row-aligned.
    """
    calib = read_middlebury(path)
    missing = [
        name
        for name, value in (("cam1", calib.cam1), ("width", calib.width), ("height", calib.height))
        if value is None
    ]
    if missing:
        raise ConfigError([f"{path}: needs {', '.join(missing)}= to describe a rig"])
    assert calib.cam1 is not None and calib.width is not None and calib.height is not None
    k0, k1 = calib.cam0, calib.cam1
    if abs(k0[0, 0] - k1[0, 0]) > 1e-6 * k0[0, 0] or abs(k0[1, 2] - k1[1, 2]) > 1e-3:
        raise ConfigError([f"{path}: cam0 and cam1 differ in focal length or cy; not rectified"])
    doffs_px = float(k1[0, 2] - k0[0, 2])
    if abs(doffs_px - calib.doffs_px) > 1e-2:
        raise ConfigError(
            [f"{path}: doffs={calib.doffs_px} but cam1 cx - cam0 cx = {doffs_px:.3f}; fix one"]
        )
    return RectifiedModel(
        width=calib.width,
        height=calib.height,
        fx=float(k0[0, 0]),
        fy=float(k0[1, 1]),
        cx=float(k0[0, 2]),
        cy=float(k0[1, 2]),
        baseline_m=calib.baseline_m,
        doffs=doffs_px,
    )


@dataclass(frozen=True)
class _EurocCamera:
    size: tuple[int, int]
    k: npt.NDArray[np.float64]
    d: list[float]
    body_from_sensor: npt.NDArray[np.float64]


def _read_euroc(path: Path) -> _EurocCamera:
    # OpenCV writes a "%YAML:1.0" directive that YAML parsers reject; it carries nothing (the
    # line stays, empty, so that errors name the right line). The bounded loader refuses huge,
    # non-UTF-8 or alias-bomb files as it does configurations.
    doc = load_yaml(path, lambda text: re.sub(r"^%YAML:[^\n]*", "", text)).data
    try:
        model = doc["camera_model"]
        distortion = doc["distortion_model"]
        fu, fv, cu, cv = (float(v) for v in doc["intrinsics"])
        coefficients = [float(v) for v in doc["distortion_coefficients"]]
        width, height = (int(v) for v in doc["resolution"])
        transform = np.asarray(doc["T_BS"]["data"], dtype=np.float64).reshape(4, 4)
    except (KeyError, TypeError, ValueError) as exc:
        raise ConfigError([f"{path}: not a EuRoC camera sensor.yaml ({exc})"]) from exc
    if model != "pinhole" or distortion != "radial-tangential" or len(coefficients) != 4:
        raise ConfigError(
            [
                f"{path}: {model} camera with {distortion} distortion; only pinhole with "
                "radial-tangential (k1, k2, p1, p2) can be imported, calibrate the rig with "
                "'avoidd calibrate' instead"
            ]
        )
    k = np.array([[fu, 0.0, cu], [0.0, fv, cv], [0.0, 0.0, 1.0]])
    return _EurocCamera((width, height), k, coefficients, transform)


def euroc_stereo(left: Path, right: Path) -> StereoModel:
    """Two EuRoC ``sensor.yaml`` files (left camera first) as a stereo calibration.

    ``T_BS`` maps sensor to body coordinates, so a left-camera point reaches the right camera
    through ``inv(T_BS_right) @ T_BS_left``.

    Raises:
        ConfigError: A file is invalid, the sizes differ, or the rig is implausible.
    """
    cam_l, cam_r = _read_euroc(left), _read_euroc(right)
    if cam_l.size != cam_r.size:
        raise ConfigError([f"{left}, {right}: resolutions {cam_l.size} and {cam_r.size} differ"])
    right_from_left = np.linalg.inv(cam_r.body_from_sensor) @ cam_l.body_from_sensor
    rot = right_from_left[:3, :3]
    trans = right_from_left[:3, 3]
    # The published rotations are orthonormal only to about 1e-4; snap to the nearest rotation.
    u, _s, vt = np.linalg.svd(rot)
    rot = u @ vt

    def rows(
        m: npt.NDArray[np.float64],
    ) -> tuple[tuple[float, float, float], tuple[float, float, float], tuple[float, float, float]]:
        r = [(float(a), float(b), float(c)) for a, b, c in m]
        return r[0], r[1], r[2]

    try:
        return StereoModel(
            width=cam_l.size[0],
            height=cam_l.size[1],
            K1=rows(cam_l.k),
            D1=cam_l.d,
            K2=rows(cam_r.k),
            D2=cam_r.d,
            R=rows(rot),
            T_m=(float(trans[0]), float(trans[1]), float(trans[2])),
        )
    except ValueError as exc:
        raise ConfigError([f"{left}, {right}: not a usable stereo rig ({exc})"]) from exc
