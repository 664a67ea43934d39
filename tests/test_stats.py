"""The daemon's stats snapshot and the periodic log line built from it."""

from __future__ import annotations

from collections import Counter, deque
from types import SimpleNamespace
from typing import Any

import pytest

from avoidd.daemon.head import HeadStats
from avoidd.daemon.stats import DaemonStats, HeadSnapshot, LinkSnapshot, log_line, snapshot
from avoidd.mavlink.modes import FlightMode
from avoidd.types import Nearest

MS = 1_000_000


def _head(name: str, processed: int, skipped: int, broken: int, latency_ms: list[float]) -> Any:
    stats = HeadStats(captured=processed + skipped, processed=processed, broken=broken)
    stats.latency_ms = deque(latency_ms, maxlen=256)
    return SimpleNamespace(
        name=name,
        stats=stats,
        slot=SimpleNamespace(skipped=skipped),
        t_capture_ns=None,
        latest=None,
        fresh_scan=lambda now_ns, max_age_ns: None,
    )


def _link() -> Any:
    return SimpleNamespace(
        sent=Counter({"OBSTACLE_DISTANCE": 120, "HEARTBEAT": 5}),
        received=Counter({"HEARTBEAT": 5, "ATTITUDE": 200}),
        dropped=Counter({"OBSTACLE_DISTANCE": 2}),
        parse_errors=1,
        signature_rejects=0,
    )


def test_snapshot_counts_and_rates_over_the_interval() -> None:
    heads = [_head("front", 10, 1, 0, []), _head("rear", 20, 0, 1, [40.0, 60.0])]
    vehicle = SimpleNamespace(link_up=False, system_id=None, mode=None)
    first = snapshot(heads, _link(), vehicle, 1_000 * MS, 300 * MS)
    assert first.interval_s == 0.0 and first.heads[0].fps == 0.0
    assert first.heads[1].mean_latency_ms == 50.0 and first.heads[0].mean_latency_ms == 0.0
    heads[0].stats.processed += 50
    heads[0].slot.skipped += 3
    heads[1].stats.broken += 2
    second = snapshot(heads, _link(), vehicle, 6_000 * MS, 300 * MS, first)
    front, rear = second.heads
    assert second.interval_s == 5.0
    assert (front.processed, front.processed_in_interval, front.fps) == (60, 50, 10.0)
    assert (front.skipped, front.skipped_in_interval) == (4, 3)
    assert (rear.broken, rear.broken_in_interval, rear.fps) == (3, 2, 0.0)
    assert front.stale and rear.stale
    assert not second.fresh_data and second.nearest is None
    assert second.link.sent["OBSTACLE_DISTANCE"] == 120
    assert (second.link.received, second.link.dropped, second.link.parse_errors) == (205, 2, 1)


def _stats(link: LinkSnapshot, fresh_data: bool, nearest: Nearest | None) -> DaemonStats:
    head = HeadSnapshot(
        name="front",
        captured=100,
        processed=75,
        skipped=20,
        broken=5,
        source_errors=0,
        restarts=0,
        processed_in_interval=74,
        skipped_in_interval=3,
        broken_in_interval=1,
        fps=14.8,
        mean_latency_ms=61.4,
        stale=False,
    )
    return DaemonStats(
        t_ns=0,
        interval_s=5.0,
        heads=(head, head),
        link=link,
        fresh_data=fresh_data,
        nearest=nearest,
    )


def test_log_line_reads_as_before() -> None:
    down = LinkSnapshot(False, None, None, {"OBSTACLE_DISTANCE": 75}, 0, 3, 0, 0)
    assert log_line(_stats(down, False, None)) == (
        "front: 14.8 fps, skipped 3, dropped 1, latency 61 ms; "
        "front: 14.8 fps, skipped 3, dropped 1, latency 61 ms; "
        "no fresh data; sent 75; no autopilot heard; "
        "rx 0, dropped 3, parse errors 0, unsigned rejected 0"
    )
    mode = FlightMode("ArduPilot", 2, "GUIDED", True, True)
    up = LinkSnapshot(True, 1, mode, {}, 1234, 0, 2, 7)
    assert log_line(_stats(up, True, Nearest(3.456, -15.0))).endswith(
        "; nearest 3.46 m at -15 deg; sent 0; link up: ArduPilot sys 1 GUIDED armed; "
        "rx 1234, dropped 0, parse errors 2, unsigned rejected 7"
    )
    assert "; nearest none; " in log_line(_stats(up, True, None))


def test_the_latency_histogram_counts_each_frame_in_its_bucket_cumulatively() -> None:
    from avoidd.daemon.latency import LATENCY_BUCKETS_S, LatencyHistogram

    histogram = LatencyHistogram()
    for latency_s in (0.01, 0.05, 0.06, 0.3, 7.0):
        histogram.observe(latency_s)
    buckets = dict(histogram.cumulative())
    assert len(buckets) == len(LATENCY_BUCKETS_S) + 1
    assert buckets[0.025] == 1 and buckets[0.05] == 2  # le: at or below the bound
    assert buckets[0.075] == 3 and buckets[0.3] == 4 and buckets[2.0] == 4
    assert buckets[float("inf")] == histogram.count == 5
    assert histogram.sum_s == pytest.approx(7.42)


def test_the_recent_frame_rate_falls_when_frames_stop() -> None:
    from avoidd.daemon.latency import FrameRate

    rate = FrameRate()
    assert rate.per_second(0) == 0.0
    for k in range(21):  # 10 Hz for 2 s
        rate.tick(k * 100_000_000)
    assert rate.per_second(2_000_000_000) == pytest.approx(10.0)
    assert rate.per_second(4_000_000_000) == pytest.approx(5.0)  # 20 frames over 4 s
    assert rate.per_second(8_000_000_000) == 0.0  # none in the last 5 s
