"""Recording: every captured stereo pair, losslessly, with the vehicle state at its capture.

A recording is a folder that ``avoidd replay`` and a ``files`` source read without conversion::

    REC/avoidd.yaml           the configuration, each head's source pointed at its folder below
    REC/original.yaml         the configuration file as it was given (signing keys are not copied)
    REC/calibration/HEAD.yaml each head's calibration
    REC/HEAD/left/000000.png  lossless images (PNG), numbered in recording order
    REC/HEAD/right/000000.png
    REC/HEAD/frames.csv       one row per pair, appended after both images are written

Frames reach the :class:`Recorder` from the heads' capture threads (:meth:`Recorder.offer`,
which never blocks). The event loop stamps each with the vehicle state at its capture time
(the Vehicle lives on the loop) once the samples after that time have arrived, and a writer
thread per head encodes and writes. What is waiting to be written is bounded in bytes; past
that, frames are dropped from the recording and counted, so a slow disk never stalls the
pipeline.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import os
import queue
import shutil
import signal
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import yaml

from avoidd import sources
from avoidd.config import AppConfig, PerceptionConfig
from avoidd.daemon.announce import Announcer, send_statustext
from avoidd.daemon.core import build_link
from avoidd.daemon.head import Head, OpenSource
from avoidd.errors import AvoiddError, ConfigError
from avoidd.loading import obstacle_range_cm
from avoidd.mavlink import codec as mav
from avoidd.mavlink.link import MavLink
from avoidd.mavlink.signed import keep_timestamps, sign_link
from avoidd.mavlink.vehicle import Vehicle
from avoidd.perception.pose import resolve_pose
from avoidd.types import FramePose, StereoFrame
from avoidd.vision.calibration import Calibration

logger = logging.getLogger(__name__)

COLUMNS = (
    "t_capture_ns",
    "left",
    "right",
    "roll_deg",
    "pitch_deg",
    "height_m",
    "yaw_deg",
    "north_m",
    "east_m",
    "down_m",
    "attitude_source",
    "height_source",
    "seq",
)
"""The columns of a recording's ``frames.csv``, in order."""

STAMP_DELAY_S = 0.1
"""How long after a frame arrives its vehicle state is taken: the attitude is then interpolated
between the samples before and after the capture instead of held from the last one before it
(at 50 Hz, over a link with some latency)."""
POSITION_MAX_AGE_NS = 500_000_000
"""A local position older (or newer) than this at the capture time is not recorded."""
DEFAULT_QUEUE_BYTES = 64 * 2**20
"""Image bytes that may wait for the writer before frames are dropped from the recording."""
MIN_FREE_BYTES = 100 * 2**20
"""Recording stops when the disk has less free space than this (the system needs some too)."""
_FREE_CHECK_S = 2.0
# Lossless whatever the settings. Camera images carry sensor noise that LZ77 matching hardly
# compresses: Huffman coding alone (after PNG's filters) was as small and 2-3 times faster.
_PNG = [
    cv2.IMWRITE_PNG_COMPRESSION,
    1,
    cv2.IMWRITE_PNG_STRATEGY,
    cv2.IMWRITE_PNG_STRATEGY_HUFFMAN_ONLY,
]


@dataclass(frozen=True)
class CaptureState:
    """What avoidd knew about the vehicle at a frame's capture.

    Attributes:
        pose: The attitude and height the frame is interpreted with (as the daemon does).
        yaw_deg: The autopilot's heading, degrees clockwise from north; NaN when unknown.
        position_ned_m: The local position (north, east, down) at capture, or None.
    """

    pose: FramePose
    yaw_deg: float = math.nan
    position_ned_m: tuple[float, float, float] | None = None


def capture_state(frame: StereoFrame, pose: FramePose, vehicle: Vehicle) -> CaptureState:
    """The vehicle state of a frame: its pose, the heading and the position at its capture.

    Call it on the event loop that owns ``vehicle``. The position is extrapolated along its
    velocity to the capture time, and left out when further than 0.5 s from it.

    Args:
        frame: The frame.
        pose: Its pose, as :meth:`avoidd.daemon.Daemon.pose_for` resolves it.
        vehicle: The autopilot's state.
    """
    t_ns = frame.t_capture_ns
    attitude = vehicle.attitude_at(t_ns)
    yaw_deg = math.nan if attitude is None else math.degrees(attitude.yaw_rad)
    position = vehicle.position
    ned = None
    if position is not None and abs(t_ns - position.t_ns) <= POSITION_MAX_AGE_NS:
        dt_s = (t_ns - position.t_ns) / 1e9
        ned = (
            position.north_m + position.vn_m_s * dt_s,
            position.east_m + position.ve_m_s * dt_s,
            position.down_m + position.vd_m_s * dt_s,
        )
    return CaptureState(pose, yaw_deg, ned)


def _number(value: float) -> str:
    """A float as written in ``frames.csv``: exact (shortest round trip), empty when unknown."""
    return repr(float(value)) if math.isfinite(value) else ""


@dataclass
class HeadCounts:
    """What a recorder did with one head's frames.

    Attributes:
        recorded: Pairs written (and listed in ``frames.csv``).
        dropped: Pairs left out because the writer was behind (or the state unknown).
        bytes: Bytes written for the head (images and index).
    """

    recorded: int = 0
    dropped: int = 0
    bytes: int = 0


class _HeadFolder:
    """One head's folder (``left/``, ``right/``, ``frames.csv``) and its writer's queue."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        (folder / "left").mkdir(parents=True)
        (folder / "right").mkdir()
        self._index = (folder / "frames.csv").open("w", encoding="utf-8", newline="")
        self._index.write(",".join(COLUMNS) + "\n")
        self._index.flush()
        self.count = 0
        self.queue: queue.SimpleQueue[tuple[StereoFrame, CaptureState, int] | None] = (
            queue.SimpleQueue()
        )

    def write(self, left: bytes, right: bytes, line: str) -> None:
        """Write both images, then append and flush the row: no row names a missing image."""
        name = f"{self.count:06d}.png"
        (self.folder / "left" / name).write_bytes(left)
        (self.folder / "right" / name).write_bytes(right)
        self._index.write(line)
        self._index.flush()
        self.count += 1

    def close(self) -> None:
        self._index.close()


class Recorder:
    """Writes the frames it is offered into a recording folder, off the pipeline's path.

    Each head has its own writer thread (PNG encoding releases the GIL, so heads encode in
    parallel); a frame is written whole (both images, then its row) or not at all.

    Args:
        folder: The recording folder (created by :func:`prepare_folder`).
        heads: Names of the heads to record.
        max_bytes: Stop recording before the folder grows past this; None: no limit.
        queue_bytes: Image bytes that may wait for the writers; past that, frames are dropped.
        on_stop: See :attr:`on_stop`.
    """

    def __init__(
        self,
        folder: Path,
        heads: list[str],
        max_bytes: int | None = None,
        queue_bytes: int = DEFAULT_QUEUE_BYTES,
        on_stop: Callable[[str], None] | None = None,
    ) -> None:
        self.folder = folder
        self.max_bytes = max_bytes
        self.counts = {name: HeadCounts() for name in heads}
        self.total_bytes = sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())
        """Bytes in the folder: the copied configuration and what was recorded."""
        self.stop_reason: str | None = None
        """Why recording stopped by itself, or None."""
        self.failed = False
        """Whether it stopped on a write error (the disk, not a limit)."""
        self.on_stop = on_stop
        """Called once, from a writer thread, with the reason when recording stops by itself
        (the size limit, the disk nearly full, a write error)."""
        self._queue_bytes = queue_bytes
        self._heads = {name: _HeadFolder(folder / name) for name in heads}
        self._lock = threading.Lock()
        self._waiting_bytes = 0
        self._closed = False
        self._warned_drop: set[str] = set()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._sample: Callable[[StereoFrame], CaptureState] | None = None
        self._threads = [
            threading.Thread(
                target=self._write_loop, args=(name,), name=f"record-{name}", daemon=True
            )
            for name in heads
        ]
        self._free_checked = 0.0

    @property
    def recording(self) -> bool:
        """Whether frames are still being taken."""
        return not self._closed and self.stop_reason is None

    def start(
        self, loop: asyncio.AbstractEventLoop, sample: Callable[[StereoFrame], CaptureState]
    ) -> None:
        """Start the writer threads.

        Args:
            loop: The event loop that owns the vehicle state.
            sample: The vehicle state of a frame (called on ``loop``).
        """
        self._loop = loop
        self._sample = sample
        for thread in self._threads:
            thread.start()

    def offer(self, head: str, frame: StereoFrame) -> None:
        """Take a captured frame for the recording (any thread; never blocks, never raises)."""
        if not self.recording or self._loop is None or head not in self.counts:
            return
        size = frame.left.nbytes + frame.right.nbytes
        with self._lock:
            if self._waiting_bytes + size > self._queue_bytes and self._waiting_bytes > 0:
                self._drop(head, "the disk or the encoder is behind")
                return
            self._waiting_bytes += size
        try:
            self._loop.call_soon_threadsafe(
                self._loop.call_later, STAMP_DELAY_S, self._stamp, head, frame, size
            )
        except RuntimeError:  # the loop is closed: the run is over
            with self._lock:
                self._waiting_bytes -= size

    def _drop(self, head: str, why: str) -> None:
        """Count a frame left out (the lock is held)."""
        self.counts[head].dropped += 1
        if head not in self._warned_drop:
            self._warned_drop.add(head)
            logger.warning(
                "recording: head '%s': dropping frames (%s); they are counted, the pipeline "
                "is not slowed",
                head,
                why,
            )

    def _stamp(self, head: str, frame: StereoFrame, size: int) -> None:
        """On the loop: attach the vehicle state at capture and hand the frame to the writer."""
        assert self._sample is not None
        try:
            state = self._sample(frame)
        except Exception:
            logger.exception("recording: head '%s': no vehicle state for frame %d", head, frame.seq)
            with self._lock:
                self._waiting_bytes -= size
                self._drop(head, "no vehicle state")
            return
        self._heads[head].queue.put((frame, state, size))

    def _write_loop(self, head: str) -> None:
        _lower_priority()
        folder = self._heads[head]
        while True:
            item = folder.queue.get()
            if item is None:
                return
            frame, state, size = item
            try:
                if self.stop_reason is None:
                    self._write(head, folder, frame, state)
            except OSError as exc:
                self.failed = True
                self._stop(f"cannot write to {self.folder} ({exc.strerror or exc})")
            except Exception as exc:  # one bad frame (an image OpenCV cannot encode)
                logger.error("recording: head '%s': frame %d not written: %s", head, frame.seq, exc)
                with self._lock:
                    self._drop(head, "a frame could not be written")
            finally:
                with self._lock:
                    self._waiting_bytes -= size

    def _write(
        self, head: str, folder: _HeadFolder, frame: StereoFrame, state: CaptureState
    ) -> None:
        ok_left, left = cv2.imencode(".png", frame.left, _PNG)
        ok_right, right = cv2.imencode(".png", frame.right, _PNG)
        if not (ok_left and ok_right):
            raise ValueError("PNG encoding failed")
        pose = state.pose
        ned = state.position_ned_m or (math.nan, math.nan, math.nan)
        name = f"{folder.count:06d}.png"
        cells = [
            str(frame.t_capture_ns),
            name,
            name,
            _number(pose.roll_deg),
            _number(pose.pitch_deg),
            _number(pose.height_m),
            _number(state.yaw_deg),
            *(_number(v) for v in ned),
            pose.source,
            pose.height_source,
            str(frame.seq),
        ]
        line = ",".join(cells) + "\n"
        size = left.nbytes + right.nbytes + len(line)
        with self._lock:
            if self.stop_reason is not None:
                return
            if self.max_bytes is not None and self.total_bytes + size > self.max_bytes:
                self._stop(f"size limit of {self.max_bytes / 1e9:g} GB reached")
                return
            if not self._enough_space(size):
                return
            self.total_bytes += size  # reserved before writing: the heads share the limit
        folder.write(left.tobytes(), right.tobytes(), line)
        counts = self.counts[head]
        counts.recorded += 1
        counts.bytes += size

    def _enough_space(self, size: int) -> bool:
        """Stop before the disk fills up (checked every 2 s; the lock is held)."""
        now = time.monotonic()
        if now - self._free_checked < _FREE_CHECK_S:
            return True
        self._free_checked = now
        free = shutil.disk_usage(self.folder).free
        if free - size >= MIN_FREE_BYTES:
            return True
        self._stop(f"the disk is nearly full ({free / 2**20:.0f} MB free)")
        return False

    def _stop(self, reason: str) -> None:
        if self.stop_reason is not None:
            return
        self.stop_reason = reason
        if self.on_stop is not None:
            self.on_stop(reason)

    async def aclose(self) -> None:
        """Write what is waiting, then stop the writers (call on the loop, heads stopped)."""
        self._closed = True
        await asyncio.sleep(STAMP_DELAY_S + 0.05)  # frames not yet stamped when the heads stopped
        for folder in self._heads.values():
            folder.queue.put(None)
        for thread in self._threads:
            if thread.is_alive():
                await asyncio.to_thread(thread.join)
        for folder in self._heads.values():
            folder.close()

    def summary(self) -> str:
        """One line for the whole recording: frames, drops and size by head."""
        parts = [
            f"{name} {c.recorded} frames ({c.dropped} dropped)" for name, c in self.counts.items()
        ]
        return f"{', '.join(parts)}; {self.total_bytes / 1e6:.1f} MB in {self.folder}"


def _lower_priority() -> None:
    """Make the calling thread yield the CPU to the pipeline (Linux: a thread's own nice).

    Encoding PNG takes a core's worth at camera rates; a recording that falls behind drops
    frames, while a pipeline that falls behind sends stale data.
    """
    if not hasattr(os, "setpriority"):
        return
    with contextlib.suppress(OSError):
        tid = threading.get_native_id()
        os.setpriority(os.PRIO_PROCESS, tid, min(os.getpriority(os.PRIO_PROCESS, tid) + 10, 19))


def expand_folder(pattern: Path) -> Path:
    """A recording folder name with ``strftime`` fields (``rec-%Y%m%d-%H%M%S``) filled in."""
    return Path(time.strftime(str(pattern)))


def folder_in_use(folder: Path) -> bool:
    """Whether ``folder`` exists as anything but an empty folder (a recording never mixes)."""
    return folder.exists() and (not folder.is_dir() or any(folder.iterdir()))


def prepare_folder(folder: Path, config_path: Path, config: AppConfig) -> None:
    """Create a recording folder with the configuration and calibrations replay needs.

    ``original.yaml`` is the configuration file as given. ``avoidd.yaml`` is the same
    configuration with each head's ``source`` made a ``files`` source of its recorded folder
    and its ``calibration`` a copy in ``calibration/``, without ``mavlink.signing`` (a
    recording carries no key).

    Raises:
        ConfigError: The folder exists and is not empty, or cannot be created.
    """
    if folder_in_use(folder):
        raise ConfigError(
            [f"{folder}: exists and is not an empty folder; give a new folder to record into"]
        )
    try:
        (folder / "calibration").mkdir(parents=True, exist_ok=True)
        shutil.copyfile(config_path, folder / "original.yaml")
        doc: Any = yaml.safe_load(config_path.read_text(encoding="utf-8"))
        for raw, head in zip(doc["heads"], config.heads, strict=True):
            shutil.copyfile(head.calibration, folder / "calibration" / f"{head.name}.yaml")
            raw["calibration"] = f"calibration/{head.name}.yaml"
            raw["source"] = {"kind": "files", "path": head.name}
        mavlink = doc.get("mavlink")
        if isinstance(mavlink, dict):
            mavlink.pop("signing", None)
        header = (
            "# Written by avoidd record: the configuration of this recording, each head's "
            "source\n# made its recorded folder. Replay: avoidd replay --config avoidd.yaml "
            "--head NAME --out FILE.jsonl\n"
        )
        text = yaml.safe_dump(doc, sort_keys=False)
        (folder / "avoidd.yaml").write_text(header + text, encoding="utf-8")
    except OSError as exc:
        raise ConfigError(
            [f"{folder}: cannot create the recording folder ({exc.strerror or exc})"]
        ) from exc


def pose_resolver(
    vehicle: Vehicle, perception: PerceptionConfig
) -> Callable[[StereoFrame], FramePose]:
    """Resolves a frame's pose from ``vehicle`` as :meth:`avoidd.daemon.Daemon.pose_for` does."""

    def pose_for(frame: StereoFrame) -> FramePose:
        return resolve_pose(
            frame.t_capture_ns,
            frame.pose,
            vehicle.attitude_at(frame.t_capture_ns),
            vehicle.rangefinder,
            vehicle.position,
            perception,
        )

    return pose_for


async def record(
    config: AppConfig,
    calibrations: dict[str, Calibration],
    recorder: Recorder,
    duration_s: float | None = None,
    *,
    open_source: OpenSource | None = None,
    link: MavLink | None = None,
) -> int:
    """Record every head with the autopilot's state until a limit, SIGINT or SIGTERM.

    The heads capture as in the daemon (reopening a lost camera) and the MAVLink link asks the
    autopilot for its attitude, position and rangefinder and sends a HEARTBEAT (STANDBY) and a
    STATUSTEXT saying that avoidd is recording without avoidance. No frame is processed and
    no obstacle message is sent.

    Returns:
        0 when recording stopped at a limit, on a signal or when every source ended; 1 when
        the link cannot open or writing failed.
    """
    loop = asyncio.get_running_loop()
    stopped = asyncio.Event()
    reason: list[str] = []

    def stop(why: str) -> None:
        if not reason:
            reason.append(why)
        stopped.set()

    handled = []
    for signum in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(NotImplementedError, RuntimeError, ValueError):
            loop.add_signal_handler(signum, stop, f"{signal.Signals(signum).name} received")
            handled.append(signum)

    def stop_from_writer(why: str) -> None:
        loop.call_soon_threadsafe(stop, why)

    recorder.on_stop = stop_from_writer
    link = link if link is not None else build_link(config.mavlink)
    # A signing autopilot ignores an unsigned recorder.
    timestamps = sign_link(link.codec, config.mavlink.signing)
    announcer = Announcer(loop)
    vehicle = Vehicle(link, config.mavlink, announcer)
    pose_for = pose_resolver(vehicle, config.perception)
    stop_threads = threading.Event()
    max_range_m = (
        obstacle_range_cm(
            config.mavlink.obstacle_distance, ((h, calibrations[h.name]) for h in config.heads)
        )[1]
        / 100.0
    )
    heads = [
        Head(
            h,
            calibrations[h.name],
            max_range_m,
            loop,
            stop_threads,
            announcer,
            config.perception,
            pose_for,
            open_source if open_source is not None else sources.open_source,
            on_frame=recorder.offer,
        )
        for h in config.heads
    ]
    try:
        await link.open()
    except AvoiddError as exc:
        logger.error("%s", exc)
        await recorder.aclose()
        return 1
    recorder.start(loop, lambda frame: capture_state(frame, pose_for(frame), vehicle))
    logger.info(
        "recording %d head(s) [%s] into %s%s; MAVLink %s (no obstacle messages are sent)",
        len(heads),
        ", ".join(h.name for h in heads),
        recorder.folder,
        f" for {duration_s:g} s" if duration_s is not None else "",
        config.mavlink.link,
    )
    announcer(mav.MAV_SEVERITY_NOTICE, "avoidd: recording, no avoidance data sent")
    for head in heads:
        head.start()
    tasks = [
        asyncio.create_task(vehicle.run(), name="vehicle"),
        asyncio.create_task(send_statustext(announcer, link, lambda: None), name="statustext"),
        asyncio.create_task(_heartbeats(link, config.mavlink.heartbeat_hz), name="heartbeat"),
    ]
    if config.mavlink.signing is not None:
        tasks.append(asyncio.create_task(keep_timestamps(link.codec, timestamps), name="signing"))
    started = time.monotonic()
    try:
        while not stopped.is_set():
            if duration_s is not None and time.monotonic() - started >= duration_s:
                stop(f"duration of {duration_s:g} s reached")
            elif all(head.ended for head in heads):
                stop("every source ended")
            else:
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(stopped.wait(), 0.05)
    finally:
        for signum in handled:
            loop.remove_signal_handler(signum)
        stop_threads.set()
        for head in heads:
            await asyncio.to_thread(head.join, 5.0)
        await recorder.aclose()
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        await link.close()
        timestamps.keep(link.codec.signing_timestamp, force=True)
    logger.info(
        "recording stopped: %s; %s", reason[0] if reason else "cancelled", recorder.summary()
    )
    return 1 if recorder.failed else 0


async def _heartbeats(link: MavLink, rate_hz: float) -> None:
    while True:
        link.send(link.codec.heartbeat(mav.MAV_STATE_STANDBY))
        await asyncio.sleep(1.0 / rate_hz)
