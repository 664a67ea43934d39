"""What avoidd tells systemd: READY once every head delivers, STATUS, WATCHDOG while none is stuck.

The rules are pure (:class:`ProgressMonitor`, :func:`waiting_for`, :func:`status_line`); the
coroutine :meth:`ServiceReporter.run` applies them to the running heads and sends the result
through a :class:`~avoidd.daemon.notify.Notifier`:

- ``READY=1`` once every head has produced a result (the MAVLink link is open before this loop
  starts), or after ``service.ready_timeout_s`` anyway, with a ``STATUS=`` and a logged error
  naming the heads still waiting: a drone's avoidd that waits for a camera is better reporting
  "camera lost" to the autopilot than killed by the start timeout and restarted in a loop.
- ``STATUS=`` every ``service.status_interval_s``: per head rate, the autopilot, health.
- ``WATCHDOG=1`` every half ``WATCHDOG_USEC``, only while no head is stuck (see
  :class:`ProgressMonitor`). The pings come from this coroutine, so a wedged event loop stops
  them too. They resume when the heads recover before systemd's deadline.
- ``STOPPING=1`` when the daemon shuts down (this task is cancelled).
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

from avoidd.config import ServiceConfig
from avoidd.daemon.head import Head
from avoidd.daemon.notify import Notifier
from avoidd.daemon.stats import DaemonStats, LinkSnapshot

logger = logging.getLogger(__name__)

_TICK_BOOT_S = 0.05
"""Readiness is checked this often until READY (it only reads counters)."""
_TICK_S = 0.5
"""Afterwards, the longest time between checks (shorter for a short watchdog)."""


@dataclass(frozen=True)
class HeadProgress:
    """What the readiness and watchdog rules read of one head at an instant.

    Attributes:
        name: The head's name.
        captured: Frames its source has delivered since start.
        processed: Frames its compute has turned into a result since start.
        finished: Frames its compute is done with since start: results, and frames dropped as
            broken (the compute is alive either way; broken frames are reported elsewhere).
        reading_since_ns: When its source's read in progress started, None between reads.
    """

    name: str
    captured: int
    processed: int
    finished: int
    reading_since_ns: int | None

    @classmethod
    def of(cls, head: Head) -> HeadProgress:
        """Read a running head's counters."""
        stats = head.stats
        return cls(
            head.name,
            stats.captured,
            stats.processed,
            stats.processed + stats.broken,
            head.reading_since_ns,
        )


def waiting_for(heads: Sequence[HeadProgress]) -> dict[str, str]:
    """The heads without a result yet, each with what it waits for.

    Args:
        heads: Every head's progress.

    Returns:
        Per head still waiting, "no frame yet" (its source delivered nothing) or "no result
        yet" (frames came, none computed); empty once every head has produced a result.
    """
    return {
        h.name: "no frame yet" if h.captured == 0 else "no result yet"
        for h in heads
        if h.processed == 0
    }


class ProgressMonitor:
    """Decides which heads are stuck, from their counters sampled over time.

    A head is stuck when frames wait for its compute (its source delivered some since it last
    finished one) and it has finished none for ``stall_ns`` (a stalled matcher), or when its
    source's read has not returned for ``stall_ns`` (a wedged driver). A head whose camera is
    missing is not stuck: its capture thread reopens it with back-off and avoidd reports it
    (CRITICAL HEARTBEAT, STATUSTEXT); a restart would not bring the camera back.

    Args:
        stall_ns: How long without progress makes a head stuck.
        started_ns: When the heads started (the first result is due ``stall_ns`` after frames).
    """

    def __init__(self, stall_ns: int, started_ns: int) -> None:
        self._stall_ns = stall_ns
        self._started_ns = started_ns
        self._finished: dict[str, int] = {}
        self._progress_ns: dict[str, int] = {}
        self._captured_then: dict[str, int] = {}

    def update(self, heads: Sequence[HeadProgress], now_ns: int) -> dict[str, str]:
        """Take the heads' counters at ``now_ns``.

        Args:
            heads: Every head's progress.
            now_ns: The current monotonic time.

        Returns:
            Per stuck head, why (for the log and ``STATUS=``); empty when every head is fine.
        """
        stuck: dict[str, str] = {}
        for head in heads:
            name = head.name
            if head.finished != self._finished.get(name, 0):
                self._finished[name] = head.finished
                self._progress_ns[name] = now_ns
                self._captured_then[name] = head.captured
            idle_ns = now_ns - self._progress_ns.get(name, self._started_ns)
            frames_wait = head.captured > self._captured_then.get(name, 0)
            if frames_wait and idle_ns >= self._stall_ns:
                stuck[name] = f"no result for {idle_ns / 1e9:.0f} s while frames wait"
            elif head.reading_since_ns is not None:
                blocked_ns = now_ns - head.reading_since_ns
                if blocked_ns >= self._stall_ns:
                    stuck[name] = f"source read blocked for {blocked_ns / 1e9:.0f} s"
        return stuck


def _link_phrase(link: LinkSnapshot) -> str:
    mode = link.mode
    if not link.link_up or mode is None:
        return "no autopilot heard"
    armed = "armed" if mode.armed else "disarmed"
    return f"{mode.autopilot} sys {link.system_id} {mode.name} {armed}"


def status_line(stats: DaemonStats, stuck: Mapping[str, str], waiting: Mapping[str, str]) -> str:
    """The ``STATUS=`` text: per head rate, the autopilot, and health.

    Args:
        stats: A snapshot taken relative to the previous status line's.
        stuck: What :meth:`ProgressMonitor.update` returned.
        waiting: What :func:`waiting_for` returned.

    Returns:
        One line, e.g. "front 14.8 fps; ArduPilot sys 1 LOITER armed; ok".
    """
    rates = ", ".join(f"{h.name} {h.fps:.1f} fps" for h in stats.heads)
    if stuck:
        health = "STUCK " + ", ".join(f"{name}: {why}" for name, why in stuck.items())
        health += "; watchdog withheld"
    elif waiting:
        health = "waiting for " + ", ".join(f"{name} ({why})" for name, why in waiting.items())
    else:
        stale = [h.name for h in stats.heads if h.stale]
        health = f"stale: {', '.join(stale)}" if stale else "ok"
    return f"{rates}; {_link_phrase(stats.link)}; {health}"


class ServiceReporter:
    """Tells the service manager about readiness, status and liveness (see the module).

    Args:
        notifier: Where the notifications go.
        config: The ``service`` section.
        heads: The daemon's running heads.
        take: Takes a snapshot of the daemon relative to the given previous one.
        watchdog_s: The watchdog interval (``WATCHDOG_USEC``), None without a watchdog.

    Attributes:
        ready_ns: When ``READY=1`` was sent (monotonic), None before.
        pings: ``WATCHDOG=1`` pings sent.
    """

    def __init__(
        self,
        notifier: Notifier,
        config: ServiceConfig,
        heads: Sequence[Head],
        take: Callable[[DaemonStats | None], DaemonStats],
        watchdog_s: float | None,
    ) -> None:
        self._notifier = notifier
        self._config = config
        self._heads = heads
        self._take = take
        self._watchdog_s = watchdog_s
        self.ready_ns: int | None = None
        self.pings = 0
        self._stuck: dict[str, str] = {}
        self._waiting: dict[str, str] = {}

    async def run(self) -> None:
        """Report until cancelled, then send ``STOPPING=1``."""
        started_ns = time.monotonic_ns()
        config = self._config
        monitor = ProgressMonitor(int(config.stall_s * 1e9), started_ns)
        ping_ns = int(self._watchdog_s * 1e9 / 2) if self._watchdog_s is not None else None
        tick_s = _TICK_S if ping_ns is None else min(_TICK_S, ping_ns / 4e9)
        status_ns = int(config.status_interval_s * 1e9)
        next_status_ns = next_ping_ns = started_ns
        previous: DaemonStats | None = None
        if self._watchdog_s is not None:
            logger.info(
                "systemd watchdog: %.1f s; pinging every %.1f s",
                self._watchdog_s,
                self._watchdog_s / 2,
            )
        try:
            while True:
                now_ns = time.monotonic_ns()
                progress = [HeadProgress.of(head) for head in self._heads]
                stuck = monitor.update(progress, now_ns)
                waiting = waiting_for(progress)
                ready_now = self.ready_ns is None and (
                    not waiting or now_ns - started_ns >= config.ready_timeout_s * 1e9
                )
                if (
                    ready_now
                    or stuck.keys() != self._stuck.keys()
                    or waiting.keys() != self._waiting.keys()
                ):
                    next_status_ns = now_ns
                self._log_changes(stuck, waiting)
                if now_ns >= next_status_ns:
                    stats = self._take(previous)
                    previous = stats
                    fields = {"STATUS": status_line(stats, stuck, waiting)}
                    if ready_now:
                        fields = {"READY": "1", **fields}
                        self.ready_ns = now_ns
                        self._log_ready(now_ns - started_ns, waiting)
                    self._notifier.notify(**fields)
                    next_status_ns = now_ns + status_ns
                if (
                    ping_ns is not None
                    and self.ready_ns is not None
                    and now_ns >= next_ping_ns
                    and not stuck
                    and self._notifier.notify(WATCHDOG="1")
                ):
                    self.pings += 1
                    next_ping_ns = now_ns + ping_ns
                await asyncio.sleep(_TICK_BOOT_S if self.ready_ns is None else tick_s)
        finally:
            self._notifier.notify(STOPPING="1", STATUS="stopping")
            self._notifier.close()

    def _log_ready(self, after_ns: int, waiting: Mapping[str, str]) -> None:
        if not waiting:
            logger.info("ready after %.2f s: every head delivers; told systemd", after_ns / 1e9)
            return
        missing = ", ".join(f"'{name}' ({why})" for name, why in waiting.items())
        logger.error(
            "not ready after %.0f s: head %s; telling systemd READY anyway so that avoidd keeps "
            "reporting; check the camera",
            after_ns / 1e9,
            missing,
        )

    def _log_changes(self, stuck: dict[str, str], waiting: dict[str, str]) -> None:
        if stuck.keys() != self._stuck.keys():
            for name, why in stuck.items():
                if name not in self._stuck:
                    logger.error(
                        "head '%s' stuck: %s; withholding the systemd watchdog ping (systemd "
                        "restarts avoidd if this lasts)",
                        name,
                        why,
                    )
            for name in self._stuck.keys() - stuck.keys():
                logger.info("head '%s' makes progress again", name)
        if self.ready_ns is not None and self._waiting and not waiting:
            logger.info("every head delivers now")
        self._stuck, self._waiting = stuck, waiting
