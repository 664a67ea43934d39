"""Prometheus metrics and the ``/api/stats`` record, both from one daemon snapshot.

Nothing is counted twice: a scrape takes a :class:`~avoidd.daemon.stats.DaemonStats` and
turns it into metric families (base units: seconds, ``_total`` counters, ``avoidd_`` names).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping
from typing import Any

from prometheus_client.core import (
    CounterMetricFamily,
    GaugeMetricFamily,
    HistogramMetricFamily,
    Metric,
)
from prometheus_client.registry import Collector

from avoidd.daemon.stats import DaemonStats, HeadSnapshot

_HEAD_COUNTERS = (
    ("captured", "avoidd_frames_captured", "Frames read from the head's source."),
    ("processed", "avoidd_frames_processed", "Frames processed by the head's pipeline."),
    ("skipped", "avoidd_frames_skipped", "Frames replaced before being processed."),
    ("broken", "avoidd_frames_broken", "Frames dropped as unreadable or unusable."),
    ("source_errors", "avoidd_source_errors", "Failed opens and lost sources."),
    ("restarts", "avoidd_source_restarts", "Times the source came back after being lost."),
)


class DaemonCollector(Collector):
    """Collects the daemon's metrics from a fresh snapshot at every scrape.

    Args:
        take: Takes a snapshot now.
        extra: Further counters by metric name (without ``_total``) with their help text and
            value, e.g. the debug view's own JPEG encodings.
    """

    def __init__(
        self,
        take: Callable[[], DaemonStats],
        extra: Callable[[], Mapping[str, tuple[str, float]]] | None = None,
    ) -> None:
        self._take = take
        self._extra = extra

    def describe(self) -> Iterator[Metric]:
        """Nothing up front: the registry then does not scrape at registration."""
        return iter(())

    def collect(self) -> Iterator[Metric]:
        """The metric families of a snapshot taken now."""
        stats = self._take()
        yield from _head_metrics(stats.heads)
        yield from _link_metrics(stats)
        if self._extra is not None:
            for name, (documentation, value) in self._extra().items():
                counter = CounterMetricFamily(name, documentation)
                counter.add_metric([], value)
                yield counter


def _head_metrics(heads: tuple[HeadSnapshot, ...]) -> Iterator[Metric]:
    for attribute, name, documentation in _HEAD_COUNTERS:
        family = CounterMetricFamily(name, documentation, labels=["head"])
        for head in heads:
            family.add_metric([head.name], getattr(head, attribute))
        yield family
    latency = GaugeMetricFamily(
        "avoidd_latency_seconds",
        "Mean capture-to-result time of the head's last processed frames.",
        labels=["head"],
    )
    stale = GaugeMetricFamily(
        "avoidd_head_stale", "1 when the head has no fresh data, else 0.", labels=["head"]
    )
    stage = GaugeMetricFamily(
        "avoidd_stage_seconds",
        "Time each pipeline stage took on the head's latest frame.",
        labels=["head", "stage"],
    )
    fps = GaugeMetricFamily(
        "avoidd_head_fps",
        "Frames the head processed per second over the last 5 s.",
        labels=["head"],
    )
    histogram = HistogramMetricFamily(
        "avoidd_capture_to_result_seconds",
        "Capture-to-result time of every frame the head processed since start.",
        labels=["head"],
    )
    for head in heads:
        latency.add_metric([head.name], head.mean_latency_ms / 1000.0)
        stale.add_metric([head.name], 1.0 if head.stale else 0.0)
        fps.add_metric([head.name], round(head.recent_fps, 3))
        for name, ms in head.stage_ms.items():
            stage.add_metric([head.name, name], ms / 1000.0)
        if head.latency_buckets:
            buckets = [(_bound(le), count) for le, count in head.latency_buckets]
            histogram.add_metric([head.name], buckets, head.latency_sum_s)
    yield from (latency, stale, stage, fps, histogram)


def _bound(upper_s: float) -> str:
    """A bucket's ``le`` label as Prometheus writes it."""
    return "+Inf" if upper_s == float("inf") else f"{upper_s:g}"


def _link_metrics(stats: DaemonStats) -> Iterator[Metric]:
    link = stats.link
    sent = CounterMetricFamily(
        "avoidd_mavlink_sent_messages", "MAVLink messages sent, by type.", labels=["type"]
    )
    for kind, count in sorted(link.sent.items()):
        sent.add_metric([kind], count)
    yield sent
    for name, documentation, value in (
        ("avoidd_mavlink_received_messages", "MAVLink messages received.", link.received),
        ("avoidd_mavlink_dropped_messages", "Messages dropped from the send queue.", link.dropped),
        ("avoidd_mavlink_parse_errors", "Incoming bytes that did not decode.", link.parse_errors),
        (
            "avoidd_mavlink_signature_rejects",
            "Incoming messages refused for a missing or wrong signature.",
            link.signature_rejects,
        ),
    ):
        counter = CounterMetricFamily(name, documentation)
        counter.add_metric([], value)
        yield counter
    mode = link.mode
    for name, documentation, value in (
        ("avoidd_link_up", "1 while the autopilot is heard.", link.link_up),
        ("avoidd_armed", "1 while the vehicle is armed.", mode is not None and mode.armed),
        ("avoidd_fresh_data", "1 while some head has fresh data.", stats.fresh_data),
    ):
        gauge = GaugeMetricFamily(name, documentation)
        gauge.add_metric([], 1.0 if value else 0.0)
        yield gauge
    nearest = GaugeMetricFamily(
        "avoidd_nearest_obstacle_meters",
        "Distance of the nearest obstacle in the merged scan (absent when none).",
    )
    if stats.nearest is not None:
        nearest.add_metric([], stats.nearest.distance_m)
    yield nearest


def _rate(now: int, before: int | None, interval_s: float) -> float:
    if before is None or interval_s <= 0:
        return 0.0
    return round((now - before) / interval_s, 2)


def stats_record(stats: DaemonStats, previous: DaemonStats | None) -> dict[str, Any]:
    """The JSON of ``/api/stats``: per head rates and stage times, the link, the planner.

    Args:
        stats: The snapshot now.
        previous: An earlier snapshot the rates are measured against (rates 0 without one).

    Returns:
        A JSON-ready dict.
    """
    before = {h.name: h for h in previous.heads} if previous is not None else {}
    interval_s = (stats.t_ns - previous.t_ns) / 1e9 if previous is not None else 0.0
    heads = []
    for head in stats.heads:
        old = before.get(head.name)
        heads.append(
            {
                "name": head.name,
                "captured_fps": _rate(head.captured, old.captured if old else None, interval_s),
                "processed_fps": _rate(head.processed, old.processed if old else None, interval_s),
                "skipped_fps": _rate(head.skipped, old.skipped if old else None, interval_s),
                "captured": head.captured,
                "processed": head.processed,
                "skipped": head.skipped,
                "broken": head.broken,
                "source_errors": head.source_errors,
                "restarts": head.restarts,
                "mean_latency_ms": round(head.mean_latency_ms, 1),
                "stage_ms": {k: round(v, 2) for k, v in head.stage_ms.items()},
                "stale": head.stale,
            }
        )
    link = stats.link
    mode = link.mode
    nearest = stats.nearest
    return {
        "interval_s": round(interval_s, 3),
        "heads": heads,
        "link": {
            "up": link.link_up,
            "system_id": link.system_id,
            "autopilot": mode.autopilot if mode is not None else None,
            "mode": mode.name if mode is not None else None,
            "armed": mode.armed if mode is not None else None,
            "sent": dict(link.sent),
            "received": link.received,
            "dropped": link.dropped,
            "parse_errors": link.parse_errors,
            "signature_rejects": link.signature_rejects,
        },
        "fresh_data": stats.fresh_data,
        "healthy": stats.fresh_data and not any(h.stale for h in stats.heads),
        "nearest": (
            None
            if nearest is None
            else {"distance_m": round(nearest.distance_m, 3), "bearing_deg": nearest.bearing_deg}
        ),
        "planner": stats.planner,
    }
