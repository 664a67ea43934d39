"""The daemon: capture threads, compute workers, the MAVLink send loop, health and shutdown."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import signal
import statistics
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass, field

from avoidd.config import AppConfig, HeadConfig, PerceptionConfig
from avoidd.errors import AvoiddError, BrokenFrame, SourceError, SourceExhausted
from avoidd.mavlink import codec as mav
from avoidd.mavlink.link import MavLink
from avoidd.mavlink.messages import (
    DistanceSensorHead,
    nearest_points,
    sectors_to_cm,
    unknown_cm,
)
from avoidd.mavlink.signing import TimestampStore, load_key
from avoidd.mavlink.vehicle import Vehicle
from avoidd.perception.pose import resolve_pose
from avoidd.perception.sectors import merge_scans
from avoidd.perception.temporal import SectorFilter
from avoidd.pipeline import HeadPipeline, HeadResult
from avoidd.slot import LatestSlot
from avoidd.sources import FrameSource, open_source
from avoidd.types import FramePose, SectorScan, StereoFrame
from avoidd.vision.calibration import Calibration

logger = logging.getLogger(__name__)

_STATUSTEXT_MIN_INTERVAL_S = 0.5
_SIGNING_KEEP_S = 5.0
_BOOT_GRACE_NS = 5_000_000_000
_BACKOFF_MIN_S = 0.5
_BACKOFF_MAX_S = 10.0


@dataclass
class HeadStats:
    """Counters of one head (written by its capture thread and compute task)."""

    captured: int = 0
    processed: int = 0
    broken: int = 0
    source_errors: int = 0
    restarts: int = 0
    latency_ms: deque[float] = field(default_factory=lambda: deque(maxlen=256))


class Head:
    """One stereo head at run time: its source thread, slot, pipeline and latest result.

    Args:
        config: The head's configuration.
        calibration: Its loaded calibration.
        max_range_m: Range treated as clear.
        loop: The daemon's event loop.
        stop: Set when the daemon shuts down.
        announce: Thread-safe callback for operator-visible events (severity, text).
        perception: Ground model, band and temporal filter parameters.
        pose_for: Attitude and height to interpret a frame with.
    """

    def __init__(
        self,
        config: HeadConfig,
        calibration: Calibration,
        max_range_m: float,
        loop: asyncio.AbstractEventLoop,
        stop: threading.Event,
        announce: _Announcer,
        perception: PerceptionConfig,
        pose_for: Callable[[StereoFrame], FramePose],
    ) -> None:
        self.config = config
        self.name = config.name
        self.pipeline = HeadPipeline(config, calibration, max_range_m, perception)
        self.filter = SectorFilter(perception.temporal)
        self._pose_for = pose_for
        self.slot: LatestSlot[StereoFrame] = LatestSlot(loop)
        self.latest: HeadResult | None = None
        self.latest_scan: SectorScan | None = None
        self.stats = HeadStats()
        self.ended = False
        self._stop = stop
        self._announce = announce
        self._thread = threading.Thread(target=self._capture, name=f"capture-{self.name}")

    def start(self) -> None:
        """Start the capture thread."""
        self._thread.start()

    def join(self, timeout_s: float) -> None:
        """Wait for the capture thread to finish."""
        self._thread.join(timeout_s)

    def _backoff_range(self) -> tuple[float, float]:
        source = self.config.source
        if source.kind == "v4l2":
            return source.reopen_min_s, source.reopen_max_s
        return _BACKOFF_MIN_S, _BACKOFF_MAX_S

    def _open(self) -> FrameSource:
        return open_source(self.config.source, self.pipeline.rig, self.name, paced=True)

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
                    logger.error("%s; retrying in %.1f s", exc, backoff_s)
                    if not lost:
                        self._announce(
                            mav.MAV_SEVERITY_CRITICAL,
                            f"avoidd: {self.name} camera lost",
                            f"camera {self.name}",
                        )
                        lost = True
                    self._stop.wait(backoff_s)
                    backoff_s = min(backoff_s * 2, high_s)
                    continue
                except Exception:
                    logger.exception("head '%s': source failed to open", self.name)
                    self.stats.source_errors += 1
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
                logger.info("head '%s': reading %s", self.name, source.description)
                backoff_s = low_s
            try:
                frame = source.read()
            except BrokenFrame as exc:
                self.stats.broken += 1
                logger.warning("%s", exc)
                continue
            except SourceExhausted:
                logger.warning("head '%s': %s ended; no more data", self.name, source.description)
                self._announce(mav.MAV_SEVERITY_WARNING, f"avoidd: {self.name} source ended")
                self.ended = True
                break
            except Exception as exc:
                self.stats.source_errors += 1
                logger.error("head '%s': source lost (%s); reopening", self.name, exc)
                self._announce(
                    mav.MAV_SEVERITY_CRITICAL,
                    f"avoidd: {self.name} camera lost",
                    f"camera {self.name}",
                )
                lost = True
                with contextlib.suppress(Exception):
                    source.close()
                source = None
                self._stop.wait(backoff_s)
                backoff_s = min(backoff_s * 2, high_s)
                continue
            self.stats.captured += 1
            self.slot.put(frame)
        if source is not None:
            with contextlib.suppress(Exception):
                source.close()

    async def compute(self) -> None:
        """Compute task: process the newest frame in a worker thread, keep the latest result."""
        while True:
            frame = await self.slot.get()
            try:
                pose = self._pose_for(frame)
                result = await asyncio.to_thread(self.pipeline.process, frame, pose)
            except BrokenFrame as exc:
                self.stats.broken += 1
                logger.warning("%s", exc)
                continue
            except Exception:
                self.stats.broken += 1
                logger.exception("head '%s': frame %d failed", self.name, frame.seq)
                continue
            if self.latest is not None and result.t_capture_ns <= self.latest.t_capture_ns:
                self.filter.reset()  # the source started over (a looping recording)
            self.latest_scan = self.filter.update(result.scan)
            self.latest = result
            self.stats.processed += 1
            self.stats.latency_ms.append((time.monotonic_ns() - result.t_capture_ns) / 1e6)

    def fresh_scan(self, now_ns: int, max_age_ns: int) -> SectorScan | None:
        """The latest filtered scan if its frame is younger than ``max_age_ns``, else None.

        Bins holding a reading older than ``max_age_ns`` (a held obstacle) come back unknown.
        """
        latest, scan = self.latest, self.latest_scan
        if latest is None or scan is None or now_ns - latest.t_capture_ns > max_age_ns:
            return None
        return scan.expired(now_ns, max_age_ns)


class _Announcer:
    """Thread-safe queue of operator messages, sent as STATUSTEXT by the event loop.

    Rate-limited without hiding state: the sender spaces messages 0.5 s apart, and a message
    about a subject (a camera, a head's freshness, the link) that is still waiting replaces the
    older one in place, so a flapping camera yields its latest state, not a backlog.
    """

    def __init__(self, loop: asyncio.AbstractEventLoop) -> None:
        self._loop = loop
        self.pending: deque[tuple[int, str, str | None]] = deque(maxlen=32)
        self.wakeup = asyncio.Event()
        self.coalesced = 0

    def __call__(self, severity: int, text: str, key: str | None = None) -> None:
        self._loop.call_soon_threadsafe(self._add, severity, text, key)

    def _add(self, severity: int, text: str, key: str | None) -> None:
        if key is not None:
            for index, (_, _, pending_key) in enumerate(self.pending):
                if pending_key == key:
                    self.pending[index] = (severity, text, key)
                    self.coalesced += 1
                    return
        self.pending.append((severity, text, key))
        self.wakeup.set()


class Daemon:
    """Wires the heads to the MAVLink link and runs until stopped.

    Args:
        config: The validated configuration.
        calibrations: Loaded calibration of every head, by head name.
    """

    def __init__(self, config: AppConfig, calibrations: dict[str, Calibration]) -> None:
        self.config = config
        self._calibrations = calibrations
        self._stop_threads = threading.Event()
        self._stopping = asyncio.Event()
        self.heads: list[Head] = []
        mavlink = config.mavlink
        self._codec = mav.Codec(mavlink.fixed_system_id or 1, mavlink.component_id)
        self._timestamps = TimestampStore(None)
        if mavlink.signing is not None:
            signing = mavlink.signing
            key = load_key(signing.key_file, signing.key_credential)
            allowed = {mav.message_id(name) for name in signing.allow_unsigned}
            self._timestamps = TimestampStore(signing.timestamp_file)
            self._codec.enable_signing(
                key, self._timestamps.start(), allowed.__contains__, signing.link_id
            )
        self.link = MavLink(mavlink.link, self._codec)
        self._announcer: _Announcer | None = None
        self.vehicle = Vehicle(self.link, mavlink, self._announce)
        self._stale: set[str] = set()
        self._started_ns = 0

    @property
    def sent(self) -> Counter[str]:
        """Messages sent, by type."""
        return self.link.sent

    @property
    def received(self) -> Counter[str]:
        """Messages received (any system), by type."""
        return self.link.received

    def stop(self) -> None:
        """Ask the daemon to shut down (safe from signal handlers in the loop)."""
        self._stopping.set()

    async def run(self) -> int:
        """Run until SIGINT/SIGTERM or :meth:`stop`.

        Returns:
            The process exit code: 0 on a clean shutdown, 1 if a task died.
        """
        loop = asyncio.get_running_loop()
        for signum in (signal.SIGINT, signal.SIGTERM):
            with contextlib.suppress(NotImplementedError, RuntimeError):
                loop.add_signal_handler(signum, self.stop)
        announcer = _Announcer(loop)
        max_range_m = self.config.mavlink.obstacle_distance.max_distance_cm / 100.0
        self.heads = [
            Head(
                h,
                self._calibrations[h.name],
                max_range_m,
                loop,
                self._stop_threads,
                announcer,
                self.config.perception,
                self.pose_for,
            )
            for h in self.config.heads
        ]
        spec = self.config.mavlink.link
        self._announcer = announcer
        try:
            await self.link.open()
        except AvoiddError as exc:
            logger.error("%s", exc)
            return 1
        self._started_ns = time.monotonic_ns()
        logger.info(
            "avoidd started: %d head(s) [%s], MAVLink %s as %s/%d%s",
            len(self.heads),
            ", ".join(h.name for h in self.heads),
            spec,
            self.config.mavlink.system_id,
            self.config.mavlink.component_id,
            ", signed" if self.config.mavlink.signing else "",
        )
        announcer(mav.MAV_SEVERITY_INFO, "avoidd started")
        for head in self.heads:
            head.start()
        tasks = [
            asyncio.create_task(head.compute(), name=f"compute-{head.name}") for head in self.heads
        ]
        mavlink = self.config.mavlink
        if mavlink.distance_sensor.enabled:
            tasks.append(asyncio.create_task(self._distance_sensor_loop(), name="distance"))
        if mavlink.obstacle_distance_3d.enabled:
            tasks.append(asyncio.create_task(self._obstacle_3d_loop(), name="obstacle-3d"))
        tasks += [
            asyncio.create_task(self._send_loop(), name="send"),
            asyncio.create_task(self._heartbeat_loop(), name="heartbeat"),
            asyncio.create_task(self._statustext_loop(announcer), name="statustext"),
            asyncio.create_task(self._log_loop(), name="log"),
            asyncio.create_task(self.vehicle.run(), name="vehicle"),
        ]
        if self.config.mavlink.signing is not None:
            tasks.append(asyncio.create_task(self._signing_loop(), name="signing"))
        stopping = asyncio.create_task(self._stopping.wait(), name="stopping")
        code = 0
        try:
            done, _ = await asyncio.wait([stopping, *tasks], return_when=asyncio.FIRST_COMPLETED)
            crashed = [task for task in done if task is not stopping]
            for task in crashed:
                # These tasks never end on their own: one that did is a bug, and running on
                # without it (say, without the send loop) would be flying blind. Exit non-zero
                # so that the service manager restarts avoidd.
                error = None if task.cancelled() else task.exception()
                logger.critical("task '%s' ended unexpectedly: %r", task.get_name(), error)
                code = 1
        finally:
            logger.info("avoidd stopping")
            stopping.cancel()
            self._stop_threads.set()
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
            for head in self.heads:
                await asyncio.to_thread(head.join, 5.0)
            await asyncio.sleep(0.05)  # let the sender flush what is queued
            await self.link.close()
            self._timestamps.keep(self._codec.signing_timestamp)
        logger.info("avoidd stopped; MAVLink %s", self.link.counters())
        return code

    def _announce(self, severity: int, text: str, key: str | None = None) -> None:
        """Report an event as STATUSTEXT (dropped before :meth:`run` has started)."""
        if self._announcer is not None:
            self._announcer(severity, text, key)

    async def _signing_loop(self) -> None:
        while True:
            await asyncio.sleep(_SIGNING_KEEP_S)
            self._timestamps.keep(self._codec.signing_timestamp)

    def pose_for(self, frame: StereoFrame) -> FramePose:
        """Attitude and height for a frame (see :func:`avoidd.perception.pose.resolve_pose`)."""
        vehicle = self.vehicle
        return resolve_pose(
            frame.t_capture_ns,
            frame.pose,
            vehicle.attitude_at(frame.t_capture_ns),
            vehicle.rangefinder,
            vehicle.position,
            self.config.perception,
        )

    async def _every(self, rate_hz: float, send: Callable[[], None]) -> None:
        """Call ``send`` at ``rate_hz`` without drift (skipping ahead after a stall)."""
        period_s = 1.0 / rate_hz
        next_s = time.monotonic()
        while True:
            send()
            next_s += period_s
            delay_s = next_s - time.monotonic()
            if delay_s < -period_s:
                next_s = time.monotonic()
                delay_s = 0.0
            await asyncio.sleep(max(delay_s, 0.0))

    async def _distance_sensor_loop(self) -> None:
        config = self.config.mavlink
        od = config.obstacle_distance
        max_age_ns = self.config.pipeline.max_age_ms * 1_000_000
        sensors = {
            head.name: DistanceSensorHead(head.pipeline.work_rig, head.pipeline.mount, index)
            for index, head in enumerate(self.heads)
        }

        def send() -> None:
            now_ns = time.monotonic_ns()
            for head in self.heads:
                scan = head.fresh_scan(now_ns, max_age_ns)
                latest = head.latest
                if scan is None or latest is None:
                    continue  # stale: say nothing, the autopilot times the sensor out
                sensor = sensors[head.name]
                reading_cm = sensor.reading_cm(scan, od.min_distance_cm, od.max_distance_cm)
                if reading_cm is None:
                    continue
                self.link.send(
                    sensor.message(
                        self._codec,
                        self.vehicle.time_boot_ms(latest.t_capture_ns),
                        reading_cm,
                        od.min_distance_cm,
                        od.max_distance_cm,
                        latest.valid_fraction,
                    )
                )

        await self._every(config.distance_sensor.rate_hz, send)

    async def _obstacle_3d_loop(self) -> None:
        config = self.config.mavlink
        od = config.obstacle_distance
        od3 = config.obstacle_distance_3d

        def send() -> None:
            scan = self._current_scan()
            if scan is None:
                return
            time_boot_ms = self.vehicle.time_boot_ms(scan.t_capture_ns)
            for point in nearest_points(scan, od3.max_points):
                self.link.send(
                    self._codec.obstacle_distance_3d(
                        time_boot_ms, point, od.min_distance_cm / 100, od.max_distance_cm / 100
                    )
                )

        await self._every(od3.rate_hz, send)

    def _current_scan(self) -> SectorScan | None:
        now_ns = time.monotonic_ns()
        max_age_ns = self.config.pipeline.max_age_ms * 1_000_000
        fresh = [s for h in self.heads if (s := h.fresh_scan(now_ns, max_age_ns)) is not None]
        return merge_scans(fresh) if fresh else None

    async def _send_loop(self) -> None:
        od = self.config.mavlink.obstacle_distance

        def send() -> None:
            scan = self._current_scan()
            if scan is None:
                distances = unknown_cm()
                time_usec = self.vehicle.time_usec(time.monotonic_ns())
            else:
                distances = sectors_to_cm(scan, od.min_distance_cm, od.max_distance_cm)
                time_usec = self.vehicle.time_usec(scan.t_capture_ns)
            self.link.send(
                self._codec.obstacle_distance(
                    time_usec, distances, od.min_distance_cm, od.max_distance_cm
                )
            )

        await self._every(od.rate_hz, send)

    def _stale_heads(self) -> set[str] | None:
        """Heads without fresh data, or None during the boot grace before any head produced."""
        now_ns = time.monotonic_ns()
        if now_ns - self._started_ns < _BOOT_GRACE_NS and all(h.latest is None for h in self.heads):
            return None
        max_age_ns = self.config.pipeline.max_age_ms * 1_000_000
        return {h.name for h in self.heads if h.fresh_scan(now_ns, max_age_ns) is None}

    def _health(self) -> int:
        """Heartbeat system status: BOOT, then ACTIVE while every head is fresh, else CRITICAL."""
        stale = self._stale_heads()
        if stale is None:
            return mav.MAV_STATE_BOOT
        return mav.MAV_STATE_CRITICAL if stale else mav.MAV_STATE_ACTIVE

    def _check_staleness(self, announce: _Announcer) -> None:
        """Log and announce heads that went stale or recovered since the last check."""
        stale = self._stale_heads()
        if stale is None:
            return
        for name in sorted(stale - self._stale):
            logger.error("head '%s': data stale; sending unknown for its sectors", name)
            announce(
                mav.MAV_SEVERITY_CRITICAL, f"avoidd: {name} stale, no avoidance", f"fresh {name}"
            )
        for name in sorted(self._stale - stale):
            logger.warning("head '%s': data fresh again", name)
            announce(mav.MAV_SEVERITY_NOTICE, f"avoidd: {name} recovered", f"fresh {name}")
        self._stale = stale

    async def _heartbeat_loop(self) -> None:
        period_s = 1.0 / self.config.mavlink.heartbeat_hz
        while True:
            self.link.send(self._codec.heartbeat(self._health()))
            await asyncio.sleep(period_s)

    async def _statustext_loop(self, announce: _Announcer) -> None:
        while True:
            self._check_staleness(announce)
            while announce.pending:
                severity, text, _ = announce.pending.popleft()
                self.link.send(self._codec.statustext(severity, text))
                await asyncio.sleep(_STATUSTEXT_MIN_INTERVAL_S)
            announce.wakeup.clear()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(announce.wakeup.wait(), timeout=0.05)

    async def _log_loop(self) -> None:
        interval_s = self.config.pipeline.log_interval_s
        previous = {h.name: (h.stats.processed, h.slot.skipped, h.stats.broken) for h in self.heads}
        while True:
            await asyncio.sleep(interval_s)
            parts = []
            for head in self.heads:
                processed, skipped, broken = (
                    head.stats.processed,
                    head.slot.skipped,
                    head.stats.broken,
                )
                p0, s0, b0 = previous[head.name]
                previous[head.name] = (processed, skipped, broken)
                latency = statistics.fmean(head.stats.latency_ms) if head.stats.latency_ms else 0.0
                fps = (processed - p0) / interval_s
                parts.append(
                    f"{head.name}: {fps:.1f} fps, skipped {skipped - s0}, "
                    f"dropped {broken - b0}, latency {latency:.0f} ms"
                )
            scan = self._current_scan()
            nearest = scan.nearest() if scan is not None else None
            where = (
                f"nearest {nearest.distance_m:.2f} m at {nearest.bearing_deg:+.0f} deg"
                if nearest is not None
                else ("nearest none" if scan is not None else "no fresh data")
            )
            logger.info(
                "%s; %s; sent %d; %s",
                "; ".join(parts),
                where,
                self.sent["OBSTACLE_DISTANCE"],
                self._link_summary(),
            )

    def _link_summary(self) -> str:
        """One phrase on the link: vehicle state and error counters."""
        vehicle = self.vehicle
        link = self.link
        if not vehicle.link_up or vehicle.mode is None:
            state = "link down"
        else:
            mode = vehicle.mode
            state = (
                f"link up: {mode.autopilot} sys {vehicle.system_id} {mode.name} "
                f"{'armed' if mode.armed else 'disarmed'}"
            )
        return (
            f"{state}; rx {sum(link.received.values())}, dropped {sum(link.dropped.values())}, "
            f"parse errors {link.parse_errors}, unsigned rejected {link.signature_rejects}"
        )
