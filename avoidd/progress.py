"""A one-line progress bar on stderr (only when stderr is a terminal)."""

from __future__ import annotations

import sys
from typing import TextIO


class Progress:
    """Shows ``[#####-----] done/total label`` and rewrites it in place.

    Args:
        total: Number of steps.
        stream: Where to draw (default stderr); nothing is drawn unless it is a terminal.
    """

    def __init__(self, total: int, stream: TextIO | None = None, width: int = 30) -> None:
        self.total = max(total, 1)
        self.done = 0
        self._stream = stream if stream is not None else sys.stderr
        self._width = width
        self._active = self._stream.isatty()

    def step(self, label: str) -> None:
        """Count one step done and redraw."""
        self.done += 1
        if not self._active:
            return
        filled = round(self._width * self.done / self.total)
        bar = "#" * filled + "-" * (self._width - filled)
        self._stream.write(f"\r[{bar}] {self.done}/{self.total} {label[:40]:<40}")
        if self.done >= self.total:
            self._stream.write("\n")
        self._stream.flush()
