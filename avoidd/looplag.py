"""Event-loop lag, split into what the machine's load caused and what the loop's own work did.

A task that sleeps ``period_s`` and wakes late measures lag. On a shared machine most of that
lateness can be the kernel giving the CPU to another process: the loop thread was ready to run
but waited in the run queue. Linux counts that wait per thread (``run_delay``, the second field
of ``/proc/<pid>/task/<tid>/schedstat``). A thread of the process that the kernel preempts
while it holds the GIL makes the loop thread wait too, off the run queue; its own run-queue
wait bounds that. Lag minus those waits is the part the process itself caused (a blocking call
in the loop, heavy work in a callback). Where schedstat is missing, the own lag is the whole
lag.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import threading
import time


def _read_run_delay_ns(fd: int) -> int | None:
    try:
        return int(os.pread(fd, 128, 0).split()[1])
    except (OSError, IndexError, ValueError):
        return None


class _RunDelays:
    """Reads the cumulative run-queue wait (ns) of this process's threads from schedstat.

    The calling thread is the one measured; the others are the ones that may hold the GIL
    while the kernel has them waiting for a CPU (the loop thread then waits for the GIL).
    """

    def __init__(self) -> None:
        self._own_tid = threading.get_native_id()
        self._fds: dict[int, int] = {}
        self._listed_s = 0.0
        self._refresh()

    def _refresh(self) -> None:
        self._listed_s = time.monotonic()
        try:
            tids = {int(name) for name in os.listdir("/proc/self/task")}
        except OSError:
            tids = set()
        for tid in set(self._fds) - tids:
            os.close(self._fds.pop(tid))
        for tid in tids - set(self._fds):
            with contextlib.suppress(OSError):
                self._fds[tid] = os.open(f"/proc/self/task/{tid}/schedstat", os.O_RDONLY)

    def read_ns(self) -> tuple[int, dict[int, int]] | None:
        """The calling thread's wait and every other thread's, or None if unknown."""
        if time.monotonic() - self._listed_s > 0.5:
            self._refresh()
        own = self._fds.get(self._own_tid)
        own_ns = _read_run_delay_ns(own) if own is not None else None
        if own_ns is None:
            return None
        others: dict[int, int] = {}
        for tid, fd in self._fds.items():
            if tid != self._own_tid and (value := _read_run_delay_ns(fd)) is not None:
                others[tid] = value
        return own_ns, others

    def close(self) -> None:
        """Release the files."""
        for fd in self._fds.values():
            os.close(fd)
        self._fds.clear()


def _load_ms(
    before: tuple[int, dict[int, int]] | None, after: tuple[int, dict[int, int]] | None
) -> float | None:
    """Milliseconds of a lag explained by waiting for a CPU.

    That is the loop thread's own wait plus the longest wait of another thread (one that may
    have held the GIL meanwhile).
    """
    if before is None or after is None:
        return None
    others = [after[1][tid] - ns for tid, ns in before[1].items() if tid in after[1]]
    return (after[0] - before[0] + max(others, default=0)) / 1e6


class LagMonitor:
    """Measures how late the event loop wakes a task that sleeps ``period_s`` at a time.

    Attributes:
        max_lag_ms: Largest lateness seen (wall clock).
        max_own_lag_ms: Largest lateness left after removing the time spent waiting for a
            CPU (the machine's load) by the loop thread and by the longest-waiting other thread
            of the process (which may have held the GIL); equals ``max_lag_ms`` without
            schedstat.
        samples: Wake-ups measured.
        accounted: Whether the load could be accounted for (schedstat readable).
    """

    def __init__(self, period_s: float = 0.005) -> None:
        self.period_s = period_s
        self.max_lag_ms = 0.0
        self.max_own_lag_ms = 0.0
        self.samples = 0
        self.accounted = False

    def reset(self) -> None:
        """Forget the lag seen so far."""
        self.max_lag_ms = 0.0
        self.max_own_lag_ms = 0.0
        self.samples = 0

    async def run(self) -> None:
        """Sleep and measure until cancelled (must run in the loop being measured)."""
        delays = _RunDelays()
        try:
            while True:
                waited0 = delays.read_ns()
                started = time.perf_counter()
                await asyncio.sleep(self.period_s)
                lag_ms = (time.perf_counter() - started - self.period_s) * 1000.0
                load_ms = _load_ms(waited0, delays.read_ns())
                own_ms = lag_ms
                if load_ms is not None:
                    own_ms = lag_ms - load_ms
                    self.accounted = True
                self.max_lag_ms = max(self.max_lag_ms, lag_ms)
                self.max_own_lag_ms = max(self.max_own_lag_ms, own_ms)
                self.samples += 1
        finally:
            delays.close()
