"""What the debug view lets in: a bounded number of connections, and only its own host names.

The view shares the daemon's process and file descriptors with the cameras and the link:
1,100 idle connections under the default limit of 1,024 descriptors took the camera away for
10 s. :class:`ConnectionGate` wraps the HTTP server's protocol factory: beyond
``max_connections`` a connection is answered ``503`` and closed at once, and one that sends
nothing within :data:`FIRST_BYTES_S` is closed. :func:`host_allowed` is the check against DNS
rebinding: a page of another site whose name was made to resolve to 127.0.0.1 sends its own
name in ``Host``, which is refused.
"""

from __future__ import annotations

import asyncio
import ipaddress
from collections.abc import Callable, Iterable

from avoidd.config.debug_server import LOOPBACK_NAMES

FIRST_BYTES_S = 10.0
"""A connection that has sent nothing after this long is closed."""
REFUSED_LINGER_S = 1.0
"""A refused connection is closed after this long if the client has not closed it."""

_REFUSAL_TEXT = b"too many connections to the avoidd debug view; close some and retry\n"
REFUSAL = (
    b"HTTP/1.1 503 Service Unavailable\r\n"
    b"Content-Type: text/plain; charset=utf-8\r\n"
    b"Retry-After: 5\r\n"
    b"Connection: close\r\n"
    b"Content-Length: " + str(len(_REFUSAL_TEXT)).encode() + b"\r\n\r\n" + _REFUSAL_TEXT
)
"""What a connection beyond the limit gets before it is closed."""


class _Refused(asyncio.Protocol):
    """A connection over the limit: the 503, then closed.

    It is closed once the client has read the answer and closed its side, or after
    :data:`REFUSED_LINGER_S`; at once while as many refused ones linger as are allowed open
    (a flood of connections must not hold descriptors while it is refused).
    """

    def __init__(self, gate: ConnectionGate) -> None:
        self._gate = gate
        self._lingering = False
        self._timer: asyncio.TimerHandle | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        gate = self._gate
        gate.refused += 1
        assert isinstance(transport, asyncio.WriteTransport)
        transport.write(REFUSAL)
        if gate.lingering >= gate.max_connections or not transport.can_write_eof():
            transport.close()
            return
        gate.lingering += 1
        self._lingering = True
        transport.write_eof()  # the answer is whole: the client may close
        self._timer = asyncio.get_running_loop().call_later(REFUSED_LINGER_S, transport.close)

    def data_received(self, data: bytes) -> None:
        """The request: not read."""

    def eof_received(self) -> bool:
        return False  # closes the transport

    def connection_lost(self, exc: Exception | None) -> None:
        if self._timer is not None:
            self._timer.cancel()
        if self._lingering:
            self._gate.lingering -= 1
            self._lingering = False


class _Counted(asyncio.Protocol):
    """A connection within the limit: the HTTP server's own protocol, counted while open."""

    def __init__(self, gate: ConnectionGate, inner: asyncio.Protocol) -> None:
        self._gate = gate
        self._inner = inner
        self._idle: asyncio.TimerHandle | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self._idle = asyncio.get_running_loop().call_later(
            self._gate.first_bytes_s, self._silent, transport
        )
        self._inner.connection_made(transport)

    def _silent(self, transport: asyncio.BaseTransport) -> None:
        self._gate.silent += 1
        transport.close()

    def data_received(self, data: bytes) -> None:
        if self._idle is not None:
            self._idle.cancel()
            self._idle = None
        self._inner.data_received(data)

    def eof_received(self) -> bool | None:
        return self._inner.eof_received()

    def pause_writing(self) -> None:
        self._inner.pause_writing()

    def resume_writing(self) -> None:
        self._inner.resume_writing()

    def connection_lost(self, exc: Exception | None) -> None:
        if self._idle is not None:
            self._idle.cancel()
            self._idle = None
        self._gate.open -= 1
        self._inner.connection_lost(exc)


class ConnectionGate:
    """A protocol factory for ``loop.create_server`` that bounds the open connections.

    Args:
        inner: The HTTP server's protocol factory (aiohttp's ``runner.server``).
        max_connections: Connections open at once; more are answered 503 and closed.
        first_bytes_s: A connection that sends nothing for this long is closed.

    Attributes:
        open: Connections open now (within the limit).
        lingering: Refused connections not yet closed.
        refused: Connections answered 503 so far.
        silent: Connections closed for sending nothing.
    """

    def __init__(
        self,
        inner: Callable[[], asyncio.Protocol],
        max_connections: int,
        first_bytes_s: float = FIRST_BYTES_S,
    ) -> None:
        self._inner = inner
        self.max_connections = max_connections
        self.first_bytes_s = first_bytes_s
        self.open = 0
        self.lingering = 0
        self.refused = 0
        self.silent = 0

    def __call__(self) -> asyncio.Protocol:
        """The protocol of one new connection: the server's, or the refusal."""
        if self.open >= self.max_connections:
            return _Refused(self)
        self.open += 1
        return _Counted(self, self._inner())


def _host_part(header: str) -> str:
    """The host of a ``Host`` header, without the port (``[::1]:8080`` -> ``::1``)."""
    header = header.strip().lower()
    if header.startswith("["):
        return header[1:].partition("]")[0]
    return header.rpartition(":")[0] if header.count(":") == 1 else header


def host_allowed(header: str | None, names: Iterable[str]) -> bool:
    """Whether a request's ``Host`` may be served.

    An address (``127.0.0.1``, ``[::1]``, ``192.168.1.7``) is fine: DNS rebinding needs a name.
    A name is fine if it is a loopback one (``localhost``) or one of ``names`` (the
    configured ``host_names`` and the listening host); any other is another site's.

    Args:
        header: The ``Host`` header (None: the request had none, as HTTP/1.0 may).
        names: Host names the view is served under.
    """
    if header is None:
        return True
    host = _host_part(header)
    try:
        ipaddress.ip_address(host)
        return True
    except ValueError:
        pass
    host = host.rstrip(".")
    return host in LOOPBACK_NAMES or host in {n.lower().rstrip(".") for n in names}
