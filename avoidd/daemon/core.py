"""The daemon: composes heads, link, outputs and reports, supervises their tasks, shuts down."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import signal
import threading
import time
from collections import Counter
from collections.abc import Callable, Coroutine
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2

from avoidd import foreignlog, sources
from avoidd.config import AppConfig, MavlinkConfig, SimSourceConfig, SourceConfig
from avoidd.config.connection import parse_connection
from avoidd.daemon import health
from avoidd.daemon.announce import Announcer, send_statustext
from avoidd.daemon.avoidance import AvoidanceLoop
from avoidd.daemon.head import Head, OpenSource
from avoidd.daemon.limits import raise_open_files_limit
from avoidd.daemon.notify import Notifier, watchdog_interval_s
from avoidd.daemon.outputs import Outputs
from avoidd.daemon.stats import DaemonStats, log_every, snapshot
from avoidd.daemon.systemd import ServiceReporter
from avoidd.errors import AvoiddError
from avoidd.loading import obstacle_range_cm
from avoidd.mavlink import codec as mav
from avoidd.mavlink.gcs import GcsEndpoint
from avoidd.mavlink.link import MavLink
from avoidd.mavlink.senders import AddressPin
from avoidd.mavlink.signed import keep_timestamps, sign_link
from avoidd.mavlink.twins import TwinWatch, instance_id
from avoidd.mavlink.vehicle import Vehicle
from avoidd.perception.pose import resolve_pose
from avoidd.sources.base import FrameSource
from avoidd.types import FramePose, Mount, RectifiedRig, StereoFrame
from avoidd.vision.calibration import Calibration

if TYPE_CHECKING:
    from avoidd.debugview.server import DebugServer

logger = logging.getLogger(__name__)

_ACTIONS = frozenset(
    {"SET_POSITION_TARGET_LOCAL_NED", "SET_POSITION_TARGET_GLOBAL_INT", "COMMAND_INT", "PARAM_SET"}
)
"""Commands that change what avoidd does (not reads)."""


def build_link(config: MavlinkConfig) -> MavLink:
    """The link a daemon uses by default: the configured connection with an unsigned codec.

    Args:
        config: The ``mavlink`` section.

    Returns:
        The link (not opened); the daemon enables signing on its codec if configured.
    """
    pin = config.autopilot_address
    return MavLink(
        config.link,
        mav.Codec(config.fixed_system_id or 1, config.component_id),
        autopilot_timeout_s=config.link_timeout_s,
        autopilot_address=AddressPin.parse(pin) if pin is not None else None,
    )


class Daemon:
    """Wires the heads to the MAVLink link and runs until stopped.

    Args:
        config: The validated configuration.
        calibrations: Loaded calibration of every head, by head name.
        open_source: Opens a head's source, with the signature of
            :func:`avoidd.sources.open_source` (the default).
        link: The MAVLink link, not yet opened; by default :func:`build_link` of the config.
            If ``mavlink.signing`` is configured, the daemon enables signing on its codec.
        on_frame: Given every captured frame with its head's name, in the head's capture
            thread (``avoidd run --record``: :meth:`avoidd.record.Recorder.offer`).

    Attributes:
        config: The configuration.
        link: The MAVLink link.
        codec: The link's codec (its ids and signing).
        vehicle: The autopilot on the link.
        heads: The heads, built when :meth:`run` starts.
    """

    def __init__(
        self,
        config: AppConfig,
        calibrations: dict[str, Calibration],
        *,
        open_source: OpenSource | None = None,
        link: MavLink | None = None,
        on_frame: Callable[[str, StereoFrame], None] | None = None,
    ) -> None:
        self.config = config
        self._on_frame = on_frame
        self._calibrations = calibrations
        self._open_source: OpenSource = open_source if open_source is not None else self._open
        self._stop_threads = threading.Event()
        self._stopping = asyncio.Event()
        self.heads: list[Head] = []
        self.outputs: Outputs | None = None
        """The obstacle message senders, built when :meth:`run` starts."""
        self.avoidance: AvoidanceLoop | None = None
        """The setpoint loop, built when :meth:`run` starts (silent unless enabled)."""
        mavlink = config.mavlink
        self.link = link if link is not None else build_link(mavlink)
        self.codec = self.link.codec
        self._timestamps = sign_link(self.codec, mavlink.signing)
        self._announcer: Announcer | None = None
        self.vehicle = Vehicle(self.link, mavlink, self.announce)
        self.gcs: GcsEndpoint | None = None
        """The ground-station endpoint (``mavlink.gcs_connection``), if configured."""
        if mavlink.gcs_connection is not None:
            # Of what ground stations send, avoidd takes only what is addressed to it, under
            # the autopilot link's trust rule; the rest goes on to the autopilot unread.
            self.gcs = GcsEndpoint(
                parse_connection(mavlink.gcs_connection),
                self.link,
                self.vehicle.handle_ground_station,
            )
        self.codec.instance = instance_id()
        self.twins = TwinWatch(self.link, self.codec.instance, self.announce)
        """Another sender speaking as avoidd's system and component (a second daemon)."""
        self._max_age_ns = config.pipeline.max_age_ms * 1_000_000
        self.threads = config.pipeline.threads or cv2.getNumberOfCPUs()
        """Vision threads (``pipeline.threads``, 0 = one per core)."""
        self._reported: dict[str, health.Reported] = {}
        self._beat: dict[str, health.Reported] = {}
        self._heartbeat_state = mav.MAV_STATE_BOOT
        self._started_ns = 0
        self.debug_server: DebugServer | None = None
        """The debug view, when ``debug_server.enabled`` (built when :meth:`run` starts)."""

    def _open(
        self,
        config: SourceConfig,
        rig: RectifiedRig,
        head: str,
        paced: bool,
        input_path: Path | None = None,
    ) -> FrameSource:
        """Open a head's source; a ``sim`` one renders from the pose this daemon hears."""
        if isinstance(config, SimSourceConfig):
            from avoidd.sim.pose_source import open_sim_source  # the renderer only when used

            m = next(h.mount for h in self.config.heads if h.name == head)
            mount = Mount(m.yaw_deg, m.pitch_deg, m.roll_deg, m.position_m)
            return open_sim_source(config, rig, mount, self.vehicle)
        return sources.open_source(config, rig, head, paced, input_path)

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

    async def stop_and_wait(self, task: asyncio.Task[int], timeout_s: float = 30.0) -> int | None:
        """Stop the daemon whose :meth:`run` is ``task`` and wait for it to end.

        For embedders that must go on whatever happened (a simulation tidying up after a
        failed flight): a run that raised or did not end in time is logged, not raised.

        Args:
            task: The task running :meth:`run`.
            timeout_s: How long to wait (a head thread mid-frame on a machine whose cores are
                all busy has taken more than 10 s to be joined).

        Returns:
            The run's exit code; None when it raised or did not end within ``timeout_s``.
        """
        self.stop()
        try:
            return await asyncio.wait_for(task, timeout_s)
        except TimeoutError:
            logger.error("avoidd did not stop within %.1f s", timeout_s)
        except Exception:
            logger.exception("avoidd ended with an error")
        # Cancelled or failed part-way through its shutdown, the run may not have closed its
        # link: a udpin port left bound would refuse the next daemon (a simulation's next run).
        with contextlib.suppress(Exception):
            if self.gcs is not None:
                await self.gcs.close()
        with contextlib.suppress(Exception):
            await self.link.close()
        return None

    def announce(self, severity: int, text: str, key: str | None = None) -> None:
        """Report an event as STATUSTEXT (dropped before :meth:`run` has started)."""
        if self._announcer is not None:
            self._announcer(severity, text, key)

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

    def snapshot(self, now_ns: int, previous: DaemonStats | None = None) -> DaemonStats:
        """The daemon's counters now (see :func:`avoidd.daemon.stats.snapshot`)."""
        planner = self.avoidance.summary() if self.avoidance is not None else None
        return snapshot(
            self.heads, self.link, self.vehicle, now_ns, self._max_age_ns, previous, planner
        )

    async def run(self) -> int:
        """Run until SIGINT/SIGTERM or :meth:`stop`.

        Returns:
            The process exit code: 0 on a clean shutdown, 1 if a task died.
        """
        loop = asyncio.get_running_loop()
        for signum in (signal.SIGINT, signal.SIGTERM):
            with contextlib.suppress(NotImplementedError, RuntimeError):
                loop.add_signal_handler(signum, self.stop)
        raise_open_files_limit()
        foreign = foreignlog.install(loop)  # aiohttp's and the loop's errors: counted lines
        try:
            return await self._run(loop)
        finally:
            foreignlog.uninstall(loop, foreign)

    async def _run(self, loop: asyncio.AbstractEventLoop) -> int:
        """The body of :meth:`run`, once signals and error reports are set up."""
        announcer = Announcer(loop)
        max_range_m = (
            obstacle_range_cm(
                self.config.mavlink.obstacle_distance,
                ((h, self._calibrations[h.name]) for h in self.config.heads),
            )[1]
            / 100.0
        )
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
                self._open_source,
                on_frame=self._on_frame,
                overlap=self.threads >= 2,
                matcher_nice=self.config.pipeline.matcher_nice,
            )
            for h in self.config.heads
        ]
        self._announcer = announcer
        try:
            await self.link.open()
        except AvoiddError as exc:
            logger.error("%s", exc)
            return 1
        if self.gcs is not None:
            try:
                await self.gcs.open()
            except AvoiddError as exc:
                # Flying comes first: without the endpoint avoidd still feeds the autopilot.
                logger.error("%s; running without the ground-station endpoint", exc)
                self.gcs = None
        self._started_ns = time.monotonic_ns()
        self._say_started()
        announcer(mav.MAV_SEVERITY_INFO, "avoidd started")
        previous_threads = cv2.getNumThreads()
        cv2.setNumThreads(self.threads)
        for head in self.heads:
            head.start()
        tasks = [
            asyncio.create_task(head.compute(), name=f"compute-{head.name}") for head in self.heads
        ]
        tasks += [
            asyncio.create_task(coro, name=name) for name, coro in self._loops(announcer).items()
        ]
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
            if self.gcs is not None:
                await self.gcs.close()
            await self.link.close()
            self._timestamps.keep(self.codec.signing_timestamp, force=True)
            cv2.setNumThreads(previous_threads)
        logger.info("avoidd stopped; MAVLink %s", self.link.counters())
        return code

    def _say_started(self) -> None:
        mavlink = self.config.mavlink
        logger.info(
            "avoidd started: %d head(s) [%s], MAVLink %s as %s/%d%s",
            len(self.heads),
            ", ".join(h.name for h in self.heads),
            mavlink.link,
            mavlink.system_id,
            mavlink.component_id,
            ", signed" if mavlink.signing else "",
        )

    def _command(self, message: mav.Message) -> None:
        """A command for avoidd: its sender's signing timestamp is stored before it is acted on.

        So the same signed frame, sent again after a crash and restart, is a replay.
        """
        if self.codec.signature_check is not None and message.get_type() in _ACTIONS:
            self._timestamps.keep(self.codec.signing_timestamp, force=True)
        assert self.avoidance is not None
        self.avoidance.handle_command(message)

    def _loops(self, announcer: Announcer) -> dict[str, Coroutine[Any, Any, None]]:
        """The long-running loops besides the heads' compute tasks, by task name."""
        self.outputs = Outputs(
            self.config.mavlink,
            self.config.pipeline.max_age_ms,
            self.heads,
            self.link,
            self.vehicle,
        )
        loops = self.outputs.loops()
        # Always there, to answer the AVD_* parameters (AVD_ENABLE switches it in flight);
        # silent while avoidance is off.
        self.avoidance = AvoidanceLoop(
            self.config.avoidance,
            self.outputs,
            self.vehicle,
            self.link,
            self.announce,
            self.outputs.max_cm / 100.0,
            min((head.pipeline.thin_range_m for head in self.heads), default=None),
        )
        self.vehicle.on_command = self._command
        loops["avoidance"] = self.avoidance.run()
        loops["heartbeat"] = self._heartbeat_loop()
        loops["statustext"] = send_statustext(announcer, self.link, self._check_staleness)
        loops["log"] = log_every(
            self.config.pipeline.log_interval_s,
            lambda previous: self.snapshot(time.monotonic_ns(), previous),
        )
        loops["vehicle"] = self.vehicle.run()
        if self.config.mavlink.signing is not None:
            loops["signing"] = keep_timestamps(self.codec, self._timestamps)
        notifier = Notifier.from_environment()  # under systemd (Type=notify)
        if notifier is not None:
            reporter = ServiceReporter(
                notifier,
                self.config.service,
                self.heads,
                lambda previous: self.snapshot(time.monotonic_ns(), previous),
                watchdog_interval_s(),
            )
            loops["systemd"] = reporter.run()
        if self.config.debug_server.enabled:
            from avoidd.debugview.server import DebugServer  # aiohttp only when enabled

            self.debug_server = DebugServer(self.config.debug_server, self)
            loops["debug-server"] = self.debug_server.run()
        return loops

    def _stale_heads(self, now_ns: int) -> frozenset[str] | None:
        """Heads without fresh data, or None during the boot grace (see :mod:`.health`)."""
        latest = {h.name: h.t_capture_ns for h in self.heads}
        return health.stale_heads(latest, self._started_ns, now_ns, self._max_age_ns)

    async def _heartbeat_loop(self) -> None:
        period_s = 1.0 / self.config.mavlink.heartbeat_hz
        while True:
            self.link.send(self.codec.heartbeat(health.mav_state(self.heartbeat_stale())))
            await asyncio.sleep(period_s)

    def heartbeat_stale(self) -> frozenset[str] | None:
        """Heads the HEARTBEAT counts as stale (None at boot).

        The HEARTBEAT says CRITICAL as soon as a head's data is too old (within ``max_age_ms``
        of the last good frame), without the announcements' 0.5 s hold, and ACTIVE again only
        after 2 s of fresh data throughout: a head that keeps missing its deadline under load
        stays CRITICAL instead of flapping (see :class:`.health.Reported`).
        """
        if self._stale_heads(time.monotonic_ns()) is None:
            return None
        return frozenset(name for name, state in self._beat.items() if state.stale)

    def _check_staleness(self) -> None:
        """Report heads that went stale or recovered (with hysteresis), saying why."""
        now_ns = time.monotonic_ns()
        stale = self._stale_heads(now_ns)
        if stale is None:
            return
        for head in self.heads:
            beat = self._beat.setdefault(head.name, health.Reported(enter_hold_ns=0))
            beat.update(head.name in stale, now_ns)
        beat_before = self._heartbeat_state
        self._heartbeat_state = health.mav_state(self.heartbeat_stale())
        if self._heartbeat_state != beat_before:
            # Say the new state now rather than at the next periodic HEARTBEAT (up to 1 s on).
            self.link.send(self.codec.heartbeat(self._heartbeat_state))
        for head in self.heads:
            change = self._reported.setdefault(head.name, health.Reported()).update(
                head.name in stale, now_ns
            )
            if change is None:
                continue
            name = head.name
            if change:
                why = head.fault or health.stale_reason(
                    now_ns, head.last_frame_ns, head.arrival_age_ns, self._max_age_ns
                )
                logger.error("head '%s': data stale (%s); its sectors are unknown", name, why)
                self.announce(
                    mav.MAV_SEVERITY_CRITICAL, f"avoidd: {name} stale, {why}", f"fresh {name}"
                )
            else:
                logger.info("head '%s': data fresh again", name)
                self.announce(mav.MAV_SEVERITY_NOTICE, f"avoidd: {name} recovered", f"fresh {name}")
