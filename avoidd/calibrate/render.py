"""Render a calibration board through a known virtual stereo rig with lens distortion.

This gives calibration a ground truth: images whose rig is known exactly, so a round trip through
``avoidd calibrate`` can be checked against it. Each pixel's ray is found by undistorting its
(supersampled) position once per camera; a board pose then only needs a ray-plane intersection and
a bilinear lookup in the board image.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import numpy.typing as npt

from avoidd.calibrate.board import Board
from avoidd.types import Image

Vector = npt.NDArray[np.float64]

_SUPERSAMPLE = 3
_BOARD_PX_PER_SQUARE = 64
_BACKGROUND = 110


@dataclass(frozen=True)
class VirtualCamera:
    """A pinhole camera with OpenCV radial-tangential distortion.

    ``rotation`` and ``translation_m`` take a point from the left camera frame into this camera's
    frame (identity and zero for the left camera itself).
    """

    width: int
    height: int
    k: Vector
    d: Vector
    rotation: Vector = field(default_factory=lambda: np.eye(3))
    translation_m: Vector = field(default_factory=lambda: np.zeros(3))


@dataclass(frozen=True)
class VirtualRig:
    """Two virtual cameras; ``right.rotation``/``right.translation_m`` are OpenCV's R and T."""

    left: VirtualCamera
    right: VirtualCamera

    @property
    def baseline_m(self) -> float:
        """Distance between the two optical centres."""
        return float(np.linalg.norm(self.right.translation_m))


def default_rig(width: int = 640, height: int = 480) -> VirtualRig:
    """A plausible small drone rig: 12 cm baseline, barrel distortion, slightly misaligned."""
    fx = 0.66 * width

    def k(cx_off: float, cy_off: float, f_scale: float) -> Vector:
        return np.array(
            [
                [fx * f_scale, 0.0, (width - 1) / 2 + cx_off],
                [0.0, fx * f_scale * 1.002, (height - 1) / 2 + cy_off],
                [0.0, 0.0, 1.0],
            ]
        )

    rotation, _ = cv2.Rodrigues(np.radians([0.6, -1.2, 0.4]))
    left_d = np.array([-0.24, 0.07, 4e-4, -3e-4, 0.0])
    left = VirtualCamera(width, height, k(3.0, -2.0, 1.0), left_d)
    right = VirtualCamera(
        width,
        height,
        k(-4.0, 2.5, 1.01),
        np.array([-0.23, 0.065, -2e-4, 5e-4, 0.0]),
        np.asarray(rotation, np.float64),
        np.array([-0.12, 0.002, -0.001]),
    )
    return VirtualRig(left, right)


class BoardRenderer:
    """Renders one board through the cameras of one rig.

    Args:
        board: The board to draw.
        rig: The virtual rig.
    """

    def __init__(self, board: Board, rig: VirtualRig) -> None:
        self.board = board
        self.rig = rig
        margin = _BOARD_PX_PER_SQUARE  # one square of white quiet zone around the pattern
        pattern = board.image(_BOARD_PX_PER_SQUARE)
        self._texture = cv2.copyMakeBorder(
            pattern, margin, margin, margin, margin, cv2.BORDER_CONSTANT, value=255
        )
        self._margin_px = margin
        self._rays = {id(cam): _pixel_rays(cam) for cam in (rig.left, rig.right)}

    def render(
        self, camera: VirtualCamera, rvec: Vector, tvec_m: Vector, rng: np.random.Generator
    ) -> Image:
        """Draw the board at a pose as one camera sees it.

        Args:
            camera: ``rig.left`` or ``rig.right``.
            rvec: Board-to-left-camera rotation (Rodrigues vector).
            tvec_m: Board origin in the left camera frame, metres.
            rng: Noise source (sensor noise of about one grey level).

        Returns:
            An 8-bit grey image of the camera's size.
        """
        board_rot, _ = cv2.Rodrigues(np.asarray(rvec, np.float64))
        rot = camera.rotation @ board_rot
        trans = camera.rotation @ np.asarray(tvec_m, np.float64) + camera.translation_m
        centre_b = -rot.T @ trans
        rays = self._rays[id(camera)] @ rot  # each row is rot.T @ ray: the ray in board frame
        with np.errstate(divide="ignore", invalid="ignore"):
            scale = -centre_b[2] / rays[:, 2]
        hit_x = centre_b[0] + scale * rays[:, 0]
        hit_y = centre_b[1] + scale * rays[:, 1]
        px_per_m = _BOARD_PX_PER_SQUARE / self.board.square_m
        map_x = (hit_x * px_per_m + self._margin_px - 0.5).astype(np.float32)
        map_y = (hit_y * px_per_m + self._margin_px - 0.5).astype(np.float32)
        behind = ~(scale > 0)
        map_x[behind] = -1e6
        shape = (camera.height * _SUPERSAMPLE, camera.width * _SUPERSAMPLE)
        big = cv2.remap(
            self._texture,
            map_x.reshape(shape),
            map_y.reshape(shape),
            cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=_BACKGROUND,
        )
        small = cv2.resize(big, (camera.width, camera.height), interpolation=cv2.INTER_AREA)
        noise = rng.normal(0.0, 1.0, small.shape)
        return np.asarray(np.clip(small + noise, 0, 255), np.uint8)

    def corners_px(self, camera: VirtualCamera, rvec: Vector, tvec_m: Vector) -> Vector:
        """Exact image positions of the board's inner corners in one camera."""
        board_rot, _ = cv2.Rodrigues(np.asarray(rvec, np.float64))
        rot = camera.rotation @ board_rot
        trans = camera.rotation @ np.asarray(tvec_m, np.float64) + camera.translation_m
        rvec_cam, _ = cv2.Rodrigues(rot)
        points, _ = cv2.projectPoints(
            self.board.object_points().astype(np.float64), rvec_cam, trans, camera.k, camera.d
        )
        return np.asarray(points, np.float64).reshape(-1, 2)


def _pixel_rays(camera: VirtualCamera) -> Vector:
    """Undistorted normalised rays (x, y, 1) of every supersampled pixel, row-major."""
    step = 1.0 / _SUPERSAMPLE
    offsets = np.arange(_SUPERSAMPLE) * step - 0.5 + step / 2
    xs = (np.arange(camera.width)[:, None] + offsets[None, :]).ravel()
    ys = (np.arange(camera.height)[:, None] + offsets[None, :]).ravel()
    grid = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 1, 2)
    criteria = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 40, 1e-6)
    normalised = cv2.undistortPoints(grid, camera.k, camera.d, None, None, criteria=criteria)
    rays = np.ones((grid.shape[0], 3), np.float64)
    rays[:, :2] = np.asarray(normalised, np.float64).reshape(-1, 2)
    return rays


def sample_poses(
    renderer: BoardRenderer, count: int, rng: np.random.Generator, max_tries: int = 2000
) -> list[tuple[Vector, Vector]]:
    """Board poses that keep the whole board inside both images, spread over the view.

    Args:
        renderer: Supplies the board and the rig.
        count: Poses wanted.
        rng: Random source (seed it for repeatable tests).
        max_tries: Give up after this many candidates.

    Returns:
        ``count`` (rvec, tvec_m) pairs, board frame to left camera frame.

    Raises:
        RuntimeError: Not enough poses fit (the board is too large for the rig).
    """
    rig = renderer.rig
    width_m, height_m = renderer.board.size_m
    fx = float(rig.left.k[0, 0])
    # A distance at which the board spans about half the image width.
    base_m = fx * width_m / (0.5 * rig.left.width)
    poses: list[tuple[Vector, Vector]] = []
    margin = 12.0
    for _ in range(max_tries):
        tilt = np.radians(rng.uniform([-30, -30, -15], [30, 30, 15]))
        rotation, _ = cv2.Rodrigues(tilt)
        distance_m = base_m * rng.uniform(0.8, 1.6)
        centre = np.array(
            [
                rng.uniform(-0.35, 0.35) * distance_m * rig.left.width / fx,
                rng.uniform(-0.3, 0.3) * distance_m * rig.left.height / fx,
                distance_m,
            ]
        )
        tvec = centre - rotation @ np.array([width_m / 2, height_m / 2, 0.0])
        rvec = np.asarray(cv2.Rodrigues(rotation)[0], np.float64).ravel()
        inside = True
        for cam in (rig.left, rig.right):
            px = renderer.corners_px(cam, rvec, tvec)
            if not (
                (px[:, 0] > margin).all()
                and (px[:, 0] < cam.width - margin).all()
                and (px[:, 1] > margin).all()
                and (px[:, 1] < cam.height - margin).all()
            ):
                inside = False
        if inside:
            poses.append((rvec, tvec))
            if len(poses) == count:
                return poses
    raise RuntimeError(f"only {len(poses)} of {count} board poses fit inside both images")


def write_pairs(
    folder: Path, board: Board, rig: VirtualRig, count: int, seed: int = 0
) -> list[tuple[Vector, Vector]]:
    """Render ``count`` pairs into ``folder/left`` and ``folder/right`` as PNG.

    Returns:
        The board poses used, in file order.
    """
    renderer = BoardRenderer(board, rig)
    rng = np.random.default_rng(seed)
    poses = sample_poses(renderer, count, rng)
    for side in ("left", "right"):
        (folder / side).mkdir(parents=True, exist_ok=True)
    for index, (rvec, tvec) in enumerate(poses):
        name = f"{index:03d}.png"
        cv2.imwrite(str(folder / "left" / name), renderer.render(rig.left, rvec, tvec, rng))
        cv2.imwrite(str(folder / "right" / name), renderer.render(rig.right, rvec, tvec, rng))
    return poses
