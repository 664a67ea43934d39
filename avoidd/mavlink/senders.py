"""Whom a listening link hears: the pinned autopilot address, and a budget per unknown sender.

On ``udpin`` anyone who can reach the port can send. :class:`AddressPin`
(``mavlink.autopilot_address``) says where the autopilot speaks from; every other sender is a
stranger from the first datagram on, never decoded. :class:`SenderBudget` bounds what a sender
that is not (yet) the autopilot costs to decode: beyond its datagrams per second the rest are
dropped unread, so a flood before the autopilot is known, or while it reboots, cannot take
the event loop (and the vision threads, which need the interpreter too) away.
"""

from __future__ import annotations

import ipaddress
from collections import OrderedDict
from dataclasses import dataclass

from avoidd.config.connection import parse_address
from avoidd.mavlink.transport import Sender

IpAddress = ipaddress.IPv4Address | ipaddress.IPv6Address

UNKNOWN_SENDER_DATAGRAMS_PER_S = 2000
"""Datagrams per second decoded from each sender that is not the adopted autopilot (an
autopilot's own streams are a few hundred; ``bench-link`` decodes 2000 msg/s)."""
_BUDGET_SENDERS = 64
"""Senders whose budget is kept; the one heard least recently is forgotten first."""


def _ip(text: str) -> IpAddress | None:
    try:
        address = ipaddress.ip_address(text.partition("%")[0])
    except ValueError:
        return None
    if isinstance(address, ipaddress.IPv6Address) and address.ipv4_mapped is not None:
        return address.ipv4_mapped  # ::ffff:127.0.0.1 on a dual-stack socket
    return address


@dataclass(frozen=True)
class AddressPin:
    """The autopilot's address on a ``udpin`` link: a host, and optionally its port.

    Attributes:
        ip: The host's address.
        port: Its port; None takes any port of the host (an autopilot that restarts may come
            back from another one).
    """

    ip: IpAddress
    port: int | None = None

    @classmethod
    def parse(cls, text: str) -> AddressPin:
        """An address as ``mavlink.autopilot_address`` writes it (``HOST``, ``HOST:PORT``).

        Raises:
            ValueError: Not an address with an optional port.
        """
        host, port = parse_address(text)
        ip = _ip(host)
        assert ip is not None  # parse_address checked it
        return cls(ip, port)

    def matches(self, sender: Sender) -> bool:
        """Whether a datagram from ``sender`` comes from the pinned address."""
        if sender is None:
            return True  # a stream has one peer
        ip = _ip(str(sender[0]))
        return ip == self.ip and (self.port is None or int(sender[1]) == self.port)

    def __str__(self) -> str:
        host = f"[{self.ip}]" if self.ip.version == 6 else str(self.ip)
        return host if self.port is None else f"{host}:{self.port}"


class SenderBudget:
    """At most ``per_s`` datagrams per second decoded from each sender; the rest are dropped.

    Args:
        per_s: Datagrams per second and sender.

    Attributes:
        dropped: Datagrams dropped unread for being over a budget.
    """

    def __init__(self, per_s: int = UNKNOWN_SENDER_DATAGRAMS_PER_S) -> None:
        self._per_s = per_s
        self._windows: OrderedDict[Sender, tuple[int, int]] = OrderedDict()
        self.dropped = 0

    def allows(self, sender: Sender, now_ns: int) -> bool:
        """Count one datagram from ``sender``; False when it is over the budget."""
        start_ns, count = self._windows.pop(sender, (now_ns, 0))
        if now_ns - start_ns >= 1_000_000_000:
            start_ns, count = now_ns, 0
        count += 1
        self._windows[sender] = (start_ns, count)
        if len(self._windows) > _BUDGET_SENDERS:
            self._windows.popitem(last=False)
        if count > self._per_s:
            self.dropped += 1
            return False
        return True
