"""Byte transports for MAVLink on asyncio: UDP (:mod:`.udp`), TCP client and server, serial."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import socket
import termios
import tty
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Protocol

from avoidd.aio import cancel_task
from avoidd.config.connection import STANDARD_BAUDS, LinkSpec
from avoidd.errors import LinkError
from avoidd.logrepeat import RepeatLimiter
from avoidd.mavlink.udp import UdpTransport

logger = logging.getLogger(__name__)

ReceiveCallback = Callable[[bytes], None]
"""Called with every chunk of received bytes."""
Sender = tuple[Any, ...] | None
"""Where a datagram came from (the socket address); None on a stream (TCP, serial)."""
SenderCallback = Callable[[bytes, Sender], None]
"""Called with every chunk of received bytes and its sender."""

_MAX_WRITE_BUFFER = 64 * 1024
# A TCP client retries a failed connect after at most this long.
_TCP_RETRY_MAX_S = 0.5


class Transport(Protocol):
    """Moves bytes; ``send`` never blocks and returns False when the bytes were dropped."""

    @property
    def connected(self) -> bool:
        """Whether bytes sent now can leave."""
        ...

    async def open(self) -> None:
        """Start the transport (binding, connecting in the background, opening the device)."""
        ...

    def send(self, data: bytes) -> bool:
        """Queue bytes for sending."""
        ...

    def reply_to(self, sender: Sender) -> None:
        """Send to ``sender`` from now on (``udpin`` only; other transports have one peer)."""
        ...

    async def close(self) -> None:
        """Stop and release everything."""
        ...


def _write_stream(writer: asyncio.StreamWriter | None, data: bytes) -> bool:
    """Write to a TCP stream unless it is gone or its buffer is full (then drop: False)."""
    if writer is None or writer.is_closing():
        return False
    if writer.transport.get_write_buffer_size() > _MAX_WRITE_BUFFER:
        return False
    writer.write(data)
    return True


async def _pump(reader: asyncio.StreamReader, on_receive: SenderCallback, spec: LinkSpec) -> None:
    """Hand every chunk read from a TCP stream to ``on_receive`` until it closes or fails."""
    try:
        while data := await reader.read(4096):
            on_receive(data, None)
    except OSError as exc:
        logger.debug("MAVLink %s: read failed (%s)", spec, exc)


def _connect_failure(exc: BaseException) -> tuple[str, str]:
    """Why a TCP connect failed, in a few words (the state), and what to check."""
    if isinstance(exc, socket.gaierror):
        return "unknown host", "check the host name in mavlink.connection"
    if isinstance(exc, ConnectionRefusedError):
        return "connection refused", "is the autopilot, SITL or router listening on that port?"
    if isinstance(exc, TimeoutError):
        return "no answer", "is the host up and the port not firewalled?"
    return (exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)), (
        "check the address in mavlink.connection"
    )


class _TcpClient:
    """TCP client that keeps reconnecting with backoff while the peer is away."""

    def __init__(self, spec: LinkSpec, on_receive: SenderCallback) -> None:
        self._spec = spec
        self._on_receive = on_receive
        self._writer: asyncio.StreamWriter | None = None
        self._task: asyncio.Task[None] | None = None
        self._failures_log = RepeatLimiter(logger)
        self.reconnects = 0
        self.connect_failures = 0

    @property
    def connected(self) -> bool:
        return self._writer is not None and not self._writer.is_closing()

    async def open(self) -> None:
        self._task = asyncio.create_task(self._run(), name=f"tcp {self._spec}")

    async def _run(self) -> None:
        backoff_s = 0.1
        while True:
            try:
                reader, writer = await asyncio.wait_for(
                    asyncio.open_connection(self._spec.host, self._spec.port), timeout=2.0
                )
            except (OSError, TimeoutError) as exc:
                self.connect_failures += 1
                why, hint = _connect_failure(exc)
                self._failures_log.report(
                    logging.INFO,
                    why,
                    f"MAVLink {self._spec}: cannot connect ({why}); {hint}; retrying every "
                    f"{_TCP_RETRY_MAX_S:g} s",
                )
                await asyncio.sleep(backoff_s)
                backoff_s = min(backoff_s * 2, _TCP_RETRY_MAX_S)
                continue
            backoff_s = 0.1
            self._writer = writer
            self._failures_log.clear()
            logger.info("MAVLink %s: connected", self._spec)
            try:
                await _pump(reader, self._on_receive, self._spec)
            finally:
                self._writer = None
                writer.close()
                with contextlib.suppress(OSError):
                    await writer.wait_closed()
            self.reconnects += 1
            logger.warning("MAVLink %s: connection lost; reconnecting", self._spec)

    def send(self, data: bytes) -> bool:
        return _write_stream(self._writer, data)

    def reply_to(self, sender: Sender) -> None:
        """One peer: nothing to choose."""

    async def close(self) -> None:
        await cancel_task(self._task)
        self._task = None
        if self._writer is not None:
            self._writer.close()
            self._writer = None


_BAUD_CONSTANTS = {
    baud: getattr(termios, f"B{baud}") for baud in STANDARD_BAUDS if hasattr(termios, f"B{baud}")
}


class _Serial:
    """A serial port in raw mode, read and written through the event loop (never blocking).

    A port that is missing or fails (a USB adapter unplugged, the far end of a pty closed) is
    reopened in the background with backoff; sends while it is away are dropped.
    """

    def __init__(self, spec: LinkSpec, on_receive: SenderCallback) -> None:
        self._spec = spec
        self._on_receive = on_receive
        self._fd: int | None = None
        self._pending = bytearray()
        self._task: asyncio.Task[None] | None = None
        self._lost = asyncio.Event()
        self.reconnects = 0
        # The port's own thread for opening and closing it: a close may wait for its output to
        # drain (up to the driver's closing_wait), which must hold up neither the loop nor the
        # shared default executor.
        self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="serial-port")

    @property
    def connected(self) -> bool:
        return self._fd is not None

    async def open(self) -> None:
        if self._spec.baud not in _BAUD_CONSTANTS:
            raise LinkError(f"MAVLink {self._spec}: baud rate {self._spec.baud} not supported here")
        self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="serial-port")
        self._task = asyncio.create_task(self._run(), name=f"serial {self._spec}")

    def _open_device(self) -> int:
        spec = self._spec
        fd = os.open(spec.device, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        try:
            tty.setraw(fd)
            attrs = termios.tcgetattr(fd)
            speed = _BAUD_CONSTANTS[spec.baud]
            attrs[4] = attrs[5] = speed
            attrs[2] |= termios.CLOCAL | termios.CREAD
            termios.tcsetattr(fd, termios.TCSANOW, attrs)
        except termios.error:
            # A pty or some USB adapters refuse line settings; raw bytes still flow.
            logger.debug("MAVLink %s: line settings not applied", spec)
        return fd

    async def _open_off_loop(self) -> int:
        """Open the port in a worker thread.

        Opening (and setting up) a serial device may wait on its driver; the loop must not.
        """
        future = asyncio.get_running_loop().run_in_executor(self._executor, self._open_device)
        try:
            return await asyncio.shield(future)
        except asyncio.CancelledError:
            future.add_done_callback(self._close_opened)  # closing meanwhile: no leaked port
            raise

    def _close_opened(self, future: asyncio.Future[int]) -> None:
        if not future.cancelled() and future.exception() is None:
            self._close_off_loop(future.result())

    def _close_off_loop(self, fd: int) -> None:
        try:
            self._executor.submit(_close_quietly, fd)
        except RuntimeError:  # the executor is shut down: close here
            _close_quietly(fd)

    async def _run(self) -> None:
        backoff_s = 0.1
        failures = 0
        while True:
            try:
                fd = await self._open_off_loop()
            except OSError as exc:
                hint = "is the user in group 'dialout'?" if exc.errno == 13 else "is it plugged in?"
                log = logger.error if failures == 0 else logger.debug
                log("MAVLink %s: cannot open %s (%s); %s", self._spec, self._spec.device, exc, hint)
                failures += 1
                await asyncio.sleep(backoff_s)
                backoff_s = min(backoff_s * 2, 0.5)
                continue
            if failures or self.reconnects:
                logger.info("MAVLink %s: port open again", self._spec)
            failures = 0
            backoff_s = 0.1
            self._fd = fd
            self._lost.clear()
            asyncio.get_running_loop().add_reader(fd, self._readable)
            await self._lost.wait()
            self.reconnects += 1
            logger.warning("MAVLink %s: port lost; reopening", self._spec)

    def _readable(self) -> None:
        if self._fd is None:
            return
        try:
            data = os.read(self._fd, 4096)
        except BlockingIOError:
            return
        except OSError as exc:
            logger.debug("MAVLink %s: read failed (%s)", self._spec, exc)
            self._drop()
            return
        if data:
            self._on_receive(data, None)
        else:
            self._drop()

    def _writable(self) -> None:
        self._flush()

    def _flush(self) -> None:
        if self._fd is None:
            return
        loop = asyncio.get_running_loop()
        try:
            written = os.write(self._fd, self._pending) if self._pending else 0
        except BlockingIOError:
            written = 0
        except OSError as exc:
            logger.debug("MAVLink %s: write failed (%s)", self._spec, exc)
            self._drop()
            return
        del self._pending[:written]
        if self._pending:
            loop.add_writer(self._fd, self._writable)
        else:
            loop.remove_writer(self._fd)

    def _drop(self) -> None:
        if self._fd is None:
            return
        loop = asyncio.get_running_loop()
        loop.remove_reader(self._fd)
        loop.remove_writer(self._fd)
        # Closing a tty may wait for its output to drain or for the kernel's tty work (a busy
        # machine's worker threads): off the loop.
        self._close_off_loop(self._fd)
        self._fd = None
        self._pending.clear()
        self._lost.set()

    def send(self, data: bytes) -> bool:
        if self._fd is None or len(self._pending) > _MAX_WRITE_BUFFER:
            return False
        self._pending += data
        self._flush()
        return True

    def reply_to(self, sender: Sender) -> None:
        """One peer: nothing to choose."""

    async def close(self) -> None:
        await cancel_task(self._task)
        self._task = None
        fd, self._fd = self._fd, None
        if fd is not None:
            loop = asyncio.get_running_loop()
            loop.remove_reader(fd)
            loop.remove_writer(fd)
            self._close_off_loop(fd)
        # Closes still draining finish in the port's thread; nothing waits for them here.
        self._executor.shutdown(wait=False)


def _close_quietly(fd: int) -> None:
    with contextlib.suppress(OSError):
        os.close(fd)


class _TcpServer:
    """A TCP server for one client at a time; a new client replaces the previous one."""

    def __init__(self, spec: LinkSpec, on_receive: SenderCallback) -> None:
        self._spec = spec
        self._on_receive = on_receive
        self._server: asyncio.Server | None = None
        self._writer: asyncio.StreamWriter | None = None
        self.clients = 0

    @property
    def connected(self) -> bool:
        return self._writer is not None and not self._writer.is_closing()

    @property
    def local_port(self) -> int:
        """The listening port (useful when bound to port 0)."""
        assert self._server is not None
        return int(self._server.sockets[0].getsockname()[1])

    async def open(self) -> None:
        try:
            self._server = await asyncio.start_server(
                self._client, self._spec.host, self._spec.port, reuse_address=True
            )
        except OSError as exc:
            raise LinkError(
                f"MAVLink {self._spec}: {exc.strerror or exc}; check the address"
            ) from exc

    async def _client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        if self._writer is not None:
            self._writer.close()
        self._writer = writer
        self.clients += 1
        logger.info("MAVLink %s: client connected", self._spec)
        try:
            await _pump(reader, self._on_receive, self._spec)
        finally:
            if self._writer is writer:
                self._writer = None
            writer.close()

    def send(self, data: bytes) -> bool:
        return _write_stream(self._writer, data)

    def reply_to(self, sender: Sender) -> None:
        """One peer: nothing to choose."""

    async def close(self) -> None:
        if self._writer is not None:
            self._writer.close()
            self._writer = None
        if self._server is not None:
            self._server.close()
            self._server = None


def create_transport(spec: LinkSpec, on_receive: ReceiveCallback) -> Transport:
    """Build the transport a connection string asks for (``udpin`` answers the last sender).

    Args:
        spec: The parsed connection string.
        on_receive: Called in the event loop with every chunk of received bytes.

    Returns:
        An unopened transport; call ``await transport.open()``.
    """
    return _create(spec, lambda data, _sender: on_receive(data), follow_sender=True)


def create_sender_transport(spec: LinkSpec, on_receive: SenderCallback) -> Transport:
    """Build a transport that says who sent what, and answers only whom it is told to.

    A ``udpin`` transport sends nothing until :meth:`Transport.reply_to` names the peer
    (a datagram from a stranger never redirects avoidd's output).

    Args:
        spec: The parsed connection string.
        on_receive: Called in the event loop with every chunk of received bytes and its
            sender (the socket address for UDP, None for TCP and serial).

    Returns:
        An unopened transport; call ``await transport.open()``.
    """
    return _create(spec, on_receive, follow_sender=False)


def _create(spec: LinkSpec, on_receive: SenderCallback, follow_sender: bool) -> Transport:
    if spec.kind in ("udpout", "udpin"):
        return UdpTransport(spec, on_receive, follow_sender)
    if spec.kind == "tcp":
        return _TcpClient(spec, on_receive)
    if spec.kind == "tcpin":
        return _TcpServer(spec, on_receive)
    return _Serial(spec, on_receive)
