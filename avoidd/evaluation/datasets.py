"""Readers for stereo datasets with ground-truth disparity.

Layouts recognised in a scene folder (:data:`LAYOUTS` lists them for error messages):

- Middlebury 2014 (MiddEval3): ``im0.png``, ``im1.png``, ``disp0GT.pfm`` (+inf unknown),
  ``calib.txt`` (f, baseline in mm, doffs, ndisp), optional ``mask0nocc.png``.
- Middlebury 2005/2006: ``view1.png`` (left), ``view5.png`` (right), ``disp1.png``: disparity
  times the size factor (1 full size, 2 half, 3 third; told apart by the image height, 1110,
  555 or 370 rows), 0 unknown; ``dmin.txt``, when present, an offset added to every known
  disparity.
- Middlebury 2003: ``im2.png``/``im6.png`` or ``imL.png``/``imR.png`` and ``disp2.png``
  (value / 4, 0 unknown).
- Middlebury 2001: ``im2.*`` (left), ``im6.*`` (right), ``disp2.pgm`` (value / 8); Tsukuba
  ``imL.png``, ``imR.png``, ``truedisp.pgm`` (value / 16); 0 unknown.
- KITTI 2012/2015 (a folder with ``image_2/`` and ``image_3/``, or ``image_0/`` and
  ``image_1/``, and a ground-truth folder): one scene per frame, 16-bit PNG disparity / 256,
  0 unknown. Non-occluded truth (``disp_noc_0/``, ``disp_noc/``) is preferred over
  ``disp_occ_0/``/``disp_occ/``.

The search range of a scene never comes from its ground truth: it is ``--num-disparities``
when given, else the dataset's stated ``ndisp`` (Middlebury 2014 ``calib.txt``), else the
largest disparity the ground-truth encoding can hold (255 / factor, plus ``dmin``), else 192
for KITTI; always rounded up to a multiple of 16.
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

KITTI_NUM_DISPARITIES = 192
"""KITTI's search range: its 16-bit encoding holds far more than any road scene needs."""

KITTI_TRUTH_DIRS = ("disp_noc_0", "disp_noc", "disp_occ_0", "disp_occ")
"""KITTI ground-truth folders, the one used first: non-occluded truth before all pixels."""

KITTI_IMAGE_DIRS = (("image_2", "image_3"), ("image_0", "image_1"))
"""KITTI left and right image folders: 2015 (colour), then 2012 (grey)."""

MIDDLEBURY_2005_FULL_HEIGHT_PX = 1110
"""Rows of a full-size Middlebury 2005/2006 image (half size 555, third size 370)."""

LAYOUTS: tuple[tuple[str, str], ...] = (
    ("Middlebury 2014", "im0.png, im1.png, disp0GT.pfm, calib.txt"),
    ("Middlebury 2005/2006", "view1.png, view5.png, disp1.png (dmin.txt optional)"),
    ("Middlebury 2003", "im2.png, im6.png, disp2.png (or imL.png, imR.png, disp2.png)"),
    ("Middlebury 2001", "im2.*, im6.*, disp2.pgm (Tsukuba: imL.png, imR.png, truedisp.pgm)"),
    (
        "KITTI 2012/2015",
        "image_2/ and image_3/ (or image_0/ and image_1/) with one of "
        + ", ".join(f"{d}/" for d in KITTI_TRUTH_DIRS)
        + ", files named alike",
    ),
)
"""Every layout :func:`find_scenes` recognises and the files each needs."""


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
        num_disparities: Search range to use, a multiple of 16 (never read off the truth).
        calib: Depth calibration, when the dataset publishes one.
        layout: The layout it was read as, one of the names in :data:`LAYOUTS`.
    """

    name: str
    left: Image
    right: Image
    truth_px: FloatArray
    num_disparities: int
    calib: Calib | None = None
    layout: str = ""


def round_up_16(num_disparities: float) -> int:
    """A search range OpenCV accepts: at least 16, rounded up to a multiple of 16."""
    return max(16, math.ceil(num_disparities / 16) * 16)


def no_scene_lines(path: Path, max_depth: int = 2) -> list[str]:
    """The message for a folder that holds no recognised layout: each layout and its files."""
    return [
        f"{path}: no stereo scene with ground truth found in it or up to {max_depth} folder "
        "levels below; a scene folder needs the files of one of these layouts:",
        *(f"  {name}: {files}" for name, files in LAYOUTS),
    ]


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


def _read_scaled(path: Path, divisor: float, offset_px: float = 0.0) -> FloatArray:
    """Integer-coded disparity: value / divisor + offset_px, NaN where the value is 0."""
    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if raw is None:
        raise ConfigError([f"{path}: cannot read the ground truth"])
    if raw.ndim == 3:
        raw = raw[:, :, 0]
    truth = raw.astype(np.float32) / np.float32(divisor) + np.float32(offset_px)
    truth[raw == 0] = np.nan
    return truth


def _encoding_range(divisor: float, offset_px: float = 0.0) -> float:
    """The largest disparity an 8-bit ground truth coded as value / divisor + offset holds."""
    return 255.0 / divisor + offset_px


def _calib_txt(path: Path) -> tuple[Calib, int]:
    calib = read_middlebury(path)
    return Calib(float(calib.cam0[0, 0]), calib.baseline_m, calib.doffs_px), calib.ndisp


def _first(folder: Path, stem: str) -> Path | None:
    for suffix in (".png", ".ppm", ".pgm", ".jpg"):
        candidate = folder / f"{stem}{suffix}"
        if candidate.is_file():
            return candidate
    return None


def middlebury_2005_factor(height_px: int) -> int:
    """The factor a Middlebury 2005/2006 ``disp1.png`` is multiplied by, from the image rows.

    Full size (1110 rows) stores the disparity itself, half size (555) twice it, third size
    (370) three times it; anything nearer one size than the next counts as that size.
    """
    ratio = MIDDLEBURY_2005_FULL_HEIGHT_PX / max(height_px, 1)
    return 1 if ratio < 1.5 else 2 if ratio < 2.5 else 3


def _dmin(folder: Path) -> float:
    path = folder / "dmin.txt"
    if not path.is_file():
        return 0.0
    try:
        return float(path.read_text(encoding="utf-8").split()[0])
    except (IndexError, ValueError) as exc:
        raise ConfigError([f"{path}: expected one number (the disparity offset)"]) from exc


def _middlebury_2005(folder: Path, name: str, num_disparities: int | None) -> Scene:
    left = _read_image(folder / "view1.png")
    factor = middlebury_2005_factor(left.shape[0])
    offset_px = _dmin(folder)
    truth = _read_scaled(folder / "disp1.png", factor, offset_px)
    stated = num_disparities or _encoding_range(factor, offset_px)
    return Scene(
        name,
        left,
        _read_image(folder / "view5.png"),
        truth,
        round_up_16(stated),
        layout="Middlebury 2005/2006",
    )


def load_scene(
    folder: Path, name: str | None = None, num_disparities: int | None = None
) -> Scene | None:
    """Load one scene folder, or return None if it is in no known layout.

    Args:
        folder: The scene folder.
        name: The scene's name (default ``parent/folder``).
        num_disparities: Search range for the scene (rounded up to 16); default: the dataset's
            stated range, else what its ground-truth encoding can hold (see the module).
    """
    name = name or f"{folder.parent.name}/{folder.name}"

    def scene(left: Path, right: Path, truth: FloatArray, default: float, layout: str) -> Scene:
        return Scene(
            name,
            _read_image(left),
            _read_image(right),
            truth,
            round_up_16(num_disparities or default),
            layout=layout,
        )

    if (folder / "disp0GT.pfm").is_file() and (folder / "im0.png").is_file():
        truth = read_pfm(folder / "disp0GT.pfm")
        calib, ndisp = _calib_txt(folder / "calib.txt")
        return Scene(
            name,
            _read_image(folder / "im0.png"),
            _read_image(folder / "im1.png"),
            truth,
            round_up_16(num_disparities or ndisp),
            calib,
            layout="Middlebury 2014",
        )
    if all((folder / f).is_file() for f in ("view1.png", "view5.png", "disp1.png")):
        return _middlebury_2005(folder, name, num_disparities)
    im_l, im_r = folder / "imL.png", folder / "imR.png"
    if im_l.is_file() and im_r.is_file():
        if (folder / "truedisp.pgm").is_file():
            truth = _read_scaled(folder / "truedisp.pgm", 16.0)
            return scene(im_l, im_r, truth, _encoding_range(16.0), "Middlebury 2001")
        if (folder / "disp2.png").is_file():
            truth = _read_scaled(folder / "disp2.png", 4.0)
            return scene(im_l, im_r, truth, _encoding_range(4.0), "Middlebury 2003")
    left_path, right_path = _first(folder, "im2"), _first(folder, "im6")
    if left_path is not None and right_path is not None:
        if (folder / "disp2.pgm").is_file():
            truth = _read_scaled(folder / "disp2.pgm", 8.0)
            return scene(left_path, right_path, truth, _encoding_range(8.0), "Middlebury 2001")
        if (folder / "disp2.png").is_file():
            truth = _read_scaled(folder / "disp2.png", 4.0)
            return scene(left_path, right_path, truth, _encoding_range(4.0), "Middlebury 2003")
    return None


def _kitti_layout(folder: Path) -> tuple[Path, Path, Path] | None:
    """KITTI's left, right and ground-truth folders under ``folder``, or None."""
    truth = next((folder / d for d in KITTI_TRUTH_DIRS if (folder / d).is_dir()), None)
    images = next(
        ((folder / a, folder / b) for a, b in KITTI_IMAGE_DIRS if (folder / a).is_dir()), None
    )
    if truth is None or images is None or not images[1].is_dir():
        return None
    return images[0], images[1], truth


def _kitti(folder: Path, num_disparities: int | None) -> Iterator[Scene]:
    layout = _kitti_layout(folder)
    if layout is None:
        return
    left_dir, right_dir, truth_dir = layout
    for truth_path in sorted(truth_dir.glob("*.png")):
        left, right = left_dir / truth_path.name, right_dir / truth_path.name
        if left.is_file() and right.is_file():
            yield Scene(
                f"{folder.name}/{truth_path.stem}",
                _read_image(left),
                _read_image(right),
                _read_scaled(truth_path, 256.0),
                round_up_16(num_disparities or KITTI_NUM_DISPARITIES),
                layout="KITTI 2012/2015",
            )


def find_scenes(
    path: Path, max_depth: int = 2, num_disparities: int | None = None
) -> Iterator[Scene]:
    """Every scene at ``path`` or in folders below it (up to ``max_depth`` levels), sorted.

    Args:
        path: A scene folder, a dataset folder, or a folder of them.
        max_depth: Folder levels to look below ``path``.
        num_disparities: Search range for every scene (see :func:`load_scene`).

    Raises:
        ConfigError: ``path`` does not exist.
    """
    if not path.exists():
        raise ConfigError([f"{path}: not found; give a scene folder or a dataset folder"])
    if _kitti_layout(path) is not None:
        yield from _kitti(path, num_disparities)
        return
    scene = load_scene(path, num_disparities=num_disparities)
    if scene is not None:
        yield scene
        return
    if max_depth > 0 and path.is_dir():
        for child in sorted(p for p in path.iterdir() if p.is_dir()):
            yield from find_scenes(child, max_depth - 1, num_disparities)
