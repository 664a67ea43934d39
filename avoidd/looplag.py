"""Event-loop lag, split into what the machine's load caused and what the loop's own work did.

A task that sleeps ``period_s`` and wakes late measures lag. On a shared machine most of that
lateness can be the kernel giving the CPU to another process: the loop thread was ready to run
but waited in the run queue. Linux counts that wait per thread (``run_delay``, the second field
of ``/proc/<pid>/task/<tid>/schedstat``). A thread of the process that the kernel preempts
while it holds the GIL makes the loop thread wait too, off the run queue; its own run-queue
wait bounds that. The interpreter's garbage collector holds the GIL while it runs, whatever the
loop was doing; its CPU time is taken (``gc.callbacks``) and counted apart, since its length
follows the size of the whole process's heap (in a test, the whole suite's). Lag minus
those waits and pauses is the part the process itself caused (a blocking call in the loop,
heavy work in a callback). Where schedstat is missing, the own lag is the lag minus the pauses.
"""

from __future__ import annotations

import asyncio
import contextlib
import gc
import os
import threading
import time
from dataclasses import dataclass
from typing import Any


def _read_schedstat_ns(fd: int) -> tuple[int, int] | None:
    """A thread's cumulative time on a CPU and time waiting for one (ns)."""
    try:
        fields = os.pread(fd, 128, 0).split()
        return int(fields[0]), int(fields[1])
    except (OSError, IndexError, ValueError):
        return None


def _read_run_delay_ns(fd: int) -> int | None:
    stat = _read_schedstat_ns(fd)
    return None if stat is None else stat[1]


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

    def own_cpu_ns(self) -> int | None:
        """The calling thread's cumulative time on a CPU, or None if unknown."""
        fd = self._fds.get(self._own_tid)
        stat = _read_schedstat_ns(fd) if fd is not None else None
        return None if stat is None else stat[0]

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


class _GcPauses:
    """CPU time the garbage collector has run since ``start`` (ns), on any thread.

    A collection holds the GIL throughout: on the loop thread it stops the loop, on another
    it keeps the loop from running Python (as a thread preempted holding the GIL does; a
    collection that overlaps a call of the loop's that had released the GIL is subtracted
    too, the same over-count as for run-queue waits: a blocking call in the loop shows on
    every occurrence, not only where it overlaps one). CPU time, not wall time: a
    collection's own waits for a CPU are already the load.
    """

    def __init__(self) -> None:
        self.total_ns = 0
        self._began_ns: dict[int, int] = {}

    def _callback(self, phase: str, info: dict[str, Any]) -> None:
        now_ns = time.thread_time_ns()
        thread = threading.get_native_id()
        if phase == "start":
            self._began_ns[thread] = now_ns
        elif (began_ns := self._began_ns.pop(thread, None)) is not None:
            self.total_ns += now_ns - began_ns

    def start(self) -> None:
        """Begin timing the collector's runs."""
        gc.callbacks.append(self._callback)

    def stop(self) -> None:
        """Stop timing."""
        with contextlib.suppress(ValueError):
            gc.callbacks.remove(self._callback)


@dataclass(frozen=True)
class LagSample:
    """One wake-up's lateness and what explains it.

    Attributes:
        lag_ms: How late the wake-up came (wall clock).
        load_ms: Of it, time the loop thread (and the longest-waiting other thread) waited for
            a CPU; None without schedstat.
        gc_ms: CPU time the garbage collector ran meanwhile (on any thread: it holds the
            GIL).
        own_ms: What is left: the loop's own doing.
        loop_cpu_ms: Time the loop thread spent on a CPU meanwhile, collections included
            (near ``own_ms + gc_ms``: the loop was busy computing; near 0: it was blocked, on
            a call or on the GIL); None without schedstat.
    """

    lag_ms: float
    load_ms: float | None
    gc_ms: float
    own_ms: float
    loop_cpu_ms: float | None

    def describe(self) -> str:
        """The breakdown in one line."""
        load = "unknown" if self.load_ms is None else f"{self.load_ms:.1f}"
        cpu = "unknown" if self.loop_cpu_ms is None else f"{self.loop_cpu_ms:.1f}"
        return (
            f"{self.lag_ms:.1f} ms late: {load} ms waiting for a CPU, {self.gc_ms:.1f} ms of "
            f"garbage collection, {self.own_ms:.1f} ms the loop's own "
            f"(loop thread on a CPU {cpu} ms)"
        )


class LagMonitor:
    """Measures how late the event loop wakes a task that sleeps ``period_s`` at a time.

    Attributes:
        max_lag_ms: Largest lateness seen (wall clock).
        max_own_lag_ms: Largest lateness left after removing the time spent waiting for a
            CPU (the machine's load) by the loop thread and by the longest-waiting other thread
            of the process (which may have held the GIL) and the garbage collector's pauses.
        worst: The breakdown of the wake-up with the largest own lateness.
        samples: Wake-ups measured.
        accounted: Whether the load could be accounted for (schedstat readable).
    """

    def __init__(self, period_s: float = 0.005) -> None:
        self.period_s = period_s
        self.max_lag_ms = 0.0
        self.max_own_lag_ms = 0.0
        self.samples = 0
        self.accounted = False
        self.worst: LagSample | None = None

    def reset(self) -> None:
        """Forget the lag seen so far."""
        self.max_lag_ms = 0.0
        self.max_own_lag_ms = 0.0
        self.samples = 0
        self.worst = None

    async def run(self) -> None:
        """Sleep and measure until cancelled (must run in the loop being measured)."""
        delays = _RunDelays()
        pauses = _GcPauses()
        pauses.start()
        try:
            while True:
                waited0 = delays.read_ns()
                cpu0_ns = delays.own_cpu_ns()
                gc0_ns = pauses.total_ns
                started = time.perf_counter()
                await asyncio.sleep(self.period_s)
                lag_ms = (time.perf_counter() - started - self.period_s) * 1000.0
                load_ms = _load_ms(waited0, delays.read_ns())
                cpu1_ns = delays.own_cpu_ns()
                gc_ms = (pauses.total_ns - gc0_ns) / 1e6
                own_ms = lag_ms - gc_ms
                if load_ms is not None:
                    own_ms -= load_ms
                    self.accounted = True
                self.max_lag_ms = max(self.max_lag_ms, lag_ms)
                if self.worst is None or own_ms > self.worst.own_ms:
                    cpu_ms = None
                    if cpu0_ns is not None and cpu1_ns is not None:
                        cpu_ms = (cpu1_ns - cpu0_ns) / 1e6
                    self.worst = LagSample(lag_ms, load_ms, gc_ms, own_ms, cpu_ms)
                    self.max_own_lag_ms = max(self.max_own_lag_ms, own_ms)
                self.samples += 1
        finally:
            pauses.stop()
            delays.close()
