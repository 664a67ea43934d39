"""A one-line progress bar on stderr (only when stderr is a terminal)."""

from __future__ import annotations

import sys
import time
from types import TracebackType
from typing import TextIO

_REDRAW_S = 0.1


class Progress:
    """Shows ``[#####-----] done/total label`` and rewrites it in place.

    Nothing is drawn unless the stream is a terminal, so CI logs and pipes stay clean. Without a
    known total it shows the count and the rate instead of a bar. Redraws are limited to ten a
    second; the last step and :meth:`close` always draw. Use it as a context manager (or call
    :meth:`close`) so that a run that ends early still finishes the line.

    Args:
        total: Number of steps, or None when unknown.
        stream: Where to draw (default stderr); nothing is drawn unless it is a terminal.
        width: Characters of the bar.
    """

    def __init__(self, total: int | None, stream: TextIO | None = None, width: int = 30) -> None:
        self.total = None if total is None else max(total, 1)
        self.done = 0
        self._stream = stream if stream is not None else sys.stderr
        self._width = width
        try:
            self._active = self._stream.isatty()
        except (AttributeError, ValueError):  # a closed or stream-like object without a tty
            self._active = False
        self._started = time.monotonic()
        self._drawn_at = 0.0
        self._open = False
        self._label = ""

    @property
    def active(self) -> bool:
        """Whether the bar is drawn (the stream is a terminal)."""
        return self._active

    def step(self, label: str = "") -> None:
        """Count one step done and redraw."""
        self.done += 1
        self._label = label
        if not self._active:
            return
        now = time.monotonic()
        last = self.total is not None and self.done >= self.total
        if not last and now - self._drawn_at < _REDRAW_S and self.done > 1:
            return
        self._draw(now)
        if last:
            self._finish()

    def _draw(self, now: float) -> None:
        self._drawn_at = now
        label = f"{self._label[:40]:<40}"
        if self.total is not None:
            filled = round(self._width * min(self.done, self.total) / self.total)
            bar = "#" * filled + "-" * (self._width - filled)
            text = f"\r[{bar}] {self.done}/{self.total} {label}"
        else:
            rate = self.done / max(now - self._started, 1e-9)
            text = f"\r{self.done} done, {rate:.1f}/s {label}"
        self._stream.write(text)
        self._stream.flush()
        self._open = True

    def _finish(self) -> None:
        if self._open:
            self._stream.write("\n")
            self._stream.flush()
            self._open = False

    def close(self) -> None:
        """End the line (drawing the final count) if anything was drawn."""
        if self._active and self._open:
            self._draw(time.monotonic())
            self._finish()

    def __enter__(self) -> Progress:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self.close()
