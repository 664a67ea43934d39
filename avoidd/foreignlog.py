"""Errors that are not avoidd's own, logged as one line per kind with a count, never a flood.

aiohttp logs a traceback for every malformed HTTP request (100 requests made 1,105 lines), and
the event loop one for every failed ``accept()`` while the process is out of file descriptors
(18,935 in 10 s). Neither is avoidd's fault nor news after the first: :class:`ForeignErrors`
says the first of each kind in one line, without the traceback, then how many more came, at
most once per :data:`SUMMARY_INTERVAL_S`, and what is still uncounted when it is closed.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

logger = logging.getLogger(__name__)

SUMMARY_INTERVAL_S = 60.0
"""Repeats of one kind are summarised at most this often."""
MAX_KINDS = 32
"""Kinds counted one by one; the rest are counted together."""
FOREIGN_LOGGERS = ("aiohttp.server", "aiohttp.web", "aiohttp.access", "aiohttp.internal")
"""aiohttp's loggers whose warnings and errors are summarised (the debug view's server)."""


@dataclass
class _Kind:
    repeats: int = 0
    since_s: float = 0.0
    total: int = 1


def _exception_text(exc: BaseException | None) -> str:
    if exc is None:
        return ""
    text = " ".join(str(exc).split())
    text = text if len(text) <= 120 else text[:117] + "..."
    return f": {type(exc).__name__}" + (f" ({text})" if text else "")


class ForeignErrors(logging.Filter):
    """Turns the records of foreign loggers and the loop's error reports into counted lines.

    As a filter on a foreign logger it drops every warning or error record (and any with a
    traceback) and logs it here instead; as the event loop's exception handler it does the
    same for the loop's reports.

    Args:
        clock: Monotonic seconds (injectable for tests).

    Attributes:
        counts: Reports seen, by kind (the capped table; the overflow under ``"others"``).
    """

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        super().__init__()
        self._clock = clock
        self._kinds: dict[str, _Kind] = {}

    @property
    def counts(self) -> dict[str, int]:
        """Every kind seen so far and how often."""
        return {name: kind.total for name, kind in self._kinds.items()}

    def report(self, source: str, message: str, exc: BaseException | None) -> None:
        """Count one report; the first of its kind is logged at once, in one line."""
        key = f"{source}: {message.split(' from ')[0]}{_exception_text(exc).split(' (')[0]}"
        if key not in self._kinds and len(self._kinds) >= MAX_KINDS:
            key = "others"
        now_s = self._clock()
        kind = self._kinds.get(key)
        if kind is None:
            self._kinds[key] = _Kind(since_s=now_s)
            logger.error(
                "%s: %s%s (not avoidd's; repeats are counted, summarised every %.0f s)",
                source,
                message,
                _exception_text(exc),
                SUMMARY_INTERVAL_S,
            )
            return
        kind.repeats += 1
        kind.total += 1
        if now_s - kind.since_s >= SUMMARY_INTERVAL_S:
            self._summarise(key, kind, now_s)

    def _summarise(self, key: str, kind: _Kind, now_s: float) -> None:
        if kind.repeats:
            logger.error(
                "%s: %d more in the last %.0f s (%d in all)",
                key,
                kind.repeats,
                now_s - kind.since_s,
                kind.total,
            )
        kind.repeats = 0
        kind.since_s = now_s

    def flush(self) -> None:
        """Log what is counted and not yet said (at shutdown)."""
        now_s = self._clock()
        for key, kind in self._kinds.items():
            self._summarise(key, kind, now_s)

    def filter(self, record: logging.LogRecord) -> bool:
        """Let a foreign logger's INFO and DEBUG lines through; count the rest here."""
        if record.levelno < logging.WARNING and record.exc_info is None:
            return True
        exc = record.exc_info[1] if record.exc_info else None
        self.report(record.name, record.getMessage(), exc)
        return False

    def loop_handler(self, loop: asyncio.AbstractEventLoop, context: dict[str, Any]) -> None:
        """An event loop exception handler (``loop.set_exception_handler``)."""
        exc = context.get("exception")
        self.report(
            "asyncio",
            str(context.get("message", "error")),
            exc if isinstance(exc, BaseException) else None,
        )


def install(loop: asyncio.AbstractEventLoop) -> ForeignErrors:
    """Summarise aiohttp's loggers and the loop's error reports until :func:`uninstall`."""
    errors = ForeignErrors()
    for name in FOREIGN_LOGGERS:
        logging.getLogger(name).addFilter(errors)
    loop.set_exception_handler(errors.loop_handler)
    return errors


def uninstall(loop: asyncio.AbstractEventLoop, errors: ForeignErrors) -> None:
    """Say what is still counted and give the loggers and the loop their own handling back."""
    errors.flush()
    for name in FOREIGN_LOGGERS:
        logging.getLogger(name).removeFilter(errors)
    loop.set_exception_handler(None)
