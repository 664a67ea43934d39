"""Calibration boards: chessboard and ChArUco, their geometry, detection and a printable image."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np
import numpy.typing as npt

from avoidd.types import Image

Points = npt.NDArray[np.float32]

# Subpixel refinement stops after 40 iterations or a 0.001 px step.
_SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 40, 0.001)
# ChArUco corners shared by both views of a pair below this count give no stable pose.
MIN_CHARUCO_CORNERS = 8


@dataclass(frozen=True)
class Board:
    """A calibration board.

    Attributes:
        pattern: ``chessboard`` or ``charuco``.
        squares_x: Squares across (a chessboard of 10x7 squares has 9x6 inner corners).
        squares_y: Squares down.
        square_m: Side of one square, metres.
        marker_m: Side of an ArUco marker (ChArUco only), metres.
        dictionary: OpenCV ArUco dictionary name (ChArUco only).
    """

    pattern: Literal["chessboard", "charuco"]
    squares_x: int
    squares_y: int
    square_m: float
    marker_m: float = 0.0
    dictionary: str = "DICT_4X4_50"

    def __post_init__(self) -> None:
        if self.squares_x < 3 or self.squares_y < 3:
            raise ValueError("a board needs at least 3x3 squares")
        if not 0.001 <= self.square_m <= 1.0:
            raise ValueError(f"square size {self.square_m} m is implausible; give it in metres")
        if self.pattern == "chessboard" and self.squares_x % 2 == self.squares_y % 2:
            raise ValueError(
                "a chessboard needs one odd and one even side (e.g. 10x7 squares), "
                "or its orientation is ambiguous"
            )
        if self.pattern == "charuco":
            if not 0.0 < self.marker_m < self.square_m:
                raise ValueError("a ChArUco marker must be smaller than its square")
            if not hasattr(cv2.aruco, self.dictionary):
                raise ValueError(f"unknown ArUco dictionary {self.dictionary!r}")

    @property
    def inner_corners(self) -> tuple[int, int]:
        """Inner corners across and down."""
        return self.squares_x - 1, self.squares_y - 1

    @property
    def size_m(self) -> tuple[float, float]:
        """Width and height of the squared area, metres."""
        return self.squares_x * self.square_m, self.squares_y * self.square_m

    def object_points(self) -> Points:
        """Every inner corner on the board plane (z = 0), metres, row by row; index = id."""
        cols, rows = self.inner_corners
        grid = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2).astype(np.float32)
        points = np.zeros((cols * rows, 3), np.float32)
        points[:, :2] = (grid + 1.0) * self.square_m
        return points

    def charuco(self) -> cv2.aruco.CharucoBoard:
        """The OpenCV ChArUco board object."""
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard(
            (self.squares_x, self.squares_y), self.square_m, self.marker_m, dictionary
        )

    def image(self, px_per_square: int) -> Image:
        """The board as a grey image, one square ``px_per_square`` wide, no margin."""
        width, height = self.squares_x * px_per_square, self.squares_y * px_per_square
        if self.pattern == "charuco":
            return np.asarray(self.charuco().generateImage((width, height), marginSize=0), np.uint8)
        rows, cols = np.indices((height, width)) // px_per_square
        return np.where((rows + cols) % 2 == 0, 0, 255).astype(np.uint8)


@dataclass(frozen=True)
class Detection:
    """Corners found in one image: their ids (indices into ``Board.object_points``) and pixels."""

    ids: npt.NDArray[np.int32]
    image_px: Points


def detect(board: Board, grey: Image) -> Detection | None:
    """Find the board's inner corners in a grey image, refined to subpixel.

    Args:
        board: The board to look for.
        grey: An 8-bit single-channel image.

    Returns:
        The corners found, or None if the board is not in the image.
    """
    if board.pattern == "chessboard":
        flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
        found, corners = cv2.findChessboardCorners(grey, board.inner_corners, flags=flags)
        if not found:
            return None
        refined = cv2.cornerSubPix(grey, corners, (5, 5), (-1, -1), _SUBPIX_CRITERIA)
        found_px = np.asarray(refined, np.float32).reshape(-1, 2)
        # OpenCV may return the grid starting from either end; put corner 0 top-left.
        if found_px[0, 0] + found_px[0, 1] > found_px[-1, 0] + found_px[-1, 1]:
            found_px = np.ascontiguousarray(found_px[::-1])
        return Detection(np.arange(len(found_px), dtype=np.int32), found_px)
    detector = cv2.aruco.CharucoDetector(board.charuco())
    corners, ids, _marker_corners, _marker_ids = detector.detectBoard(grey)
    if ids is None or len(ids) < MIN_CHARUCO_CORNERS:
        return None
    charuco_px = np.asarray(corners, np.float32).reshape(-1, 1, 2)
    # A small window: ChArUco corners sit between markers whose edges a larger one would catch.
    refined = cv2.cornerSubPix(grey, charuco_px, (2, 2), (-1, -1), _SUBPIX_CRITERIA)
    corners_px = np.asarray(refined, np.float32).reshape(-1, 2)
    return Detection(np.asarray(ids, np.int32).ravel(), corners_px)


BLUR_VARIANCE = 30.0
"""An image whose Laplacian varies less than this (grey levels squared) is too blurred to
find corners in: a sharp board's black and white edges give hundreds to thousands."""


def why_not_found(board: Board, grey: Image) -> str:
    """Why :func:`detect` found no board in an image, as far as can be told.

    The image is too blurred (motion, focus), or a chessboard of another size is in it (the
    common mistake of giving the inner corners as the squares, or across and down swapped),
    or the board is cut off or hidden.
    """
    if float(grey.std()) < 5.0:
        return "board not found (the image is almost one shade: covered, dark or overexposed)"
    sharpness = float(cv2.Laplacian(grey, cv2.CV_64F).var())
    if sharpness < BLUR_VARIANCE:
        return (
            f"blurred (sharpness {sharpness:.0f}, a sharp board gives {BLUR_VARIANCE:.0f} or more)"
        )
    if board.pattern == "chessboard":
        given = board.inner_corners
        for other in _other_sizes(given):
            found, _ = cv2.findChessboardCorners(grey, other, flags=cv2.CALIB_CB_FAST_CHECK)
            if found:
                return (
                    f"the board found has {other[0] + 1}x{other[1] + 1} squares "
                    f"({other[0]}x{other[1]} inner corners), not the {board.squares_x}x"
                    f"{board.squares_y} given: pass --squares {other[0] + 1}x{other[1] + 1}"
                )
    return "board not found (cut off, hidden or lit unevenly? the whole board must be in view)"


def _other_sizes(given: tuple[int, int]) -> list[tuple[int, int]]:
    """Chessboard sizes (inner corners) one might have meant instead of ``given``."""
    cols, rows = given
    sizes = [(rows, cols)]
    for d_cols in (-1, 0, 1, 2, -2):
        for d_rows in (-1, 0, 1, 2, -2):
            sizes.append((cols + d_cols, rows + d_rows))
    seen: list[tuple[int, int]] = []
    for size in sizes:
        if size != given and min(size) >= 3 and size not in seen:
            seen.append(size)
    return seen


def printable(board: Board, dpi: float, margin_mm: float = 10.0) -> Image:
    """The board on white with a margin, at ``dpi`` (printed at 100 %, squares are true size)."""
    px_per_mm = dpi / 25.4
    square_px = round(1000.0 * board.square_m * px_per_mm)
    if square_px < 8:
        raise ValueError(
            f"{1000 * board.square_m:g} mm squares are {square_px} px at {dpi:g} dpi: raise --dpi"
        )
    margin_px = round(margin_mm * px_per_mm)
    image = board.image(square_px)
    return np.asarray(
        cv2.copyMakeBorder(
            image, margin_px, margin_px, margin_px, margin_px, cv2.BORDER_CONSTANT, value=255
        ),
        np.uint8,
    )
