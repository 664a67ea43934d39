"""The calibration commands: calibrate, render-board, import-calibration, check-rectification."""

from __future__ import annotations

import argparse
import json
from collections.abc import Iterator
from datetime import UTC, datetime
from pathlib import Path

import cv2
import numpy as np

from avoidd.calibrate.board import Board, detect, printable, why_not_found
from avoidd.calibrate.check import board_dy_px, matched_dy_px, rectify_pair, valid_masks
from avoidd.calibrate.importers import euroc_stereo, middlebury_rectified
from avoidd.calibrate.render import default_rig, write_pairs
from avoidd.calibrate.stereo import (
    CalibrationFailed,
    PairObservation,
    PairReport,
    StereoCalibration,
    calibrate,
    observe_pair,
)
from avoidd.commands import EXIT_FAILURE, EXIT_OK
from avoidd.errors import ConfigError, SourceError
from avoidd.progress import Progress
from avoidd.sources.files import list_pairs
from avoidd.types import Image
from avoidd.vision.calibration import load_calibration, write_calibration

# The rectification check warns (calibrate) or fails (check-rectification) above this mean |dy|.
DY_WARN_PX = 0.5


def _add_board_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--pattern", choices=["chessboard", "charuco"], default="chessboard")
    parser.add_argument(
        "--squares", default="10x7", help="squares across x down (a 10x7 board has 9x6 corners)"
    )
    parser.add_argument("--square-mm", type=float, default=25.0, help="side of one square, mm")
    parser.add_argument("--marker-mm", type=float, help="ChArUco marker side, mm")
    parser.add_argument("--dictionary", default="DICT_4X4_50", help="ChArUco ArUco dictionary")


def configure(name: str, parser: argparse.ArgumentParser) -> None:
    """Add the options of one of the calibration commands."""
    if name == "calibrate":
        parser.add_argument("folder", type=Path, help="folder with left/ and right/ image pairs")
        _add_board_options(parser)
        parser.add_argument("--out", type=Path, required=True, help="calibration YAML to write")
        parser.set_defaults(handler=_cmd_calibrate)
    elif name == "print-board":
        parser.add_argument("out", type=Path, help="PNG to write (print it at 100 %%)")
        _add_board_options(parser)
        parser.add_argument("--dpi", type=float, default=300.0, help="printer resolution")
        parser.set_defaults(handler=_cmd_print_board)
    elif name == "render-board":
        parser.add_argument("folder", type=Path, help="where left/ and right/ are written")
        _add_board_options(parser)
        parser.add_argument("--count", type=int, default=15, help="number of pairs")
        parser.add_argument("--seed", type=int, default=0)
        parser.set_defaults(handler=_cmd_render_board)
    elif name == "import-calibration":
        parser.add_argument("kind", choices=["euroc", "middlebury"])
        parser.add_argument(
            "files", type=Path, nargs="+", help="cam0 and cam1 sensor.yaml, or calib.txt"
        )
        parser.add_argument("--out", type=Path, required=True, help="calibration YAML to write")
        parser.set_defaults(handler=_cmd_import_calibration)
    else:
        parser.add_argument("--calibration", type=Path, required=True, help="calibration YAML")
        parser.add_argument(
            "folder", type=Path, help="left/ + right/ folder, or a EuRoC mav0 folder"
        )
        parser.add_argument("--max-pairs", type=int, default=20, help="pairs to sample")
        parser.add_argument("--json", type=Path, help="also write the figures as JSON")
        parser.add_argument(
            "--max-dy-px",
            type=float,
            default=DY_WARN_PX,
            help=f"FAIL above this mean |dy|, px (default {DY_WARN_PX})",
        )
        _add_board_options(parser)
        parser.set_defaults(handler=_cmd_check_rectification)


def _board(args: argparse.Namespace) -> Board:
    return make_board(args.pattern, args.squares, args.square_mm, args.marker_mm, args.dictionary)


def _cmd_calibrate(args: argparse.Namespace) -> int:
    run_calibrate(args.folder, _board(args), args.out)
    return EXIT_OK


def _cmd_print_board(args: argparse.Namespace) -> int:
    board = _board(args)
    if not 72.0 <= args.dpi <= 1200.0:
        raise ConfigError([f"--dpi {args.dpi:g}: give 72 to 1200 (the printer's resolution)"])
    try:
        image = printable(board, args.dpi)
    except ValueError as exc:
        raise ConfigError([f"print-board: {exc}"]) from exc
    args.out.parent.mkdir(parents=True, exist_ok=True)
    # The resolution in the file, so that a viewer prints it at true size.
    ok = cv2.imwrite(str(args.out), image)
    if not ok:
        raise SourceError(f"{args.out}: cannot write the image")
    _set_png_dpi(args.out, args.dpi)
    width_mm, height_mm = (25.4 * n / args.dpi for n in (image.shape[1], image.shape[0]))
    sheet = _sheet(width_mm, height_mm)
    print(
        f"wrote {args.out}: {board.pattern} {board.squares_x}x{board.squares_y} squares of "
        f"{1000 * board.square_m:g} mm, {width_mm:.0f} x {height_mm:.0f} mm with its margin "
        f"({sheet}). Print at 100 % (no fit to page), measure one square, and give that size "
        f"to avoidd calibrate --square-mm; glue the sheet to something flat."
    )
    return EXIT_OK


def _sheet(width_mm: float, height_mm: float) -> str:
    """The smallest common paper the board fits on."""
    short, long = sorted((width_mm, height_mm))
    for name, (a, b) in (("A4", (210, 297)), ("US letter", (216, 279)), ("A3", (297, 420))):
        if short <= a and long <= b:
            return f"fits {name}"
    return "larger than A3: print at a copy shop, or give smaller --square-mm"


def _set_png_dpi(path: Path, dpi: float) -> None:
    """Put a pHYs chunk (pixels per metre) after the PNG's header chunk."""
    import struct
    import zlib

    data = path.read_bytes()
    per_m = round(dpi / 0.0254)
    body = b"pHYs" + struct.pack(">IIB", per_m, per_m, 1)
    chunk = struct.pack(">I", 9) + body + struct.pack(">I", zlib.crc32(body) & 0xFFFFFFFF)
    end_of_header = 8 + 25  # signature, then IHDR: length, type, 13 bytes, CRC
    path.write_bytes(data[:end_of_header] + chunk + data[end_of_header:])


def _cmd_render_board(args: argparse.Namespace) -> int:
    write_pairs(args.folder, _board(args), default_rig(), args.count, args.seed)
    print(f"wrote {args.count} pairs to {args.folder}/left and {args.folder}/right")
    return EXIT_OK


def _cmd_import_calibration(args: argparse.Namespace) -> int:
    run_import(args.kind, args.files, args.out)
    return EXIT_OK


def _cmd_check_rectification(args: argparse.Namespace) -> int:
    figures = run_check(args.calibration, args.folder, args.max_pairs, _board(args))
    if args.json is not None:
        args.json.write_text(json.dumps(figures, indent=2) + "\n")
    if figures["mean"] <= args.max_dy_px:
        print(f"PASS: mean |dy| {figures['mean']:.3f} px <= {args.max_dy_px} px")
        return EXIT_OK
    print(
        f"FAIL: mean |dy| {figures['mean']:.3f} px > {args.max_dy_px} px; the calibration does not "
        "rectify these images: check it belongs to this camera and resolution, or recalibrate"
    )
    return EXIT_FAILURE


def parse_grid(text: str, what: str) -> tuple[int, int]:
    """``"10x7"`` as (10, 7).

    Raises:
        ConfigError: Not two positive integers joined by 'x'.
    """
    parts = text.lower().split("x")
    if len(parts) == 2 and all(p.isdigit() and int(p) > 0 for p in parts):
        return int(parts[0]), int(parts[1])
    raise ConfigError([f"{what} {text!r}: write COLUMNSxROWS of squares, e.g. 10x7"])


def make_board(
    pattern: str, squares: str, square_mm: float, marker_mm: float | None, dictionary: str
) -> Board:
    """The board the command-line options describe.

    Raises:
        ConfigError: The options do not describe a usable board.
    """
    cols, rows = parse_grid(squares, "--squares")
    if pattern == "charuco" and marker_mm is None:
        raise ConfigError(["--marker-mm: a ChArUco board needs its marker size (e.g. 18)"])
    try:
        return Board(
            "charuco" if pattern == "charuco" else "chessboard",
            cols,
            rows,
            square_mm / 1000.0,
            (marker_mm or 0.0) / 1000.0,
            dictionary,
        )
    except ValueError as exc:
        raise ConfigError([f"board: {exc}"]) from exc


def _grey(path: Path) -> Image:
    image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise SourceError(f"{path}: cannot read the image")
    return np.asarray(image, np.uint8)


def run_calibrate(folder: Path, board: Board, out: Path) -> StereoCalibration:
    """Detect the board in every pair of ``folder`` (``left/``, ``right/``), calibrate, write.

    Prints per-pair results, the errors and the rectification check.

    Raises:
        SourceError: The folder layout is wrong or the image sizes differ.
        CalibrationFailed: Too few usable pairs.
    """
    pairs = list_pairs(folder)
    progress = Progress(len(pairs))
    observations: list[PairObservation | PairReport] = []
    size: tuple[int, int] | None = None
    for pair in pairs:
        try:
            left, right = _grey(pair.left), _grey(pair.right)
        except SourceError as exc:  # one unreadable pair is dropped, like a pair without a board
            observations.append(PairReport(pair.left.name, used=False, reason=str(exc)))
            progress.step(pair.left.name)
            continue
        shape = (left.shape[1], left.shape[0])
        if right.shape != left.shape or (size is not None and shape != size):
            raise SourceError(f"{pair.left}: every image must have the same size as the first")
        size = shape
        name = pair.left.name
        observations.append(_observe(board, name, left, right))
        progress.step(name)
    if size is None:
        raise SourceError(f"{folder}: no image pairs")
    try:
        result = calibrate(size, observations)
    except CalibrationFailed:
        print(format_rejections(observations))
        raise
    print(format_calibration(result))
    used = sum(1 for p in result.pairs if p.used)
    rig = result.rig
    write_calibration(
        out,
        result.model,
        [
            f"avoidd calibrate {folder} ({board.pattern} {board.squares_x}x{board.squares_y}, "
            f"{1000 * board.square_m:g} mm), {datetime.now(UTC):%Y-%m-%d %H:%M} UTC",
            f"{used} of {len(pairs)} pairs used; RMS {result.rms_px:.3f} px; rectified |dy| "
            f"mean {result.dy_mean_px:.3f} max {result.dy_max_px:.3f} px",
            f"rectified: fx {rig.fx:.2f} px, baseline {rig.baseline_m:.5f} m",
        ],
    )
    print(f"wrote {out}")
    return result


def _observe(board: Board, name: str, left: Image, right: Image) -> PairObservation | PairReport:
    """One pair's shared corners, or why it cannot be used (the board's absence explained)."""
    found_left, found_right = detect(board, left), detect(board, right)
    observation = observe_pair(board, name, found_left, found_right)
    if found_left is None or found_right is None:
        side = "left" if found_left is None else "right"
        why = why_not_found(board, left if found_left is None else right)
        both = found_left is None and found_right is None
        where = "both images" if both else f"the {side} image"
        return PairReport(name, False, f"{where}: {why}")
    return observation


def format_rejections(observations: list[PairObservation | PairReport]) -> str:
    """Every pair that cannot be used, with its reason (printed when too few are left)."""
    lines = ["pair                          why it was not used"]
    for item in observations:
        if isinstance(item, PairReport) and not item.used:
            lines.append(f"{item.name[:28]:<28}  {item.reason}")
    usable = sum(isinstance(item, PairObservation) for item in observations)
    lines.append(f"{usable} of {len(observations)} pairs usable")
    return "\n".join(lines)


def format_calibration(result: StereoCalibration) -> str:
    """Per-pair table, errors and rectification check as text."""
    lines = ["pair                          corners  error px  status"]
    for pair in result.pairs:
        error = f"{pair.error_px:8.3f}" if pair.error_px is not None else "       -"
        status = "used" if pair.used else f"dropped: {pair.reason}"
        lines.append(f"{pair.name[:28]:<28}  {pair.corners:7d}  {error}  {status}")
    model, rig = result.model, result.rig
    lines += [
        f"RMS reprojection error: stereo {result.rms_px:.3f} px, left {result.left_rms_px:.3f} px,"
        f" right {result.right_rms_px:.3f} px",
        f"left  fx {model.K1[0][0]:.2f} fy {model.K1[1][1]:.2f} cx {model.K1[0][2]:.2f} "
        f"cy {model.K1[1][2]:.2f}",
        f"right fx {model.K2[0][0]:.2f} fy {model.K2[1][1]:.2f} cx {model.K2[0][2]:.2f} "
        f"cy {model.K2[1][2]:.2f}",
        f"baseline {float(np.linalg.norm(model.T_m)):.5f} m; rectified fx {rig.fx:.2f} px",
        f"rectification check: |dy| of matched corners mean {result.dy_mean_px:.3f} px, "
        f"max {result.dy_max_px:.3f} px",
    ]
    if result.dy_mean_px > DY_WARN_PX:
        lines.append(
            f"WARNING: mean |dy| above {DY_WARN_PX} px; recapture with sharper, simultaneous pairs"
        )
    return "\n".join(lines)


def run_import(kind: str, files: list[Path], out: Path) -> None:
    """Convert a dataset's calibration into the project's format and write it.

    Raises:
        ConfigError: Wrong number of files or an invalid file.
    """
    if kind == "euroc":
        if len(files) != 2:
            raise ConfigError(["import-calibration euroc: give cam0/sensor.yaml cam1/sensor.yaml"])
        model = euroc_stereo(files[0], files[1])
        write_calibration(out, model, [f"imported from EuRoC {files[0]} and {files[1]}"])
        print(f"EuRoC stereo rig, baseline {float(np.linalg.norm(model.T_m)):.4f} m")
    else:
        if len(files) != 1:
            raise ConfigError(["import-calibration middlebury: give one calib.txt"])
        rectified = middlebury_rectified(files[0])
        write_calibration(out, rectified, [f"imported from Middlebury {files[0]}"])
        print(f"Middlebury rectified rig, baseline {rectified.baseline_m:.4f} m")
    print(f"wrote {out}")


def stereo_folder_pairs(folder: Path) -> Iterator[tuple[str, Path, Path]]:
    """Pairs of a ``left/``+``right/`` folder or of a EuRoC ``mav0`` (``cam0/data``, ``cam1/data``).

    Raises:
        SourceError: Neither layout.
    """
    cam0, cam1 = folder / "cam0" / "data", folder / "cam1" / "data"
    if cam0.is_dir() and cam1.is_dir():
        for left in sorted(cam0.iterdir()):
            right = cam1 / left.name
            if right.exists():
                yield left.name, left, right
        return
    for pair in list_pairs(folder):
        yield pair.left.name, pair.left, pair.right


def run_check(
    calibration_path: Path, folder: Path, max_pairs: int, board: Board | None = None
) -> dict[str, float]:
    """Rectify image pairs with a calibration and measure |dy| of unambiguous matches.

    A pair showing ``board`` in both views is measured on the board's corners, paired by id;
    any other pair on features matched by descriptor (see ``matched_dy_px``).

    Returns:
        ``pairs``, ``board_pairs`` (pairs measured on the board), ``matches``, and |dy| ``mean``,
        ``median``, ``p95`` in pixels.
    """
    calibration = load_calibration(calibration_path)
    pairs = list(stereo_folder_pairs(folder))
    if not pairs:
        raise SourceError(f"{folder}: no image pairs")
    step = max(1, len(pairs) // max_pairs)
    chosen = pairs[::step][:max_pairs]
    max_disparity_px = 0.5 * calibration.rig.width
    values = []
    board_pairs = 0
    progress = Progress(len(chosen))
    masks: tuple[Image, Image] | None = None
    for name, left, right in chosen:
        left_raw = _grey(left)
        if masks is None:
            masks = valid_masks(calibration, left_raw.shape)
        left_r, right_r = rectify_pair(calibration, left_raw, _grey(right))
        on_board = None if board is None else board_dy_px(board, left_r, right_r)
        if on_board is not None:
            board_pairs += 1
            values.append(on_board)
        else:
            values.append(matched_dy_px(left_r, right_r, max_disparity_px, masks))
        progress.step(name)
    dy = np.concatenate(values)
    if dy.size == 0:
        raise SourceError(f"{folder}: no features matched across the views; is it textured?")
    figures = {
        "pairs": float(len(chosen)),
        "board_pairs": float(board_pairs),
        "matches": float(dy.size),
        "mean": float(dy.mean()),
        "median": float(np.median(dy)),
        "p95": float(np.percentile(dy, 95)),
    }
    print(
        f"{len(chosen)} pairs ({board_pairs} measured on the board's corners), {dy.size} "
        "matches: rectified |dy| mean "
        f"{figures['mean']:.3f} px, median {figures['median']:.3f} px, "
        f"95th percentile {figures['p95']:.3f} px"
    )
    return figures
