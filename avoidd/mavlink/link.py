"""One MAVLink link: a transport, its codec, a bounded send queue with one sender, and counters.

Everything here runs in the event loop. Messages are built anywhere in the loop but packed only
by the link's sender task, which owns the sequence counter and the signing timestamp.
HEARTBEAT and STATUSTEXT jump the queue, so that health reaches the autopilot even when the link
is saturated.

Every sender (a UDP address; a stream has one) has a parser of its own. A ``udpin`` link sends
nothing until the vehicle tracker says which sender the autopilot speaks from
(:meth:`MavLink.autopilot_spoke`, on a heartbeat it adopts); from then on the link belongs to
it, as a mavlink-router endpoint does: replies go there only, and what other senders send is
counted and dropped unread. The adopted address is not replaced while it is heard; once it has
been silent for the link timeout, other senders are heard again, so an autopilot that
restarted on a new port is found. With ``mavlink.autopilot_address`` only that address is ever
heard. A sender not adopted is decoded only up to its budget (:mod:`avoidd.mavlink.senders`).
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections import Counter, OrderedDict, deque
from collections.abc import Callable
from dataclasses import dataclass

from avoidd.aio import cancel_task
from avoidd.config.connection import LinkSpec
from avoidd.mavlink.codec import PYMAVLINK_NOTES, Codec, Message, Parser
from avoidd.mavlink.senders import AddressPin, SenderBudget
from avoidd.mavlink.transport import Sender, Transport, create_sender_transport

logger = logging.getLogger(__name__)

URGENT_TYPES = frozenset({"HEARTBEAT", "STATUSTEXT"})

Handler = Callable[[Message, int], None]
"""Called with every decoded message and its local monotonic receive time (ns)."""

MAX_PARSERS = 16
"""Senders with a parser of their own; the one unheard longest gives its parser up."""
MAX_STRANGERS = 64
"""Senders counted one by one; more are counted together under ``"others"``."""
STRANGER_SUMMARY_S = 60.0
"""At most one summary line about strangers per this many seconds."""


@dataclass
class StrangerCount:
    """What one sender other than the autopilot sent (and the link dropped unread)."""

    datagrams: int = 0
    bytes: int = 0


def sender_text(sender: Sender) -> str:
    """A sender for logs: ``host:port`` (``[v6]:port``), or the stream for None."""
    if sender is None:
        return "the stream"
    host, port = sender[0], sender[1]
    return f"[{host}]:{port}" if ":" in str(host) else f"{host}:{port}"


class MavLink:
    """A MAVLink 2 link driven from asyncio.

    Args:
        spec: Where the link goes.
        codec: The link's codec (its ids and signing).
        queue_size: Messages waiting to be sent beyond which the oldest ordinary one is dropped.
        autopilot_timeout_s: After this long without a byte from the autopilot's address,
            another sender may become the autopilot (the ``link_timeout_s`` of the config).
        autopilot_address: The only sender heard (``mavlink.autopilot_address``); None
            hears any until the autopilot is adopted.

    Attributes:
        autopilot_sender: Where the autopilot speaks from, once known.
        strangers: What each other sender sent since then (bounded: see ``MAX_STRANGERS``).
    """

    def __init__(
        self,
        spec: LinkSpec,
        codec: Codec,
        queue_size: int = 64,
        autopilot_timeout_s: float = 3.0,
        autopilot_address: AddressPin | None = None,
    ) -> None:
        self.spec = spec
        self.pin = autopilot_address
        self.budget = SenderBudget()
        """Bounds what a sender not adopted costs to decode."""
        self.codec = codec
        self.transport: Transport = create_sender_transport(spec, self._on_bytes)
        self.sent: Counter[str] = Counter()
        self.received: Counter[str] = Counter()
        self.dropped: Counter[str] = Counter()
        self.handler_errors = 0
        self.bytes_received = 0
        self.autopilot_sender: Sender = None
        self.strangers: dict[str, StrangerCount] = {}
        self._locked = False
        self._autopilot_heard_ns = 0
        self._autopilot_timeout_ns = int(autopilot_timeout_s * 1e9)
        self._handling: tuple[Sender] | None = None
        self._parsers: OrderedDict[Sender, Parser] = OrderedDict()
        self._parse_errors = 0
        self._signature_rejects = 0
        self._window = StrangerCount()
        self._window_senders: set[Sender] = set()
        self._stranger_counts: dict[Sender, StrangerCount] = {}
        """Each stranger's entry in :attr:`strangers` by its address (no text per datagram)."""
        self._summary_ns: int | None = None
        self._urgent: deque[Message] = deque()
        self._normal: deque[Message] = deque()
        self._queue_size = queue_size
        self._wake = asyncio.Event()
        self._handlers: list[Handler] = []
        self._mirrors: list[Callable[[bytes], None]] = []
        self.forwarded = 0
        """Datagrams from another endpoint sent on to the autopilot (:meth:`send_raw`)."""
        self._sender: asyncio.Task[None] | None = None

    @property
    def connected(self) -> bool:
        """Whether bytes sent now can leave (a UDP-in link needs to have heard its peer)."""
        return self.transport.connected

    @property
    def parse_errors(self) -> int:
        """Bytes that did not decode, counted per bad chunk or frame (strangers' left out)."""
        return self._parse_errors

    @property
    def signature_rejects(self) -> int:
        """Incoming messages refused because their signature was missing or wrong."""
        return self._signature_rejects

    def subscribe(self, handler: Handler) -> None:
        """Call ``handler`` with every message decoded from now on."""
        self._handlers.append(handler)

    def mirror(self, forward: Callable[[bytes], None]) -> None:
        """Also hand ``forward`` what avoidd sends and what the adopted autopilot sends.

        Packed messages of avoidd's and the autopilot's datagrams as received: what a
        ground-station endpoint (:mod:`avoidd.mavlink.gcs`) passes on.
        """
        self._mirrors.append(forward)

    def unmirror(self, forward: Callable[[bytes], None]) -> None:
        """Stop handing bytes to ``forward``."""
        if forward in self._mirrors:
            self._mirrors.remove(forward)

    def _mirror(self, data: bytes) -> None:
        for forward in self._mirrors:
            try:
                forward(data)
            except Exception:
                # A mirror's failure must take neither the sender nor the receiver down.
                self.handler_errors += 1
                logger.exception("MAVLink %s: a mirror failed", self.spec)

    def send_raw(self, data: bytes) -> bool:
        """Send bytes another endpoint received on to the autopilot, unchanged.

        Returns:
            False when they were dropped (the link cannot send yet).
        """
        if not self.transport.connected or not self.transport.send(data):
            return False
        self.forwarded += 1
        return True

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
                packed = self.codec.pack(message)
                if self.transport.send(packed):
                    self.sent[kind] += 1
                else:
                    self.dropped[kind] += 1
                self._mirror(packed)

    def _on_bytes(self, data: bytes, sender: Sender = None) -> None:
        received_ns = time.monotonic_ns()
        if self.pin is not None and not self.pin.matches(sender):
            self._from_stranger(data, sender, received_ns)
            return
        if self._locked and sender != self.autopilot_sender:
            if received_ns - self._autopilot_heard_ns <= self._autopilot_timeout_ns:
                self._from_stranger(data, sender, received_ns)
                return
            self._locked = False
            logger.warning(
                "MAVLink %s: nothing from the autopilot at %s for %.1f s; listening to %s",
                self.spec,
                sender_text(self.autopilot_sender),
                (received_ns - self._autopilot_heard_ns) / 1e9,
                sender_text(sender),
            )
        elif self._locked:
            self._autopilot_heard_ns = received_ns
        if not self._locked and not self.budget.allows(sender, received_ns):
            return  # a flood from a sender not adopted: dropped unread (counted)
        if self._locked and sender == self.autopilot_sender:
            self._mirror(data)  # the autopilot's own bytes, to a ground-station endpoint
        self.bytes_received += len(data)
        parser = self._parser(sender)
        errors, rejects = parser.parse_errors, parser.signature_rejects
        messages = parser.decode(data)
        self._parse_errors += parser.parse_errors - errors
        self._signature_rejects += parser.signature_rejects - rejects
        self._handling = (sender,)
        try:
            for message in messages:
                self.received[message.get_type()] += 1
                for handler in self._handlers:
                    try:
                        handler(message, received_ns)
                    except Exception:
                        # A handler bug must not take the link down; it is counted and logged.
                        self.handler_errors += 1
                        logger.exception("MAVLink %s: handler failed on %s", self.spec, message)
        finally:
            self._handling = None

    def autopilot_spoke(self) -> None:
        """The message being handled is the adopted autopilot's HEARTBEAT: the link is its.

        Called by the vehicle tracker from its handler. From now on replies go to this sender
        only, and other senders are counted and dropped unread; before it, a ``udpin`` link
        sends nothing.
        """
        if self._handling is None:
            return
        (sender,) = self._handling
        self._autopilot_heard_ns = time.monotonic_ns()
        if self._locked and sender == self.autopilot_sender:
            return
        if sender is not None:
            if self.autopilot_sender is None:
                logger.info(
                    "MAVLink %s: the autopilot speaks from %s", self.spec, sender_text(sender)
                )
            elif sender != self.autopilot_sender:
                logger.warning(
                    "MAVLink %s: the autopilot now speaks from %s (was %s)",
                    self.spec,
                    sender_text(sender),
                    sender_text(self.autopilot_sender),
                )
        self._locked = True
        self.autopilot_sender = sender
        self.transport.reply_to(sender)

    def _parser(self, sender: Sender) -> Parser:
        parser = self._parsers.get(sender)
        if parser is None:
            if len(self._parsers) >= MAX_PARSERS:
                self._parsers.popitem(last=False)
            parser = self._parsers[sender] = self.codec.parser()
        else:
            self._parsers.move_to_end(sender)
        return parser

    def _from_stranger(self, data: bytes, sender: Sender, now_ns: int) -> None:
        """Count (and drop, unread) what a sender other than the autopilot sent; log sparingly.

        Nothing of it is decoded: decoding a flood of 20,000 messages a second took the event
        loop and the vision threads away (OBSTACLE_DISTANCE fell from 15 Hz to 5).
        """
        count = self._stranger_counts.get(sender)
        if count is None:
            count = self._new_stranger(sender)
        count.datagrams += 1
        count.bytes += len(data)
        window = self._window
        window.datagrams += 1
        window.bytes += len(data)
        if len(self._window_senders) < 4 * MAX_STRANGERS:
            self._window_senders.add(sender)
        if self._summary_ns is None:
            self._summary_ns = now_ns
        elif now_ns - self._summary_ns >= STRANGER_SUMMARY_S * 1e9:
            self._log_strangers(now_ns)

    def _new_stranger(self, sender: Sender) -> StrangerCount:
        """The count of a sender not seen before (named once in the log), or of the others."""
        name = sender_text(sender)
        if len(self.strangers) >= MAX_STRANGERS:
            others = self.strangers.setdefault("others", StrangerCount())
            if len(self._stranger_counts) < 4 * MAX_STRANGERS:
                self._stranger_counts[sender] = others
            return others
        count = self.strangers[name] = StrangerCount()
        self._stranger_counts[sender] = count
        where = (
            f"mavlink.autopilot_address is {self.pin}"
            if self.pin is not None
            else sender_text(self.autopilot_sender)
        )
        logger.warning(
            "MAVLink %s: %s is not the autopilot (%s); what it sends is ignored and nothing is "
            "sent to it",
            self.spec,
            name,
            where,
        )
        return count

    def _log_strangers(self, now_ns: int) -> None:
        assert self._summary_ns is not None
        window = self._window
        logger.warning(
            "MAVLink %s: ignored %d datagrams (%d bytes) from %d%s strangers in the last %.0f s",
            self.spec,
            window.datagrams,
            window.bytes,
            len(self._window_senders),
            "+" if len(self._window_senders) >= 4 * MAX_STRANGERS else "",
            (now_ns - self._summary_ns) / 1e9,
        )
        self._window = StrangerCount()
        self._window_senders = set()
        self._summary_ns = now_ns

    def _signature_refused(self) -> dict[str, int]:
        check = self.codec.signature_check
        if check is None:
            return {}
        return {"mismatch": check.mismatches, "replay": check.replays, "stale": check.stale}

    def counters(self) -> dict[str, object]:
        """Counters for logs and tests: sent/received/dropped by type and error counts."""
        return {
            "sent": dict(self.sent),
            "received": dict(self.received),
            "dropped": dict(self.dropped),
            "parse_errors": self.parse_errors,
            "signature_rejects": self.signature_rejects,
            # Why signed frames were refused (avoidd's own check: mismatch, replay, stale).
            "signature_refused": self._signature_refused(),
            "handler_errors": self.handler_errors,
            "strangers": {name: vars(count) for name, count in self.strangers.items()},
            "over_budget": self.budget.dropped,
            # pymavlink's per-packet lines, silenced (process-wide: every link's parser).
            "pymavlink_notes": dict(PYMAVLINK_NOTES.counts),
        }
