"""A latest-wins hand-off of capacity one from a producer thread to an asyncio consumer."""

from __future__ import annotations

import asyncio
import threading
from typing import Generic, TypeVar

T = TypeVar("T")


class LatestSlot(Generic[T]):
    """Holds at most one item; a new item replaces an unconsumed one, which counts as skipped.

    ``put`` may be called from any thread; ``get`` must be awaited in the slot's event loop.

    Args:
        loop: The event loop of the consumer.
    """

    def __init__(self, loop: asyncio.AbstractEventLoop) -> None:
        self._loop = loop
        self._lock = threading.Lock()
        self._item: T | None = None
        self._ready = asyncio.Event()
        self.put_count = 0
        self.skipped = 0

    def put(self, item: T) -> None:
        """Offer an item (thread-safe); an item not yet taken is overwritten and counted."""
        with self._lock:
            if self._item is not None:
                self.skipped += 1
            self._item = item
            self.put_count += 1
        self._loop.call_soon_threadsafe(self._ready.set)

    async def get(self) -> T:
        """Wait for an item and take it."""
        while True:
            await self._ready.wait()
            with self._lock:
                self._ready.clear()
                item, self._item = self._item, None
            if item is not None:
                return item
