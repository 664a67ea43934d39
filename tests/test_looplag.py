"""The loop-lag monitor: load from other processes is accounted for, blocking is not."""

from __future__ import annotations

import asyncio
import json
import subprocess
import sys
from dataclasses import dataclass

BUSY = "import time\nend = time.monotonic() + 20\nwhile time.monotonic() < end: pass\n"


MEASURE = """
import asyncio, json, sys, time
from avoidd.looplag import LagMonitor

import gc

async def main(block_s, seconds, heap):
    kept = [[i] for i in range(heap)]  # objects a full garbage collection has to visit
    lag = LagMonitor()
    task = asyncio.create_task(lag.run())
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        await asyncio.sleep(0.05)
        if block_s:
            time.sleep(block_s)  # what a blocking call in a callback does to the loop
        if heap:
            gc.collect()  # a collector pause, as any allocation may start one
    task.cancel()
    await asyncio.gather(task, return_exceptions=True)
    worst = lag.worst
    print(json.dumps([lag.accounted, lag.samples, lag.max_lag_ms, lag.max_own_lag_ms,
                      worst.gc_ms if worst else 0.0, len(kept)]))

asyncio.run(main(float(sys.argv[1]), float(sys.argv[2]), int(sys.argv[3])))
"""


@dataclass
class Measured:
    """What a LagMonitor reported."""

    accounted: bool
    samples: int
    max_lag_ms: float
    max_own_lag_ms: float
    worst_gc_ms: float
    heap: int


async def _measure(block_s: float, seconds: float, heap: int = 0) -> Measured:
    """Run the monitor in a process of its own: threads other tests left running in this one
    would otherwise wait in the run queue under load and be counted as the machine's load."""
    process = await asyncio.create_subprocess_exec(
        sys.executable,
        "-c",
        MEASURE,
        str(block_s),
        str(seconds),
        str(heap),
        stdout=asyncio.subprocess.PIPE,
    )
    out, _ = await process.communicate()
    assert process.returncode == 0
    return Measured(*json.loads(out))


async def test_blocking_in_the_loop_counts_as_own_lag_even_under_load() -> None:
    busy = [subprocess.Popen([sys.executable, "-c", BUSY]) for _ in range(3)]
    try:
        blocked = await _measure(0.06, 1.0)
        quiet = await _measure(0.0, 1.0)
    finally:
        for process in busy:
            process.kill()
            process.wait()
    assert blocked.accounted and quiet.accounted
    assert blocked.samples > 5 and quiet.samples > 20
    # A 60 ms sleep in the loop is 60 ms of lag that no CPU wait explains...
    assert blocked.max_own_lag_ms >= 45.0, blocked.max_own_lag_ms
    # ...while the same load without it leaves the own lag far below the raw lag's worst.
    assert quiet.max_own_lag_ms < 45.0, (quiet.max_lag_ms, quiet.max_own_lag_ms)


async def test_garbage_collection_pauses_are_counted_apart_from_the_loops_own_lag() -> None:
    collecting = await _measure(0.0, 1.5, heap=1_500_000)
    blocked = await _measure(0.06, 1.0, heap=0)
    assert collecting.accounted and collecting.samples > 5
    # Full collections over a million and a half objects make the loop late (tens of
    # milliseconds here; less on a faster machine)...
    assert collecting.max_lag_ms >= 10.0, collecting.max_lag_ms
    # ...which are the collector's pauses, not the loop's own lateness...
    assert collecting.max_own_lag_ms < 0.5 * collecting.max_lag_ms, collecting
    # ...while a blocking call is no garbage collection.
    assert blocked.max_own_lag_ms >= 45.0 and blocked.worst_gc_ms < 5.0, blocked
