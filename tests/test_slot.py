from __future__ import annotations

import asyncio
import threading

from avoidd.slot import LatestSlot


async def test_latest_wins_and_overwrites_are_counted() -> None:
    slot: LatestSlot[int] = LatestSlot(asyncio.get_running_loop())
    for value in range(5):
        slot.put(value)
    assert await slot.get() == 4
    assert slot.skipped == 4 and slot.put_count == 5
    slot.put(9)
    assert await slot.get() == 9
    assert slot.skipped == 4


async def test_put_from_a_thread_wakes_the_consumer() -> None:
    slot: LatestSlot[str] = LatestSlot(asyncio.get_running_loop())
    waiter = asyncio.create_task(slot.get())
    await asyncio.sleep(0.01)
    assert not waiter.done()
    thread = threading.Thread(target=slot.put, args=("frame",))
    thread.start()
    assert await asyncio.wait_for(waiter, timeout=2.0) == "frame"
    thread.join()


async def test_get_waits_for_a_new_item() -> None:
    slot: LatestSlot[int] = LatestSlot(asyncio.get_running_loop())
    slot.put(1)
    assert await slot.get() == 1
    second = asyncio.create_task(slot.get())
    await asyncio.sleep(0.05)
    assert not second.done()
    slot.put(2)
    assert await asyncio.wait_for(second, timeout=2.0) == 2
