"""The frame source interface and the pacing shared by sources that are not cameras."""

from __future__ import annotations

import time
from typing import Protocol

from avoidd.types import StereoFrame


class FrameSource(Protocol):
    """Something that delivers stereo frames, one blocking ``read`` at a time.

    ``read`` raises :class:`avoidd.errors.SourceExhausted` after the last frame of a finite
    source, :class:`avoidd.errors.BrokenFrame` for a single unusable frame (the next read may
    succeed) and :class:`avoidd.errors.SourceError` when the source is lost (close and reopen).
    """

    @property
    def description(self) -> str:
        """What the source reads, for logs and errors."""
        ...

    def read(self) -> StereoFrame:
        """Block until the next frame and return it."""
        ...

    def close(self) -> None:
        """Release devices and files."""
        ...


class Pacer:
    """Spaces frames at a fixed rate, without bursting to catch up after a stall.

    Args:
        fps: Target rate.
    """

    def __init__(self, fps: float) -> None:
        self._period_ns = int(1e9 / fps)
        self._next_ns: int | None = None

    def wait(self) -> int:
        """Sleep until the next frame slot and return the monotonic time of that slot in ns."""
        now = time.monotonic_ns()
        if self._next_ns is None or now - self._next_ns > self._period_ns:
            self._next_ns = now
        elif self._next_ns > now:
            time.sleep((self._next_ns - now) / 1e9)
        slot = self._next_ns
        self._next_ns += self._period_ns
        return max(slot, time.monotonic_ns())
