"""Recorded frames: a folder of left/right image pairs, or a side-by-side video file."""

from __future__ import annotations

import csv
import io
import logging
import math
import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from avoidd.errors import BrokenFrame, SourceError, SourceExhausted
from avoidd.fileread import UnreadableFile, read_bounded
from avoidd.sources.base import Pacer
from avoidd.sources.imagesize import image_size, too_many_pixels
from avoidd.types import FramePose, Image, StereoFrame, VehicleSample, wrap_deg

logger = logging.getLogger(__name__)

IMAGE_SUFFIXES = frozenset({".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm"})
DEFAULT_FPS = 10.0


POSE_COLUMNS = ("roll_deg", "pitch_deg")
"""Optional ``frames.csv`` columns with the vehicle attitude at capture (both or neither)."""
HEIGHT_COLUMN = "height_m"
"""Optional ``frames.csv`` column with the height above ground at capture."""
VEHICLE_COLUMNS = ("yaw_deg", "north_m", "east_m", "down_m")
"""Optional ``frames.csv`` columns with the heading and local position at capture (any of them;
an empty cell is unknown)."""
MAX_T_CAPTURE_NS = 2**63 - 1
"""Capture times are monotonic nanoseconds: 0 to the largest signed 64-bit number."""
MAX_INDEX_BYTES = 64_000_000
"""Largest ``frames.csv`` read: about 400,000 rows with every column (hours of frames)."""
MAX_IMAGE_BYTES = 256_000_000
"""Largest image file read (a 33.5-megapixel view in 16-bit colour, uncompressed, is 201 MB)."""


@dataclass(frozen=True)
class _Pair:
    left: Path
    right: Path
    t_capture_ns: int | None
    pose: FramePose | None = None
    vehicle: VehicleSample | None = None


def _images(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)


def _pose(row: dict[str, str], has_height: bool, where: str) -> FramePose:
    """The recorded attitude (and height) of one ``frames.csv`` row."""
    values = {}
    for column in (*POSE_COLUMNS, HEIGHT_COLUMN) if has_height else POSE_COLUMNS:
        try:
            values[column] = float(row[column])
        except (TypeError, ValueError) as exc:
            raise SourceError(f"{where}: {column} is not a number") from exc
        if not math.isfinite(values[column]):
            raise SourceError(f"{where}: {column} is not finite")
    if abs(values["roll_deg"]) > 90.0 or abs(values["pitch_deg"]) > 90.0:
        raise SourceError(f"{where}: roll_deg and pitch_deg must lie within +-90 degrees")
    height = values.get(HEIGHT_COLUMN, math.nan)
    return FramePose(
        values["roll_deg"],
        values["pitch_deg"],
        height,
        "recording",
        "recording" if has_height else "none",
    )


def _vehicle(row: dict[str, str], columns: list[str], where: str) -> VehicleSample:
    """The recorded heading and local position of one row; empty or absent cells are NaN."""
    values = {}
    for column in columns:
        text = (row[column] or "").strip()
        if not text:
            continue
        try:
            value = float(text)
        except ValueError as exc:
            raise SourceError(
                f"{where}: {column} is not a number (leave it empty if unknown)"
            ) from exc
        if not math.isfinite(value):
            raise SourceError(f"{where}: {column} is not finite (leave it empty if unknown)")
        values[column] = value
    if "yaw_deg" in values:
        values["yaw_deg"] = wrap_deg(values["yaw_deg"])
    return VehicleSample(**values)


def _read_utf8(path: Path) -> str:
    """A text file's content; bytes that are not UTF-8 are an error naming the line."""
    try:
        size = path.stat().st_size
        if size > MAX_INDEX_BYTES:
            raise SourceError(
                f"{path}: {size / 1e6:.0f} MB, larger than the {MAX_INDEX_BYTES // 1_000_000} MB "
                "an index may be (about 400,000 frames with every column); split the recording"
            )
        data = read_bounded(path, MAX_INDEX_BYTES)
    except OSError as exc:
        raise SourceError(f"{path}: cannot read ({exc.strerror or exc})") from exc
    except UnreadableFile as exc:
        raise SourceError(f"{path}: {exc.reason}; an index is a CSV file") from None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data[: exc.start].count(b"\n") + 1
        raise SourceError(
            f"{path}:{line}: byte 0x{data[exc.start]:02x} is not UTF-8; save the file as UTF-8"
        ) from None


def _read_index(folder: Path, path: Path) -> list[_Pair]:
    """Pairs listed in ``frames.csv``.

    Columns: ``t_capture_ns``; optionally ``left`` and ``right`` (file names), ``roll_deg``
    and ``pitch_deg`` (vehicle attitude at capture), ``height_m`` (height above ground) and
    ``yaw_deg``, ``north_m``, ``east_m``, ``down_m`` (heading and local position, cells may be
    empty). Other columns (``seq``, ``attitude_source``, ``height_source``) are ignored.
    """
    left_dir, right_dir = folder / "left", folder / "right"
    reader = csv.DictReader(io.StringIO(_read_utf8(path), newline=""))
    fields = set(reader.fieldnames or ())
    if "t_capture_ns" not in fields:
        raise SourceError(f"{path}: needs a header with a 't_capture_ns' column")
    named = {"left", "right"} <= fields
    has_pose = set(POSE_COLUMNS) <= fields
    if not has_pose and fields & set(POSE_COLUMNS):
        raise SourceError(f"{path}: has one of roll_deg and pitch_deg; give both or neither")
    has_height = HEIGHT_COLUMN in fields
    if has_height and not has_pose:
        raise SourceError(f"{path}: height_m needs roll_deg and pitch_deg columns too")
    vehicle_columns = [c for c in VEHICLE_COLUMNS if c in fields]
    left_images = [] if named else _images(left_dir)
    right_images = [] if named else _images(right_dir)

    # Each row is checked as it is read: a broken one is reported at once, however long
    # the file is.
    pairs = []
    for number, row in enumerate(reader):
        line = reader.line_num  # the row's last line (a quoted cell may hold line breaks)
        if not named and number >= len(left_images):
            raise SourceError(
                f"{path}:{line}: more rows than the {len(left_images)} images in left/; "
                "add 'left' and 'right' columns or make the counts agree"
            )
        try:
            t_ns = int(row["t_capture_ns"])
        except (TypeError, ValueError) as exc:
            raise SourceError(f"{path}:{line}: t_capture_ns is not an integer") from exc
        if not 0 <= t_ns <= MAX_T_CAPTURE_NS:
            raise SourceError(
                f"{path}:{line}: t_capture_ns {row['t_capture_ns'][:24]} is out of range; "
                f"a capture time is monotonic nanoseconds from 0 to {MAX_T_CAPTURE_NS}"
            )
        pose = _pose(row, has_height, f"{path}:{line}") if has_pose else None
        vehicle = _vehicle(row, vehicle_columns, f"{path}:{line}") if vehicle_columns else None
        if named:
            left, right = left_dir / row["left"], right_dir / row["right"]
        else:
            left, right = left_images[number], right_images[number]
        pairs.append(_Pair(left, right, t_ns, pose, vehicle))
    if not named and len(pairs) != len(left_images):
        raise SourceError(
            f"{path}: {len(pairs)} rows but {len(left_images)} images in left/; "
            "add 'left' and 'right' columns or make the counts agree"
        )
    return pairs


def list_pairs(folder: Path) -> list[_Pair]:
    """The stereo pairs of a folder, in order.

    Args:
        folder: Holds ``left/`` and ``right/`` image folders and optionally ``frames.csv``.

    Returns:
        The pairs; capture times come from ``frames.csv`` when it exists.

    Raises:
        SourceError: The layout is wrong or the two folders disagree.
    """
    left_dir, right_dir = folder / "left", folder / "right"
    if not left_dir.is_dir() or not right_dir.is_dir():
        raise SourceError(f"{folder}: expected 'left/' and 'right/' folders of images")
    index = folder / "frames.csv"
    if index.exists():
        return _read_index(folder, index)
    left_images, right_images = _images(left_dir), _images(right_dir)
    if len(left_images) != len(right_images):
        raise SourceError(
            f"{folder}: left/ has {len(left_images)} images, right/ has {len(right_images)}; "
            "pairs are matched by sorted name, so both need the same count"
        )
    if not left_images:
        raise SourceError(f"{folder}: no images in left/ (looked for {sorted(IMAGE_SUFFIXES)})")
    return [_Pair(a, b, None) for a, b in zip(left_images, right_images, strict=True)]


class FolderSource:
    """Stereo pairs from ``left/`` and ``right/`` image folders.

    Args:
        folder: The folder.
        fps: Playback rate when paced; default from ``frames.csv`` times, else 10.
        paced: Deliver frames in real time stamped with the monotonic clock (daemon) rather
            than as fast as possible with their recorded times (replay).
        loop: Start over after the last pair instead of ending.
    """

    def __init__(self, folder: Path, fps: float | None, paced: bool, loop: bool) -> None:
        self._folder = folder
        self._pairs = list_pairs(folder)
        self._loop = loop
        self._paced = paced
        self._fps = fps or self._recorded_fps() or DEFAULT_FPS
        self._pacer = Pacer(self._fps) if paced else None
        self._index = 0
        self._seq = 0
        self._restarts = 0

    def _recorded_fps(self) -> float | None:
        times = [p.t_capture_ns for p in self._pairs if p.t_capture_ns is not None]
        if len(times) < 2 or times[-1] <= times[0]:
            return None
        return (len(times) - 1) / ((times[-1] - times[0]) / 1e9)

    @property
    def description(self) -> str:
        """What the source reads, for logs and errors."""
        return f"image folder {self._folder} ({len(self._pairs)} pairs)"

    def __len__(self) -> int:
        return len(self._pairs)

    def read(self) -> StereoFrame:
        """Deliver the next pair; raises BrokenFrame for an unreadable one."""
        if self._index >= len(self._pairs):
            if not self._loop:
                raise SourceExhausted(f"{self.description} ended")
            self._index = 0
            self._restarts += 1
        pair = self._pairs[self._index]
        self._index += 1
        seq = self._seq
        self._seq += 1
        if self._pacer is not None:
            t_capture_ns = self._pacer.wait()
        elif pair.t_capture_ns is not None:
            t_capture_ns = pair.t_capture_ns
        else:
            t_capture_ns = int(seq * 1e9 / self._fps)
        for path in (pair.left, pair.right):
            if not path.exists():
                raise BrokenFrame(
                    f"{path}: missing (was the recording moved or deleted?); frame {seq} dropped"
                )
        left, right = read_image(pair.left, seq), read_image(pair.right, seq)
        return StereoFrame(
            seq,
            t_capture_ns,
            _as_uint8(left, pair.left),
            _as_uint8(right, pair.right),
            pose=pair.pose,
            restarts=self._restarts,
            vehicle=pair.vehicle,
        )

    def close(self) -> None:
        """Nothing to release."""


_PNG_END = b"IEND\xaeB`\x82"
_JPEG_END = b"\xff\xd9"


def read_image(path: Path, seq: int) -> np.ndarray:
    """One recorded image, as stored (any depth and channels).

    A PNG or JPEG file cut short (a copy or a recording interrupted) is refused before it is
    decoded: libpng and libjpeg report such files on stderr themselves, line after line, past
    every logging setting.

    Raises:
        BrokenFrame: The file is truncated or does not decode.
    """
    try:
        data = read_bounded(path, MAX_IMAGE_BYTES)
    except FileNotFoundError as exc:
        raise BrokenFrame(f"{path}: missing; frame {seq} dropped") from exc
    except UnreadableFile as exc:
        raise BrokenFrame(f"{path}: {exc.reason}; frame {seq} dropped") from None
    too_large = too_many_pixels(image_size(data))
    if too_large is not None:
        raise BrokenFrame(f"{path}: {too_large} (is it a camera view?); frame {seq} dropped")
    suffix = path.suffix.lower()
    ends = {".png": _PNG_END, ".jpg": _JPEG_END, ".jpeg": _JPEG_END}.get(suffix)
    if ends is not None and not data.rstrip(b"\0").endswith(ends):
        raise BrokenFrame(f"{path}: truncated image (no end marker); frame {seq} dropped")
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise BrokenFrame(f"{path}: unreadable image; frame {seq} dropped")
    return np.asarray(image)


def _as_uint8(image: np.ndarray, path: Path) -> Image:
    if image.dtype == np.uint8:
        return np.asarray(image, dtype=np.uint8)
    if image.dtype == np.uint16:
        return np.asarray(image >> 8, dtype=np.uint8)
    raise BrokenFrame(f"{path}: unsupported pixel type {image.dtype}")


class SideBySideVideoSource:
    """Stereo pairs from a video whose frames hold the left view beside the right view.

    Args:
        path: The video file.
        fps: Playback rate when paced; default the video's own rate.
        paced: Deliver in real time (daemon) rather than as fast as possible (replay).
        loop: Start over at the end instead of ending.
    """

    def __init__(self, path: Path, fps: float | None, paced: bool, loop: bool) -> None:
        self._path = path
        self._loop = loop
        self._capture = self._open()
        props = (cv2.CAP_PROP_FRAME_WIDTH, cv2.CAP_PROP_FRAME_HEIGHT)
        size = tuple(int(self._capture.get(prop) or 0) for prop in props)
        too_large = too_many_pixels(size, views=2)
        if too_large is not None:
            self._capture.release()
            raise SourceError(f"{path}: frames of {too_large} (is it a stereo recording?)")
        video_fps = float(self._capture.get(cv2.CAP_PROP_FPS) or 0.0)
        self._fps = fps or (video_fps if 0 < video_fps < 1000 else DEFAULT_FPS)
        self._pacer = Pacer(self._fps) if paced else None
        self._seq = 0
        self._restarts = 0
        count = float(self._capture.get(cv2.CAP_PROP_FRAME_COUNT) or 0.0)
        self._announced = int(count) if 0 < count < 1e9 else None
        """Frames the file's header announces (None: it does not say)."""
        self._in_pass = 0
        self._said_short = False

    def _open(self) -> cv2.VideoCapture:
        capture = cv2.VideoCapture(str(self._path))
        if not capture.isOpened():
            raise SourceError(f"{self._path}: cannot open the video; is it a supported format?")
        return capture

    @property
    def description(self) -> str:
        """What the source reads, for logs and errors."""
        return f"side-by-side video {self._path}"

    def _short(self) -> str | None:
        """How the pass that just ended fell short of the announced count (None: it did not).

        A frame or 1 % less is allowed: some containers' counts are estimates.
        """
        announced = self._announced
        if announced is None or announced - self._in_pass <= max(1, announced // 100):
            return None
        return (
            f"after {self._in_pass} of the {announced} frames its header announces: the file "
            "is truncated or damaged"
        )

    def read(self) -> StereoFrame:
        """Deliver the next frame split into its two halves."""
        ok, image = self._capture.read()
        if not ok and self._loop and self._seq > 0:
            short = self._short()
            if short is not None and not self._said_short:
                logger.warning("%s ended %s; starting over", self.description, short)
                self._said_short = True
            self._capture.release()
            self._capture = self._open()
            self._restarts += 1
            self._in_pass = 0
            ok, image = self._capture.read()
        if not ok or image is None:
            short = self._short()
            if short is None:
                raise SourceExhausted(f"{self.description} ended")
            raise SourceExhausted(f"{self.description} ended {short}", early=True)
        seq = self._seq
        self._seq += 1
        self._in_pass += 1
        if self._pacer is not None:
            t_capture_ns = self._pacer.wait()
        else:
            position_ms = float(self._capture.get(cv2.CAP_PROP_POS_MSEC) or 0.0)
            t_capture_ns = int(position_ms * 1e6) if position_ms > 0 else int(seq * 1e9 / self._fps)
        width = image.shape[1]
        if width % 2:
            raise BrokenFrame(f"{self._path}: frame width {width} is odd; not side-by-side")
        half = width // 2
        left = np.ascontiguousarray(image[:, :half], dtype=np.uint8)
        right = np.ascontiguousarray(image[:, half:], dtype=np.uint8)
        return StereoFrame(seq, t_capture_ns, left, right, restarts=self._restarts)

    def close(self) -> None:
        """Release the video."""
        self._capture.release()


def open_files(
    path: Path, fps: float | None, paced: bool, loop: bool
) -> FolderSource | SideBySideVideoSource:
    """Open a folder of pairs or a side-by-side video, whichever ``path`` is.

    Args:
        path: Folder with ``left/`` and ``right/``, or a video file.
        fps: Playback rate when paced.
        paced: Real-time delivery (daemon) or as fast as possible (replay).
        loop: Start over at the end.

    Returns:
        The source.

    Raises:
        SourceError: The path is neither, or cannot be read.
    """
    if not path.exists():
        raise SourceError(f"{path}: not found; give a folder with left/ and right/ or a video file")
    if not (path.is_dir() or path.is_file()):
        raise SourceError(
            f"{path}: neither a folder nor a regular file (a device, pipe or socket); give a "
            "folder with left/ and right/ or a video file"
        )
    if not os.access(path, os.R_OK | (os.X_OK if path.is_dir() else 0)):
        raise SourceError(f"{path}: not readable by this user; check its permissions")
    if path.is_dir():
        return FolderSource(path, fps, paced, loop)
    return SideBySideVideoSource(path, fps, paced, loop)
