"""Readers for stereo datasets with ground-truth disparity.

Layouts recognised in a scene folder:

- Middlebury 2014 (MiddEval3): ``im0.png``, ``im1.png``, ``disp0GT.pfm`` (+inf unknown),
  ``calib.txt`` (f, baseline in mm, doffs, ndisp), optional ``mask0nocc.png``.
- Middlebury 2001 Tsukuba: ``imL.png``, ``imR.png``, ``truedisp.pgm`` (value / 16, 0 unknown).
- Middlebury 2001/2003: ``im2.*`` (left), ``im6.*`` (right), ``disp2.pgm`` (value / 8) or
  ``disp2.png`` (value / 4), 0 unknown.
- KITTI 2012/2015 (a folder with ``image_2/``, ``image_3/``, ``disp_occ_0/``): one scene per
  frame, 16-bit PNG disparity / 256, 0 unknown.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from avoidd.calibrate.importers import read_middlebury
from avoidd.errors import ConfigError
from avoidd.types import FloatArray, Image


@dataclass(frozen=True)
class Calib:
    """What turns disparity into depth for a scene: Z = f * B / (d + doffs)."""

    focal_px: float
    baseline_m: float
    doffs_px: float = 0.0


@dataclass(frozen=True)
class Scene:
    """One stereo pair with ground truth.

    Attributes:
        name: ``dataset/scene`` (or ``dataset/frame`` for KITTI).
        left: Left view, (H, W, 3) BGR or (H, W) grey uint8.
        right: Right view, same shape.
        truth_px: Ground-truth disparity of the left view, float32, NaN where unknown.
        num_disparities: Search range to use, a multiple of 16 covering the scene.
        calib: Depth calibration, when the dataset publishes one.
    """

    name: str
    left: Image
    right: Image
    truth_px: FloatArray
    num_disparities: int
    calib: Calib | None = None


def read_pfm(path: Path) -> FloatArray:
    """Read a single-channel PFM (rows stored bottom to top); infinities become NaN."""
    data = path.read_bytes()
    header, dims, scale, payload = data.split(b"\n", 3)
    if header.strip() != b"Pf":
        raise ConfigError([f"{path}: not a single-channel PFM (header {header[:4]!r})"])
    width, height = (int(v) for v in dims.split())
    order = "<" if float(scale) < 0 else ">"
    values = np.frombuffer(payload, dtype=f"{order}f4", count=width * height)
    image = values.reshape(height, width)[::-1].astype(np.float32)
    image[~np.isfinite(image)] = np.nan
    return image


def _read_image(path: Path) -> Image:
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise ConfigError([f"{path}: cannot read the image; is it a PNG/PPM/JPEG?"])
    return np.asarray(image, dtype=np.uint8)


def _read_scaled(path: Path, divisor: float) -> FloatArray:
    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if raw is None:
        raise ConfigError([f"{path}: cannot read the ground truth"])
    if raw.ndim == 3:
        raw = raw[:, :, 0]
    truth = raw.astype(np.float32) / np.float32(divisor)
    truth[raw == 0] = np.nan
    return truth


def _range_for(truth: FloatArray, stated: int | None = None) -> int:
    """A search range that covers the scene, rounded up to a multiple of 16."""
    needed = stated if stated is not None else math.ceil(float(np.nanmax(truth)) * 1.1) + 1
    return max(16, math.ceil(needed / 16) * 16)


def _calib_txt(path: Path) -> tuple[Calib, int]:
    calib = read_middlebury(path)
    return Calib(float(calib.cam0[0, 0]), calib.baseline_m, calib.doffs_px), calib.ndisp


def _first(folder: Path, stem: str) -> Path | None:
    for suffix in (".png", ".ppm", ".pgm", ".jpg"):
        candidate = folder / f"{stem}{suffix}"
        if candidate.is_file():
            return candidate
    return None


def load_scene(folder: Path, name: str | None = None) -> Scene | None:
    """Load one scene folder, or return None if it is in no known layout."""
    name = name or f"{folder.parent.name}/{folder.name}"
    if (folder / "disp0GT.pfm").is_file() and (folder / "im0.png").is_file():
        truth = read_pfm(folder / "disp0GT.pfm")
        calib, ndisp = _calib_txt(folder / "calib.txt")
        return Scene(
            name,
            _read_image(folder / "im0.png"),
            _read_image(folder / "im1.png"),
            truth,
            _range_for(truth, ndisp),
            calib,
        )
    if (folder / "truedisp.pgm").is_file() and (folder / "imL.png").is_file():
        truth = _read_scaled(folder / "truedisp.pgm", 16.0)
        left, right = _read_image(folder / "imL.png"), _read_image(folder / "imR.png")
        return Scene(name, left, right, truth, _range_for(truth))
    left_path, right_path = _first(folder, "im2"), _first(folder, "im6")
    if left_path is not None and right_path is not None:
        if (folder / "disp2.pgm").is_file():
            truth = _read_scaled(folder / "disp2.pgm", 8.0)
        elif (folder / "disp2.png").is_file():
            truth = _read_scaled(folder / "disp2.png", 4.0)
        else:
            return None
        return Scene(
            name, _read_image(left_path), _read_image(right_path), truth, _range_for(truth)
        )
    return None


def _kitti(folder: Path) -> Iterator[Scene]:
    for truth_path in sorted((folder / "disp_occ_0").glob("*.png")):
        left = folder / "image_2" / truth_path.name
        right = folder / "image_3" / truth_path.name
        if left.is_file() and right.is_file():
            truth = _read_scaled(truth_path, 256.0)
            yield Scene(
                f"{folder.name}/{truth_path.stem}",
                _read_image(left),
                _read_image(right),
                truth,
                _range_for(truth, 192),
            )


def find_scenes(path: Path, max_depth: int = 2) -> Iterator[Scene]:
    """Every scene at ``path`` or in folders below it (up to ``max_depth`` levels), sorted.

    Raises:
        ConfigError: ``path`` does not exist.
    """
    if not path.exists():
        raise ConfigError([f"{path}: not found; give a scene folder or a dataset folder"])
    if (path / "disp_occ_0").is_dir():
        yield from _kitti(path)
        return
    scene = load_scene(path)
    if scene is not None:
        yield scene
        return
    if max_depth > 0 and path.is_dir():
        for child in sorted(p for p in path.iterdir() if p.is_dir()):
            yield from find_scenes(child, max_depth - 1)
