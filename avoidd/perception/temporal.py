"""Per-bin filter between frames: persistence for new obstacles, fast attack, bounded hold."""

from __future__ import annotations

import numpy as np

from avoidd.config import TemporalConfig
from avoidd.types import SECTOR_COUNT, SectorScan


class SectorFilter:
    """Filters the scans of one head frame by frame.

    Rules, per bin:

    - a new obstacle (a finite reading in a bin without a confirmed one) is reported once it was
      seen in ``confirm_frames`` of the last ``window_frames`` frames; until then the bin is
      unknown, because the frame can vouch neither for an obstacle nor for clear space;
    - once confirmed, every new finite reading is taken at once (an approaching obstacle is
      never delayed);
    - a confirmed obstacle that vanishes (the bin reads clear or unknown) keeps its last
      distance for at most ``hold_ms`` after the frame that measured it; the reading keeps its
      own capture time, so the sender's age limit applies to it as to any other;
    - until it has seen ``confirm_frames`` frames since it started or was reset (a recording
      that starts over), every bin is unknown: no obstacle can be confirmed yet, and the bins
      measured clear beside one would tell the autopilot the way is free (ArduPilot reads an
      unknown bin as nothing; the first message after a start or a loop had the obstacle's
      bins unknown between clear ones).

    Args:
        config: The filter parameters.
    """

    def __init__(self, config: TemporalConfig) -> None:
        self._k = config.confirm_frames
        self._hold_ns = config.hold_ms * 1_000_000
        self._seen = np.zeros((config.window_frames, SECTOR_COUNT), dtype=np.bool_)
        self._next = 0
        self._distance = np.full(SECTOR_COUNT, np.nan, dtype=np.float32)
        self._points = np.full((SECTOR_COUNT, 3), np.nan, dtype=np.float32)
        self._t_ns = np.zeros(SECTOR_COUNT, dtype=np.int64)
        self._frames = 0
        """Frames seen since the start or the last reset (counted up to ``confirm_frames``)."""

    @property
    def warming_up(self) -> bool:
        """Whether too few frames were seen to confirm an obstacle (every bin is unknown)."""
        return self._frames < self._k

    def reset(self) -> None:
        """Forget every bin (the source restarted): the warm-up starts again."""
        self._seen[:] = False
        self._distance[:] = np.nan
        self._points[:] = np.nan
        self._frames = 0

    def update(self, scan: SectorScan) -> SectorScan:
        """Filter the newest scan of the head.

        Args:
            scan: The raw scan of a new frame (frames must come in capture order).

        Returns:
            The filtered scan, with the capture time of every bin's reading.
        """
        t_ns = scan.t_capture_ns
        raw = scan.distance_m
        raw_points = (
            scan.points_frd_m
            if scan.points_frd_m is not None
            else np.full((SECTOR_COUNT, 3), np.nan, dtype=np.float32)
        )
        seen = np.isfinite(raw)
        self._seen[self._next] = seen
        self._next = (self._next + 1) % self._seen.shape[0]
        persistent = np.count_nonzero(self._seen, axis=0) >= self._k
        active = np.isfinite(self._distance) & (t_ns - self._t_ns <= self._hold_ns)

        confirmed = seen & (persistent | active)
        held = ~seen & active
        pending = seen & ~confirmed

        distance = raw.astype(np.float32, copy=True)
        points = raw_points.astype(np.float32, copy=True)
        times = np.full(SECTOR_COUNT, t_ns, dtype=np.int64)
        distance[pending] = np.nan
        points[pending] = np.nan
        distance[held] = self._distance[held]
        points[held] = self._points[held]
        times[held] = self._t_ns[held]

        self._distance[confirmed] = raw[confirmed]
        self._points[confirmed] = raw_points[confirmed]
        self._t_ns[confirmed] = t_ns
        expired = ~confirmed & ~held
        self._distance[expired] = np.nan
        self._points[expired] = np.nan
        self._frames = min(self._frames + 1, self._k)
        if self._frames < self._k:
            distance[:] = np.nan
            points[:] = np.nan
        return SectorScan(t_ns, distance, points, times)
