"""One MAVLink link: a transport, its codec, a bounded send queue with one sender, and counters.

Everything here runs in the event loop. Messages are built anywhere in the loop but packed only
by the link's sender task, which owns the sequence counter and the signing timestamp.
HEARTBEAT and STATUSTEXT jump the queue, so that health reaches the autopilot even when the link
is saturated.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections import Counter, deque
from collections.abc import Callable

from avoidd.aio import cancel_task
from avoidd.config.connection import LinkSpec
from avoidd.mavlink.codec import Codec, Message
from avoidd.mavlink.transport import Transport, create_transport

logger = logging.getLogger(__name__)

URGENT_TYPES = frozenset({"HEARTBEAT", "STATUSTEXT"})

Handler = Callable[[Message, int], None]
"""Called with every decoded message and its local monotonic receive time (ns)."""


class MavLink:
    """A MAVLink 2 link driven from asyncio.

    Args:
        spec: Where the link goes.
        codec: The link's codec (its ids and signing).
        queue_size: Messages waiting to be sent beyond which the oldest ordinary one is dropped.
    """

    def __init__(self, spec: LinkSpec, codec: Codec, queue_size: int = 64) -> None:
        self.spec = spec
        self.codec = codec
        self.transport: Transport = create_transport(spec, self._on_bytes)
        self.sent: Counter[str] = Counter()
        self.received: Counter[str] = Counter()
        self.dropped: Counter[str] = Counter()
        self.handler_errors = 0
        self.bytes_received = 0
        self._urgent: deque[Message] = deque()
        self._normal: deque[Message] = deque()
        self._queue_size = queue_size
        self._wake = asyncio.Event()
        self._handlers: list[Handler] = []
        self._sender: asyncio.Task[None] | None = None

    @property
    def connected(self) -> bool:
        """Whether bytes sent now can leave (a UDP-in link needs to have heard its peer)."""
        return self.transport.connected

    @property
    def parse_errors(self) -> int:
        """Bytes that did not decode, counted per bad chunk or frame."""
        return self.codec.parse_errors

    @property
    def signature_rejects(self) -> int:
        """Incoming messages refused because their signature was missing or wrong."""
        return self.codec.signature_rejects

    def subscribe(self, handler: Handler) -> None:
        """Call ``handler`` with every message decoded from now on."""
        self._handlers.append(handler)

    async def open(self) -> None:
        """Open the transport and start the sender.

        Raises:
            LinkError: The transport cannot start (a bad address, a busy port).
        """
        await self.transport.open()
        self._sender = asyncio.create_task(self._send_loop(), name=f"send {self.spec}")

    async def close(self) -> None:
        """Stop the sender and close the transport (queued messages are dropped)."""
        await cancel_task(self._sender)
        self._sender = None
        await self.transport.close()

    def send(self, message: Message) -> None:
        """Queue a message; never blocks. A full queue drops its oldest ordinary message."""
        kind = message.get_type()
        queue = self._urgent if kind in URGENT_TYPES else self._normal
        if len(queue) >= self._queue_size:
            self.dropped[queue.popleft().get_type()] += 1
        queue.append(message)
        self._wake.set()

    async def _send_loop(self) -> None:
        while True:
            await self._wake.wait()
            self._wake.clear()
            while self._urgent or self._normal:
                message = self._urgent.popleft() if self._urgent else self._normal.popleft()
                kind = message.get_type()
                if self.transport.send(self.codec.pack(message)):
                    self.sent[kind] += 1
                else:
                    self.dropped[kind] += 1

    def _on_bytes(self, data: bytes) -> None:
        received_ns = time.monotonic_ns()
        self.bytes_received += len(data)
        for message in self.codec.decode(data):
            self.received[message.get_type()] += 1
            for handler in self._handlers:
                try:
                    handler(message, received_ns)
                except Exception:
                    # A handler bug must not take the link down; it is counted and logged.
                    self.handler_errors += 1
                    logger.exception("MAVLink %s: handler failed on %s", self.spec, message)

    def counters(self) -> dict[str, object]:
        """Counters for logs and tests: sent/received/dropped by type and error counts."""
        return {
            "sent": dict(self.sent),
            "received": dict(self.received),
            "dropped": dict(self.dropped),
            "parse_errors": self.parse_errors,
            "signature_rejects": self.signature_rejects,
            "handler_errors": self.handler_errors,
        }
