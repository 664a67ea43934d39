"""OBSTACLE_DISTANCE leaves as soon as a scan is made (issue 51 item 2), within its rate.

Before, a scan waited for the next 15 Hz send tick. ``when_ready`` sends on each new scan, at
most ``rate_hz`` times a second, and repeats the last message when no new scan comes. Only
orderings and bounds with wide margins are asserted here; the latency figures are measured
by ``avoidd bench --daemon``.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import time

from avoidd.daemon.outputs import when_ready


def _fresh(sent: list[float]) -> bool:
    sent.append(time.monotonic())
    return True


async def _run_for(coroutine: object, seconds: float) -> None:
    task = asyncio.ensure_future(coroutine)  # type: ignore[call-overload]
    await asyncio.sleep(seconds)
    task.cancel()
    with contextlib.suppress(asyncio.CancelledError):
        await task


async def test_a_new_scan_is_sent_at_once_not_at_the_next_repeat() -> None:
    ready = asyncio.Event()
    sent: list[float] = []
    task = asyncio.ensure_future(when_ready(ready, 15.0, lambda: _fresh(sent), 30.0))
    await asyncio.sleep(0.3)
    assert len(sent) == 1  # the first call goes at once; the next repeat is 30 s away
    ready.set()
    for _ in range(200):  # up to 10 s on a loaded machine, still far before the repeat
        if len(sent) == 2:
            break
        await asyncio.sleep(0.05)
    task.cancel()
    with contextlib.suppress(asyncio.CancelledError):
        await task
    assert len(sent) == 2
    assert not ready.is_set()  # taken


async def test_scans_faster_than_the_rate_are_sent_at_the_rate_at_most() -> None:
    ready = asyncio.Event()
    sent: list[float] = []

    async def flood() -> None:
        while True:
            ready.set()
            await asyncio.sleep(0.001)

    flooding = asyncio.ensure_future(flood())
    await _run_for(when_ready(ready, 10.0, lambda: _fresh(sent)), 1.0)
    flooding.cancel()
    gaps = [b - a for a, b in itertools.pairwise(sent)]
    assert len(sent) <= 11
    assert gaps and min(gaps) >= 0.1 - 0.005


async def test_without_new_scans_the_message_is_repeated() -> None:
    ready = asyncio.Event()
    sent: list[float] = []
    await _run_for(when_ready(ready, 50.0, lambda: _fresh(sent), 0.05), 1.0)
    assert len(sent) >= 4  # 20 expected idle; a loaded machine may stall a few
    gaps = [b - a for a, b in itertools.pairwise(sent)]
    assert min(gaps) >= 0.05 - 0.005  # not more often than asked either


async def test_without_fresh_data_the_message_goes_at_the_full_rate() -> None:
    # PX4's all-unknown message (no fresh scan) must keep coming at rate_hz, not at the
    # repeat interval of fresh data.
    ready = asyncio.Event()
    sent: list[float] = []

    def unknown() -> bool:
        sent.append(time.monotonic())
        return False

    await _run_for(when_ready(ready, 20.0, unknown, 10.0), 1.0)
    assert len(sent) >= 8  # 20 expected idle; a loaded machine may stall some
    gaps = [b - a for a, b in itertools.pairwise(sent)]
    assert min(gaps) >= 0.05 - 0.005


async def test_a_stop_that_lands_as_a_scan_is_ready_ends_the_loop() -> None:
    # The daemon stops by cancelling its loops. On Python 3.11 asyncio.wait_for swallows a
    # cancellation that lands in the same turn as the event it waits on is set, and the loop
    # went on for ever (a daemon stop hung for 30 s once in CI).
    sent: list[float] = []
    for _ in range(3):
        ready = asyncio.Event()
        task = asyncio.ensure_future(when_ready(ready, 15.0, lambda: _fresh(sent), 30.0))
        await asyncio.sleep(0.2)  # waiting for the next scan
        ready.set()
        task.cancel()
        done, _ = await asyncio.wait([task], timeout=2.0)
        assert task in done and task.cancelled()
