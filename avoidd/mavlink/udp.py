"""The UDP transport (``udpout``, ``udpin``): a non-blocking socket read in batches.

asyncio's datagram transport hands over one datagram per turn of the event loop: a flood of
20,000 datagrams a second cost the loop 11 us each even when every one was dropped unread.
Here each time the socket is readable up to :data:`BATCH` datagrams are read in one go, and
sending never blocks: a datagram the socket cannot take now is dropped and counted.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import socket
from collections.abc import Callable
from typing import Any

from avoidd.config.connection import LinkSpec
from avoidd.errors import LinkError

logger = logging.getLogger(__name__)

BATCH = 256
"""Datagrams read per wake-up at most (then the loop runs its other work)."""
_MAX_DATAGRAM = 65535

RECEIVE_BUFFER_BYTES = 4 << 20
"""Receive buffer asked for: half a second of a 20,000 datagram/s flood, so that a moment
in which the loop is busy drops nothing of the autopilot's. The kernel grants at most
``net.core.rmem_max`` (212992 by default on many boards; raise it with sysctl)."""

UdpSender = tuple[Any, ...]
"""Where a datagram came from (the socket address)."""


class UdpTransport:
    """UDP out (to a fixed address) or in (listening).

    Args:
        spec: The link.
        on_receive: Gets every datagram and its sender.
        follow_sender: ``udpin`` answers whoever sent the last datagram; otherwise nobody
            until :meth:`reply_to` names the peer.

    Attributes:
        send_errors: Datagrams the socket refused (full, or ICMP unreachable reported).
    """

    def __init__(
        self,
        spec: LinkSpec,
        on_receive: Callable[[bytes, UdpSender], None],
        follow_sender: bool,
    ) -> None:
        self._spec = spec
        self._on_receive = on_receive
        self._follow_sender = follow_sender
        self._sock: socket.socket | None = None
        self._peer: Any = None
        self.send_errors = 0
        self.socket_closed = asyncio.Event()
        """Set once the socket is closed."""

    @property
    def connected(self) -> bool:
        """Whether bytes sent now can leave (a ``udpin`` link needs to know its peer)."""
        return self._sock is not None and self._peer is not None

    @property
    def local_port(self) -> int:
        """The local port (useful when bound to port 0)."""
        assert self._sock is not None
        return int(self._sock.getsockname()[1])

    @property
    def peer(self) -> Any:
        """Where it sends (None until known)."""
        return self._peer

    def socket_fileno(self) -> int | None:
        """The socket's file descriptor (None when closed).

        A thread that must send on time whatever the event loop does can ``dup`` it and send
        from the same address.
        """
        return None if self._sock is None else self._sock.fileno()

    def reply_to(self, sender: UdpSender | None) -> None:
        """Send to ``sender`` from now on (``udpin`` only)."""
        if self._spec.kind == "udpin" and sender is not None:
            self._peer = sender

    async def open(self) -> None:
        """Resolve, bind (``udpin``) or connect (``udpout``), and start reading.

        Raises:
            LinkError: The address cannot be resolved or bound.
        """
        spec = self._spec
        loop = asyncio.get_running_loop()
        try:
            infos = await loop.getaddrinfo(spec.host, spec.port, type=socket.SOCK_DGRAM)
        except OSError as exc:
            raise LinkError(f"MAVLink {spec}: {exc.strerror or exc}; check the address") from exc
        error: OSError | None = None
        for family, kind, proto, _, address in infos:  # the first address that works
            try:
                sock = socket.socket(family, kind, proto)
            except OSError as exc:
                error = exc
                continue
            try:
                sock.setblocking(False)
                _enlarge_receive_buffer(sock, spec)
                if spec.kind == "udpout":
                    sock.connect(address)
                else:
                    sock.bind(address)
            except OSError as exc:
                sock.close()
                error = exc
                continue
            self._peer = address if spec.kind == "udpout" else None
            self._sock = sock
            self.socket_closed.clear()
            loop.add_reader(sock.fileno(), self._readable)
            return
        why = (error.strerror or str(error)) if error is not None else "no address"
        raise LinkError(f"MAVLink {spec}: {why}; check the address")

    def _readable(self) -> None:
        sock = self._sock
        udpin = self._spec.kind == "udpin"
        for _ in range(BATCH):
            if sock is None or self._sock is not sock:
                return  # closed by a handler
            try:
                data, addr = sock.recvfrom(_MAX_DATAGRAM)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                # ICMP port unreachable while nobody listens yet: expected with udpout.
                self.send_errors += 1
                continue
            if udpin and self._follow_sender:
                self._peer = addr
            self._on_receive(data, addr)

    def send(self, data: bytes) -> bool:
        """Send one datagram now; False when it was dropped (no peer, socket full, error)."""
        sock, peer = self._sock, self._peer
        if sock is None or peer is None:
            return False
        try:
            if self._spec.kind == "udpout":
                sock.send(data)
            else:
                sock.sendto(data, peer)
        except OSError:
            self.send_errors += 1
            return False
        return True

    async def close(self) -> None:
        """Stop reading and close the socket (its port is free once this returns)."""
        sock, self._sock = self._sock, None
        if sock is None:
            return
        with contextlib.suppress(ValueError, OSError):
            asyncio.get_running_loop().remove_reader(sock.fileno())
        sock.close()
        self.socket_closed.set()


def _enlarge_receive_buffer(sock: socket.socket, spec: LinkSpec) -> None:
    """Ask for :data:`RECEIVE_BUFFER_BYTES` of receive buffer; say so when far less is granted."""
    with contextlib.suppress(OSError):
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RECEIVE_BUFFER_BYTES)
    granted = sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
    if spec.kind == "udpin" and granted < RECEIVE_BUFFER_BYTES // 2:
        logger.info(
            "MAVLink %s: receive buffer %d kB (asked %d kB); a flood from a stranger may then "
            "crowd out the autopilot's datagrams: sysctl -w net.core.rmem_max=%d",
            spec,
            granted // 1024,
            RECEIVE_BUFFER_BYTES // 1024,
            RECEIVE_BUFFER_BYTES,
        )
