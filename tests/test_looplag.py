"""The loop-lag monitor: load from other processes is accounted for, blocking is not."""

from __future__ import annotations

import asyncio
import subprocess
import sys
import time

from avoidd.looplag import LagMonitor

BUSY = "import time\nend = time.monotonic() + 20\nwhile time.monotonic() < end: pass\n"


async def _measure(block_s: float, seconds: float) -> LagMonitor:
    lag = LagMonitor()
    task = asyncio.create_task(lag.run())
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        await asyncio.sleep(0.05)
        if block_s:
            time.sleep(block_s)  # what a blocking call in a callback does to the loop
    task.cancel()
    await asyncio.gather(task, return_exceptions=True)
    return lag


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
