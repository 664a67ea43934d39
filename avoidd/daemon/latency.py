"""A head's capture-to-result times as a histogram, and its recent frame rate.

Both are written by the head's compute task once per processed frame and read by snapshots
(the status line, ``/api/stats``, ``/metrics``); plain integers and a bounded deque, so a
reader in another thread sees at worst one frame's update half done.
"""

from __future__ import annotations

import bisect
from collections import deque

LATENCY_BUCKETS_S = (0.025, 0.05, 0.075, 0.1, 0.15, 0.2, 0.3, 0.5, 1.0, 2.0)
"""Upper bounds of the histogram's buckets (a last one, +Inf, holds the rest): a frame is
processed in 20-100 ms on a companion computer, and the autopilots drop data older than
0.5 s."""

_RATE_WINDOW_NS = 5_000_000_000
"""The recent frame rate counts the frames of this long before now."""


class LatencyHistogram:
    """Cumulative counts of capture-to-result times since start, Prometheus style."""

    def __init__(self) -> None:
        self._counts = [0] * (len(LATENCY_BUCKETS_S) + 1)
        self.sum_s = 0.0
        self.count = 0

    def observe(self, latency_s: float) -> None:
        """Count one frame's capture-to-result time."""
        self._counts[bisect.bisect_left(LATENCY_BUCKETS_S, latency_s)] += 1
        self.sum_s += latency_s
        self.count += 1

    def cumulative(self) -> tuple[tuple[float, int], ...]:
        """``(upper bound, frames at or below it)`` per bucket, the last bound ``inf``."""
        bounds = (*LATENCY_BUCKETS_S, float("inf"))
        total, out = 0, []
        for bound, count in zip(bounds, list(self._counts), strict=True):
            total += count
            out.append((bound, total))
        return tuple(out)


class FrameRate:
    """Frames processed per second over the last few seconds."""

    def __init__(self) -> None:
        self._t_ns: deque[int] = deque(maxlen=512)

    def tick(self, now_ns: int) -> None:
        """One frame processed now."""
        self._t_ns.append(now_ns)

    def per_second(self, now_ns: int) -> float:
        """The rate over the window before ``now_ns`` (0.0 with fewer than two frames)."""
        recent = [t for t in list(self._t_ns) if now_ns - t <= _RATE_WINDOW_NS]
        if len(recent) < 2:
            return 0.0
        span_ns = max(now_ns - recent[0], recent[-1] - recent[0])
        return (len(recent) - 1) / (span_ns / 1e9) if span_ns > 0 else 0.0
