"""One log line per state change: repeats of the same problem are counted and summarised.

A fault that recurs every frame (a deleted input folder, a refused connection) would otherwise
write a line per frame or per retry and bury everything else in the log.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

SUMMARY_INTERVAL_S = 60.0
"""Repeats of one state are summarised at most this often."""


class RepeatLimiter:
    """Logs the first report of a state, then one summary line per interval while it lasts.

    Args:
        logger: Where the lines go.
        summary_interval_s: Least time between summary lines of one state.
        clock: Monotonic seconds (injectable for tests).
    """

    def __init__(
        self,
        logger: logging.Logger,
        summary_interval_s: float = SUMMARY_INTERVAL_S,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self._logger = logger
        self._interval_s = summary_interval_s
        self._clock = clock
        self._state: str | None = None
        self._level = logging.INFO
        self._last = ""
        self._repeats = 0
        self._since_s = 0.0

    @property
    def state(self) -> str | None:
        """The state being reported, None when all is well."""
        return self._state

    def report(self, level: int, state: str, text: str) -> bool:
        """Report ``text`` as an instance of ``state``.

        Args:
            level: Logging level of the lines.
            state: What kind of problem this is; a change of state is logged at once.
            text: The full message of this instance.

        Returns:
            True when this report started a new state (the caller may announce it too).
        """
        now_s = self._clock()
        if state != self._state:
            self._flush(now_s)
            self._state, self._level, self._last = state, level, text
            self._repeats, self._since_s = 0, now_s
            self._logger.log(level, "%s", text)
            return True
        self._repeats += 1
        self._last = text
        if now_s - self._since_s >= self._interval_s:
            self._flush(now_s)
            self._since_s = now_s
        return False

    def clear(self, text: str | None = None, level: int = logging.INFO) -> bool:
        """The problem is over: summarise outstanding repeats and log ``text`` (if any).

        Returns:
            True when there was a problem to clear.
        """
        if self._state is None:
            return False
        self._flush(self._clock())
        self._state = None
        if text is not None:
            self._logger.log(level, "%s", text)
        return True

    def _flush(self, now_s: float) -> None:
        if self._state is None or self._repeats == 0:
            return
        self._logger.log(
            self._level,
            "%s (repeated %d times in the last %.0f s)",
            self._last,
            self._repeats,
            now_s - self._since_s,
        )
        self._repeats = 0
