"""The daemon's counters in one frozen snapshot, and the periodic log line built from it.

One :class:`DaemonStats` is meant to feed every view of the running daemon (the log line here;
later a web view, metrics, a service manager's status line), so that they agree.
"""

from __future__ import annotations

import asyncio
import logging
import statistics
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType

from avoidd.daemon.head import Head
from avoidd.daemon.health import is_fresh
from avoidd.daemon.outputs import current_scan
from avoidd.mavlink.link import MavLink
from avoidd.mavlink.modes import FlightMode
from avoidd.mavlink.vehicle import Vehicle
from avoidd.types import Nearest

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class HeadSnapshot:
    """One head's counters at a snapshot.

    Attributes:
        name: The head's name.
        captured: Frames read from the source since start.
        processed: Frames processed since start.
        skipped: Frames replaced in the slot before being processed, since start.
        broken: Frames dropped as broken (by the source or the pipeline), since start.
        source_errors: Failed opens and lost sources since start.
        restarts: Times the source came back after being lost.
        processed_in_interval: Frames processed since the previous snapshot.
        skipped_in_interval: Frames skipped since the previous snapshot.
        broken_in_interval: Frames dropped as broken since the previous snapshot.
        fps: Frames processed per second since the previous snapshot (0.0 without one).
        mean_latency_ms: Mean capture-to-result time of the last processed frames (0.0 before
            the first).
        stale: Whether the head has no fresh data (regardless of the boot grace).
        stage_ms: Milliseconds of each pipeline stage on the latest processed frame (empty
            before the first).
        recent_fps: Frames processed per second over the last 5 s (what a scrape without a
            previous snapshot can tell).
        latency_buckets: Capture-to-result times since start, ``(upper bound in seconds,
            frames at or below it)`` per bucket, the last bound ``inf``.
        latency_sum_s: Their sum.
    """

    name: str
    captured: int
    processed: int
    skipped: int
    broken: int
    source_errors: int
    restarts: int
    processed_in_interval: int
    skipped_in_interval: int
    broken_in_interval: int
    fps: float
    mean_latency_ms: float
    stale: bool
    stage_ms: Mapping[str, float] = field(default_factory=lambda: MappingProxyType({}))
    recent_fps: float = 0.0
    latency_buckets: tuple[tuple[float, int], ...] = ()
    latency_sum_s: float = 0.0


@dataclass(frozen=True)
class LinkSnapshot:
    """The MAVLink link and the autopilot on it at a snapshot.

    Attributes:
        link_up: Whether the autopilot is heard.
        system_id: The autopilot's system id, None before discovery.
        mode: The autopilot's state from its last heartbeat, None before the first.
        sent: Messages sent, by type (read-only).
        received: Messages received, all types.
        dropped: Messages dropped from the send queue, all types.
        parse_errors: Incoming bytes that did not decode.
        signature_rejects: Incoming messages refused for a missing or wrong signature.
    """

    link_up: bool
    system_id: int | None
    mode: FlightMode | None
    sent: Mapping[str, int]
    received: int
    dropped: int
    parse_errors: int
    signature_rejects: int


@dataclass(frozen=True)
class DaemonStats:
    """Everything the daemon reports about itself, at one instant.

    Attributes:
        t_ns: When the snapshot was taken (monotonic clock).
        interval_s: Time since the previous snapshot, 0.0 without one.
        heads: Per head, in configuration order.
        link: The link and the autopilot.
        fresh_data: Whether any head has fresh data (the merged scan exists).
        nearest: The nearest obstacle of the merged scan, None if none or no fresh data.
        planner: The avoidance loop's state in a phrase (None when there is none).
    """

    t_ns: int
    interval_s: float
    heads: tuple[HeadSnapshot, ...]
    link: LinkSnapshot
    fresh_data: bool
    nearest: Nearest | None
    planner: str | None = None


def snapshot(
    heads: Sequence[Head],
    link: MavLink,
    vehicle: Vehicle,
    now_ns: int,
    max_age_ns: int,
    previous: DaemonStats | None = None,
    planner: str | None = None,
) -> DaemonStats:
    """Take a snapshot of the daemon's counters.

    Args:
        heads: The daemon's heads.
        link: Its MAVLink link.
        vehicle: The autopilot on that link.
        now_ns: The current monotonic time.
        max_age_ns: Age beyond which a head's data is stale (``pipeline.max_age_ms``).
        previous: The snapshot the interval counts and rates are relative to; without one
            they count from start and rates are 0.0.
        planner: The avoidance loop's state (see ``AvoidanceLoop.summary``).

    Returns:
        The snapshot.
    """
    before = {h.name: h for h in previous.heads} if previous is not None else {}
    interval_s = (now_ns - previous.t_ns) / 1e9 if previous is not None else 0.0
    head_stats = []
    for head in heads:
        processed, skipped, broken = head.stats.processed, head.slot.skipped, head.stats.broken
        latency_ms = head.stats.latency_ms
        latest = head.latest
        old = before.get(head.name)
        processed_in = processed - (old.processed if old is not None else 0)
        head_stats.append(
            HeadSnapshot(
                name=head.name,
                captured=head.stats.captured,
                processed=processed,
                skipped=skipped,
                broken=broken,
                source_errors=head.stats.source_errors,
                restarts=head.stats.restarts,
                processed_in_interval=processed_in,
                skipped_in_interval=skipped - (old.skipped if old is not None else 0),
                broken_in_interval=broken - (old.broken if old is not None else 0),
                fps=processed_in / interval_s if interval_s > 0 else 0.0,
                mean_latency_ms=statistics.fmean(latency_ms) if latency_ms else 0.0,
                stale=not is_fresh(head.t_capture_ns, now_ns, max_age_ns),
                stage_ms=MappingProxyType(dict(latest.timing_ms) if latest is not None else {}),
                recent_fps=head.stats.rate.per_second(now_ns),
                latency_buckets=head.stats.latency.cumulative(),
                latency_sum_s=head.stats.latency.sum_s,
            )
        )
    scan = current_scan(heads, now_ns, max_age_ns)
    return DaemonStats(
        t_ns=now_ns,
        interval_s=interval_s,
        heads=tuple(head_stats),
        link=LinkSnapshot(
            link_up=vehicle.link_up,
            system_id=vehicle.system_id,
            mode=vehicle.mode,
            sent=MappingProxyType(dict(link.sent)),
            received=sum(link.received.values()),
            dropped=sum(link.dropped.values()),
            parse_errors=link.parse_errors,
            signature_rejects=link.signature_rejects,
        ),
        fresh_data=scan is not None,
        nearest=scan.nearest() if scan is not None else None,
        planner=planner,
    )


def link_summary(link: LinkSnapshot) -> str:
    """One phrase on the link: vehicle state and error counters."""
    mode = link.mode
    if not link.link_up or mode is None:
        # Not "link down": the messages are sent all the same (udpout), nothing answers.
        state = "no autopilot heard"
    else:
        state = (
            f"link up: {mode.autopilot} sys {link.system_id} {mode.name} "
            f"{'armed' if mode.armed else 'disarmed'}"
        )
    return (
        f"{state}; rx {link.received}, dropped {link.dropped}, "
        f"parse errors {link.parse_errors}, unsigned rejected {link.signature_rejects}"
    )


def log_line(stats: DaemonStats) -> str:
    """The periodic status line: per head rate, skips, drops and latency; nearest; the link.

    Args:
        stats: A snapshot taken relative to the previous line's.

    Returns:
        The line, without a trailing newline.
    """
    parts = [
        f"{h.name}: {h.fps:.1f} fps, skipped {h.skipped_in_interval}, "
        f"dropped {h.broken_in_interval}, latency {h.mean_latency_ms:.0f} ms"
        for h in stats.heads
    ]
    nearest = stats.nearest
    if nearest is not None:
        where = f"nearest {nearest.distance_m:.2f} m at {nearest.bearing_deg:+.0f} deg"
    else:
        where = "nearest none" if stats.fresh_data else "no fresh data"
    sent = stats.link.sent.get("OBSTACLE_DISTANCE", 0)
    line = f"{'; '.join(parts)}; {where}; sent {sent}; {link_summary(stats.link)}"
    return f"{line}; {stats.planner}" if stats.planner else line


async def log_every(interval_s: float, take: Callable[[DaemonStats | None], DaemonStats]) -> None:
    """Log :func:`log_line` every ``interval_s``, forever.

    Args:
        interval_s: Period of the line.
        take: Takes a snapshot relative to the given previous one.
    """
    previous = take(None)
    while True:
        await asyncio.sleep(interval_s)
        current = take(previous)
        logger.info("%s", log_line(current))
        previous = current
