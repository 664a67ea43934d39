"""One stereo head at run time: its capture thread with backoff, compute task and latest scan."""

from __future__ import annotations

import asyncio
import contextlib
import functools
import logging
import os
import threading
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol, TypeVar

from avoidd.config import HeadConfig, PerceptionConfig, SourceConfig
from avoidd.daemon.framecheck import FrameCheck
from avoidd.daemon.latency import FrameRate, LatencyHistogram
from avoidd.errors import BrokenFrame, SourceError, SourceExhausted
from avoidd.logrepeat import RepeatLimiter
from avoidd.mavlink import codec as mav
from avoidd.mavlink.vehicle import Announce
from avoidd.perception.temporal import SectorFilter
from avoidd.pipeline import HeadPipeline, HeadResult, Matched
from avoidd.slot import LatestSlot
from avoidd.sources import FrameSource
from avoidd.types import FramePose, RectifiedRig, SectorScan, StereoFrame
from avoidd.vision.calibration import Calibration

logger = logging.getLogger(__name__)
_R = TypeVar("_R")

_BACKOFF_MIN_S = 0.5
_BACKOFF_MAX_S = 10.0
# This many unreadable frames in a row and the camera is lost: no usable frames arrive.
LOST_AFTER_BROKEN = 5


class OpenSource(Protocol):
    """Opens a head's frame source; the signature of :func:`avoidd.sources.open_source`."""

    def __call__(
        self,
        config: SourceConfig,
        rig: RectifiedRig,
        head: str,
        paced: bool,
        input_path: Path | None = None,
    ) -> FrameSource:
        """Open the source ``config`` describes (raises ``SourceError`` when it cannot)."""


@dataclass
class StageClock:
    """The wall time one stage of a head has been busy (``avoidd bench --daemon`` reads it).

    A run lasts from handing a frame to the stage's thread to having its result back. Over a
    window, the growth of :meth:`busy_s` divided by the window's length is the share of
    the time the stage was busy (the busier stage limits the frame rate); a stage running at
    either edge of the window is counted for the part inside it.
    """

    total_s: float = 0.0
    since_s: float | None = None
    recent: deque[tuple[float, float]] = field(default_factory=lambda: deque(maxlen=256))
    """The last 256 runs: when each ended (``time.perf_counter``) and its milliseconds."""

    def start(self) -> None:
        """A run begins."""
        self.since_s = time.perf_counter()

    def stop(self) -> None:
        """The run ends (also when it failed or was cancelled)."""
        if self.since_s is None:
            return
        now_s = time.perf_counter()
        self.total_s += now_s - self.since_s
        self.recent.append((now_s, (now_s - self.since_s) * 1000.0))
        self.since_s = None

    def busy_s(self, now_s: float) -> float:
        """Seconds busy up to ``now_s``, the run going on included.

        Args:
            now_s: A ``time.perf_counter`` reading.
        """
        return self.total_s + (now_s - self.since_s if self.since_s is not None else 0.0)


@dataclass
class HeadStats:
    """Counters of one head (written by its capture thread and compute task).

    ``match`` and ``finish`` time the head's two stages as its threads run them (the
    near-field pass is in ``finish``; ``avoidd bench`` and the stage metrics count it in the
    matcher's ``match`` time instead).
    """

    captured: int = 0
    processed: int = 0
    broken: int = 0
    source_errors: int = 0
    restarts: int = 0
    latency_ms: deque[float] = field(default_factory=lambda: deque(maxlen=256))
    latency: LatencyHistogram = field(default_factory=LatencyHistogram)
    rate: FrameRate = field(default_factory=FrameRate)
    match: StageClock = field(default_factory=StageClock)
    finish: StageClock = field(default_factory=StageClock)


class Head:
    """One stereo head at run time: its source thread, slot, pipeline and latest result.

    Args:
        config: The head's configuration.
        calibration: Its loaded calibration.
        max_range_m: Range treated as clear.
        loop: The daemon's event loop.
        stop: Set when the daemon shuts down.
        announce: Thread-safe callback for operator-visible events (severity, text, key).
        perception: Ground model, band and temporal filter parameters.
        pose_for: Attitude and height to interpret a frame with.
        open_source: Opens the head's source (called from the capture thread).
        on_frame: Also given every captured frame with the head's name, in the capture
            thread (a recorder); it must return at once and never raise.
        overlap: Match the next frame while the previous one is finished (two threads).
        matcher_nice: With ``overlap``: nice steps added to the matching thread (see
            :func:`lower_thread_priority`).
    """

    def __init__(
        self,
        config: HeadConfig,
        calibration: Calibration,
        max_range_m: float,
        loop: asyncio.AbstractEventLoop,
        stop: threading.Event,
        announce: Announce,
        perception: PerceptionConfig,
        pose_for: Callable[[StereoFrame], FramePose],
        open_source: OpenSource,
        on_frame: Callable[[str, StereoFrame], None] | None = None,
        overlap: bool = False,
        matcher_nice: int = 0,
    ) -> None:
        self.config = config
        self._overlap = overlap
        # One thread per stage, always the same: the stages keep per-thread scratch arrays
        # (tens of MB at 640x480), which a shared pool would grow with every thread it adds.
        self._match_pool = ThreadPoolExecutor(
            1,
            thread_name_prefix=f"match-{config.name}",
            initializer=functools.partial(lower_thread_priority, matcher_nice)
            if overlap and matcher_nice
            else None,
        )
        self._finish_pool = (
            ThreadPoolExecutor(1, thread_name_prefix=f"finish-{config.name}")
            if overlap
            else self._match_pool
        )
        self.name = config.name
        self.pipeline = HeadPipeline(config, calibration, max_range_m, perception)
        self.filter = SectorFilter(perception.temporal)
        self._restarts_seen = 0
        self._pose_for = pose_for
        self._open_source = open_source
        self._on_frame = on_frame
        self.slot: LatestSlot[StereoFrame] = LatestSlot(loop)
        self.latest: HeadResult | None = None
        self.latest_scan: SectorScan | None = None
        self.on_result: Callable[[], None] | None = None
        """Called (in the event loop) each time a new scan is published."""
        self.stats = HeadStats()
        self.ended = False
        self.last_frame_ns: int | None = None
        """When the source last delivered a frame (local monotonic)."""
        self.arrival_age_ns: int | None = None
        """How old that frame was when it arrived (its capture time to delivery)."""
        self.reading_since_ns: int | None = None
        """When the read in progress started, None between reads (a wedged source shows)."""
        self._stop = stop
        self._announce = announce
        self._thread = threading.Thread(target=self._capture, name=f"capture-{self.name}")
        self._capture_log = RepeatLimiter(logger)
        self._compute_log = RepeatLimiter(logger)
        self._broken_in_row = 0
        self._lost_to_broken = False
        self.frame_check = FrameCheck(self.name, repeats=config.source.kind != "synthetic")
        self._compute_failing = False

    @property
    def fault(self) -> str | None:
        """Why the head's data stops, when the head knows ("camera frozen" ...), else None."""
        if self.frame_check.fault is not None:
            return self.frame_check.fault
        return "compute failing" if self._compute_failing else None

    @property
    def t_capture_ns(self) -> int | None:
        """Capture time of the newest processed frame, or None before the first."""
        latest = self.latest
        return None if latest is None else latest.t_capture_ns

    def start(self) -> None:
        """Start the capture thread."""
        self._thread.start()

    def join(self, timeout_s: float) -> None:
        """Wait for the capture thread to finish; let the stage threads end."""
        self._thread.join(timeout_s)
        self._match_pool.shutdown(wait=False)
        self._finish_pool.shutdown(wait=False)

    def _backoff_range(self) -> tuple[float, float]:
        source = self.config.source
        if source.kind == "v4l2":
            return source.reopen_min_s, source.reopen_max_s
        return _BACKOFF_MIN_S, _BACKOFF_MAX_S

    def _open(self) -> FrameSource:
        return self._open_source(self.config.source, self.pipeline.rig, self.name, paced=True)

    def _capture(self) -> None:
        """Capture thread: read frames into the slot; reopen a lost source with backoff."""
        low_s, high_s = self._backoff_range()
        backoff_s = low_s
        source: FrameSource | None = None
        lost = False
        while not self._stop.is_set():
            if source is None:
                try:
                    source = self._open()
                except SourceError as exc:
                    self.stats.source_errors += 1
                    self._capture_log.report(
                        logging.ERROR, "open failed", f"{exc}; retrying with backoff"
                    )
                    lost = self._say_lost(lost)
                    self._stop.wait(backoff_s)
                    backoff_s = min(backoff_s * 2, high_s)
                    continue
                except Exception:
                    logger.exception("head '%s': source failed to open", self.name)
                    self.stats.source_errors += 1
                    self._stop.wait(backoff_s)
                    backoff_s = min(backoff_s * 2, high_s)
                    continue
                if not lost:
                    self._capture_log.clear()
                logger.info("head '%s': reading %s", self.name, source.description)
            try:
                frame = self._read(source)
                self.pipeline.check_frame(frame)  # wrong size or pixel format: dropped here
            except BrokenFrame as exc:
                self.stats.broken += 1
                self._frame_broken(exc)
                continue
            except SourceExhausted as exc:
                logger.warning("head '%s': %s; no more data", self.name, exc)
                self._announce(mav.MAV_SEVERITY_WARNING, f"avoidd: {self.name} source ended")
                self.ended = True
                break
            except Exception as exc:
                # A camera that opens but gives no frame stays lost: one line per run of
                # failed reopenings, and "back" is said only once a frame arrives.
                self.stats.source_errors += 1
                self._capture_log.report(
                    logging.ERROR,
                    "source lost",
                    f"head '{self.name}': source lost ({exc}); reopening with backoff",
                )
                lost = self._say_lost(lost)
                with contextlib.suppress(Exception):
                    source.close()
                source = None
                self._stop.wait(backoff_s)
                backoff_s = min(backoff_s * 2, high_s)
                continue
            if lost:
                self.stats.restarts += 1
                self._announce(
                    mav.MAV_SEVERITY_NOTICE,
                    f"avoidd: {self.name} camera back",
                    f"camera {self.name}",
                )
                lost = False
                self._capture_log.clear(f"head '{self.name}': frames arriving again")
                backoff_s = low_s
            self._frame_good()
            if not self.frame_check.usable(frame):
                self.stats.broken += 1  # frozen or blind: no news (logged by the check)
                continue
            self.stats.captured += 1
            arrived_ns = time.monotonic_ns()
            self.arrival_age_ns = arrived_ns - frame.t_capture_ns
            self.last_frame_ns = arrived_ns
            self.slot.put(frame)
            if self._on_frame is not None:
                self._on_frame(self.name, frame)
        self._capture_log.clear()  # the repeats not yet summarised
        if source is not None:
            with contextlib.suppress(Exception):
                source.close()

    def _say_lost(self, lost: bool) -> bool:
        """Announce the camera lost unless it is already; returns True (lost now)."""
        if not lost:
            self._announce(
                mav.MAV_SEVERITY_CRITICAL, f"avoidd: {self.name} camera lost", f"camera {self.name}"
            )
        return True

    def _read(self, source: FrameSource) -> StereoFrame:
        """Read a frame, noting when the read started while it lasts."""
        self.reading_since_ns = time.monotonic_ns()
        try:
            return source.read()
        finally:
            self.reading_since_ns = None

    def _frame_broken(self, exc: BrokenFrame) -> None:
        """Log an unreadable frame once per run of them; a long run means the camera is lost."""
        self._broken_in_row += 1
        self._capture_log.report(logging.WARNING, "broken frames", self._about(exc))
        if self._broken_in_row == LOST_AFTER_BROKEN and not self._lost_to_broken:
            self._lost_to_broken = True
            logger.error(
                "head '%s': camera lost: %d frames in a row unreadable; check the source",
                self.name,
                self._broken_in_row,
            )
            self._announce(
                mav.MAV_SEVERITY_CRITICAL, f"avoidd: {self.name} camera lost", f"camera {self.name}"
            )

    def _about(self, exc: Exception) -> str:
        """An error's text with the head's name in front, unless it starts with it already."""
        text, prefix = str(exc), f"head '{self.name}': "
        return text if text.startswith(prefix) else prefix + text

    def _frame_good(self) -> None:
        """A usable frame arrived: end a run of unreadable ones."""
        if self._broken_in_row:
            self._capture_log.clear(
                f"head '{self.name}': frames readable again after {self._broken_in_row} "
                "unreadable ones"
            )
            self._broken_in_row = 0
        if self._lost_to_broken:
            self._lost_to_broken = False
            self._announce(
                mav.MAV_SEVERITY_NOTICE, f"avoidd: {self.name} camera back", f"camera {self.name}"
            )

    async def compute(self) -> None:
        """Compute task: process the newest frame in worker threads, keep the latest result.

        With ``overlap``, the next frame is matched while the previous one is finished (two
        worker threads); the matcher takes a new frame only once the finisher has taken the
        last one, so nothing queues up and the frame it takes is the newest one.
        """
        if not self._overlap:
            while True:
                frame = await self.slot.get()
                matched = await self._match(frame)
                if matched is not None:
                    await self._finish(matched)
        handoff: asyncio.Queue[Matched] = asyncio.Queue(maxsize=1)
        taken = asyncio.Event()
        taken.set()

        async def finisher() -> None:
            while True:
                matched = await handoff.get()
                taken.set()
                await self._finish(matched)

        finishing = asyncio.create_task(finisher(), name=f"finish-{self.name}")
        try:
            while True:
                await taken.wait()
                if finishing.done():
                    finishing.result()  # a finisher that died takes the task with it
                frame = await self.slot.get()
                matched = await self._match(frame)
                if matched is not None:
                    taken.clear()
                    handoff.put_nowait(matched)
        finally:
            finishing.cancel()

    async def _match(self, frame: StereoFrame) -> Matched | None:
        """Match one frame in the matcher's thread (None: dropped), timing the stage."""
        self.stats.match.start()
        try:
            return await self._guarded(self._match_pool, frame, self.pipeline.match, frame)
        finally:
            self.stats.match.stop()

    async def _finish(self, matched: Matched) -> None:
        """Post-process, interpret and publish one matched frame."""
        frame = matched.frame
        pose = self._pose_for(frame)
        self.stats.finish.start()
        try:
            result = await self._guarded(
                self._finish_pool, frame, self.pipeline.finish, matched, pose
            )
        finally:
            self.stats.finish.stop()
        if result is None:
            return
        self._compute_failing = False
        self._compute_log.clear()
        went_back = self.latest is not None and result.t_capture_ns <= self.latest.t_capture_ns
        if went_back or frame.restarts != self._restarts_seen:
            # The source started over (a looping recording): what the filter holds is of
            # another place. Paced sources stamp frames with the clock, so their times
            # never go back: they count their restarts instead.
            self.filter.reset()
            self._restarts_seen = frame.restarts
        self.latest_scan = self.filter.update(result.scan)
        self.latest = result
        self.stats.processed += 1
        now_ns = time.monotonic_ns()
        self.stats.latency_ms.append((now_ns - result.t_capture_ns) / 1e6)
        self.stats.latency.observe((now_ns - result.t_capture_ns) / 1e9)
        self.stats.rate.tick(now_ns)
        if self.on_result is not None:
            self.on_result()

    async def _guarded(
        self, pool: ThreadPoolExecutor, frame: StereoFrame, stage: Callable[..., _R], *args: object
    ) -> _R | None:
        """Run a stage in its thread; a failure is counted and logged, and gives None."""
        try:
            loop = asyncio.get_running_loop()
            return await loop.run_in_executor(pool, functools.partial(stage, *args))
        except BrokenFrame as exc:
            self.stats.broken += 1
            self._compute_log.report(logging.WARNING, "broken", self._about(exc))
        except Exception as exc:
            # A bug in a stage: one line per run of failures, not a traceback per frame
            # (the traceback is there at DEBUG level).
            self.stats.broken += 1
            self._compute_failing = True
            text = f"head '{self.name}': frame {frame.seq} failed ({exc!r}); dropped"
            if self._compute_log.report(logging.ERROR, "failed", text):
                logger.debug("head '%s': the failure", self.name, exc_info=True)
        return None

    def fresh_scan(self, now_ns: int, max_age_ns: int) -> SectorScan | None:
        """The latest filtered scan if its frame is younger than ``max_age_ns``, else None.

        Bins holding a reading older than ``max_age_ns`` (a held obstacle) come back unknown.
        """
        latest, scan = self.latest, self.latest_scan
        if latest is None or scan is None or now_ns - latest.t_capture_ns > max_age_ns:
            return None
        return scan.expired(now_ns, max_age_ns)


def lower_thread_priority(by: int) -> None:
    """Make the calling thread ``by`` nicer than it is (Linux: nice is per thread).

    The overlapped matcher runs with it (``pipeline.matcher_nice``); where per-thread nice is
    not available the thread keeps its priority (logged at DEBUG).

    Args:
        by: Nice steps to add (the result is at most 19).
    """
    thread_id = threading.get_native_id()
    try:
        now = os.getpriority(os.PRIO_PROCESS, thread_id)
        os.setpriority(os.PRIO_PROCESS, thread_id, min(19, now + by))
    except (OSError, AttributeError) as exc:
        logger.debug("matcher thread priority left as it is: %s", exc)
