"""Why a pair is not used (blur, a board of another size, no board), the table printed when
too few are left, and the printable board."""

from __future__ import annotations

import struct
from pathlib import Path

import cv2
import numpy as np
import pytest

from avoidd.calibrate.board import Board, detect, printable, why_not_found
from avoidd.calibrate.render import default_rig, write_pairs
from avoidd.cli import main

CHESS = Board("chessboard", 10, 7, 0.05)


def _board_on_grey(board: Board) -> np.ndarray:
    image = printable(board, 150.0)
    return np.asarray(cv2.resize(image, (640, 480), interpolation=cv2.INTER_AREA), np.uint8)


def test_a_board_of_another_size_is_named_with_the_remedy() -> None:
    picture = _board_on_grey(CHESS)
    assert detect(CHESS, picture) is not None
    given = Board("chessboard", 9, 6, 0.05)  # the inner corners given as squares, one less
    assert detect(given, picture) is None
    why = why_not_found(given, picture)
    assert "10x7 squares" in why and "--squares 10x7" in why, why


def test_a_blurred_view_says_blurred() -> None:
    picture = cv2.GaussianBlur(_board_on_grey(CHESS), (0, 0), 12.0)
    assert detect(CHESS, picture) is None
    assert why_not_found(CHESS, picture).startswith("blurred")


def test_a_view_without_a_board_says_so() -> None:
    rng = np.random.default_rng(1)
    noise = rng.integers(0, 255, (480, 640), dtype=np.uint8)
    assert why_not_found(CHESS, noise).startswith("board not found")


def test_calibrate_with_the_wrong_size_prints_each_pairs_reason(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    write_pairs(tmp_path, CHESS, default_rig(), 6, seed=3)
    out = tmp_path / "c.yaml"
    assert main(["calibrate", str(tmp_path), "--squares", "9x6", "--out", str(out)]) == 1
    printed = capsys.readouterr().out
    assert "0 of 6 pairs usable" in printed
    reasons = [line for line in printed.splitlines() if "both images:" in line]
    assert len(reasons) >= 3, printed
    assert any("--squares 10x7" in line for line in reasons), printed
    assert not out.exists()


def test_the_printed_board_has_true_size_squares_and_is_detected(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "board.png"
    args = ["print-board", str(out), "--squares", "10x7", "--square-mm", "25", "--dpi", "300"]
    assert main(args) == 0
    assert "fits A4" in capsys.readouterr().out
    image = cv2.imread(str(out), cv2.IMREAD_GRAYSCALE)
    assert image is not None
    square_px = round(25.0 / 25.4 * 300.0)  # 295 px
    margin_px = round(10.0 / 25.4 * 300.0)
    assert image.shape == (7 * square_px + 2 * margin_px, 10 * square_px + 2 * margin_px)
    data = out.read_bytes()
    at = data.index(b"pHYs")
    per_m_x, per_m_y, unit = struct.unpack(">IIB", data[at + 4 : at + 13])
    assert unit == 1 and per_m_x == per_m_y == round(300 / 0.0254)
    small = cv2.resize(image, (image.shape[1] // 4, image.shape[0] // 4))
    assert detect(Board("chessboard", 10, 7, 0.025), small) is not None
    assert main(["print-board", str(out), "--square-mm", "1", "--dpi", "72"]) == 2
