"""Operator messages: a thread-safe, coalescing queue and the loop that sends it as STATUSTEXT."""

from __future__ import annotations

import asyncio
import contextlib
from collections import deque
from collections.abc import Callable

from avoidd.mavlink.link import MavLink

STATUSTEXT_MIN_INTERVAL_S = 0.5
"""Spacing between two STATUSTEXT messages."""

_IDLE_POLL_S = 0.05


class Announcer:
    """Thread-safe queue of operator messages, sent as STATUSTEXT by the event loop.

    Rate-limited without hiding state: the sender spaces messages 0.5 s apart, and a message
    about a subject (a camera, a head's freshness, the link) that is still waiting replaces the
    older one in place, so a flapping camera yields its latest state, not a backlog.

    Args:
        loop: The event loop that owns the queue; calls from any thread land through it.

    Attributes:
        pending: Messages waiting to be sent, as (severity, text, key).
        wakeup: Set when a message is added.
        coalesced: Messages that replaced a waiting one about the same subject.
    """

    def __init__(self, loop: asyncio.AbstractEventLoop) -> None:
        self._loop = loop
        self.pending: deque[tuple[int, str, str | None]] = deque(maxlen=32)
        self.wakeup = asyncio.Event()
        self.coalesced = 0

    def __call__(self, severity: int, text: str, key: str | None = None) -> None:
        """Queue one message (from any thread); ``key`` names its subject for coalescing."""
        self._loop.call_soon_threadsafe(self._add, severity, text, key)

    def _add(self, severity: int, text: str, key: str | None) -> None:
        if key is not None:
            for index, (_, _, pending_key) in enumerate(self.pending):
                if pending_key == key:
                    self.pending[index] = (severity, text, key)
                    self.coalesced += 1
                    return
        self.pending.append((severity, text, key))
        self.wakeup.set()


async def send_statustext(
    announcer: Announcer, link: MavLink, before_each: Callable[[], None]
) -> None:
    """Send what ``announcer`` holds as STATUSTEXT, spaced, until cancelled.

    Args:
        announcer: The queue to drain.
        link: Where to send (its codec builds the messages).
        before_each: Called before every drain, at least every 50 ms (the daemon checks its
            heads' freshness there, so that a head going stale is announced promptly).
    """
    loop = asyncio.get_running_loop()
    while True:
        before_each()
        while announcer.pending:
            severity, text, _ = announcer.pending.popleft()
            link.send(link.codec.statustext(severity, text))
            # Spaced, but the checks go on meanwhile: a head going stale while a message
            # waits out its spacing must not be noticed 0.5 s late.
            next_s = loop.time() + STATUSTEXT_MIN_INTERVAL_S
            while (wait_s := next_s - loop.time()) > 0:
                await asyncio.sleep(min(wait_s, _IDLE_POLL_S))
                before_each()
        announcer.wakeup.clear()
        with contextlib.suppress(TimeoutError):  # asyncio.timeout: see outputs.when_ready
            async with asyncio.timeout(_IDLE_POLL_S):
                await announcer.wakeup.wait()
