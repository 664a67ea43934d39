"""The systemd notification protocol (``sd_notify``): datagrams to ``$NOTIFY_SOCKET``.

A service of ``Type=notify`` tells its manager ``READY=1``, ``STATUS=...``, ``WATCHDOG=1`` and
``STOPPING=1`` as newline-separated ``KEY=VALUE`` lines in one datagram on an ``AF_UNIX`` socket
whose address the manager puts in ``NOTIFY_SOCKET`` (a path, or an abstract name written with a
leading ``@``). The watchdog interval comes in ``WATCHDOG_USEC`` (and ``WATCHDOG_PID``, the
process it is meant for). Only the standard library is needed; see ``sd_notify(3)``.
"""

from __future__ import annotations

import logging
import os
import socket
from collections.abc import Mapping

logger = logging.getLogger(__name__)


def watchdog_interval_s(
    environ: Mapping[str, str] | None = None, pid: int | None = None
) -> float | None:
    """The watchdog interval the service manager expects pings within, as ``sd_watchdog_enabled``.

    Args:
        environ: The environment (default: ``os.environ``).
        pid: This process's id (default: ``os.getpid()``).

    Returns:
        ``WATCHDOG_USEC`` in seconds, or None when it is unset, not a positive whole number, or
        ``WATCHDOG_PID`` names another process.
    """
    env = os.environ if environ is None else environ
    usec_text = env.get("WATCHDOG_USEC", "")
    if not usec_text.isdigit() or int(usec_text) == 0:
        return None
    pid_text = env.get("WATCHDOG_PID")
    if pid_text is not None:
        own_pid = os.getpid() if pid is None else pid
        if not pid_text.isdigit() or int(pid_text) != own_pid:
            return None
    return int(usec_text) / 1e6


class Notifier:
    """Sends notifications to the service manager's socket; never blocks, never raises.

    A message that cannot be sent (the manager is gone, its queue is full) is dropped and logged
    once per run of failures: the daemon must not stop flying because systemd is not listening.

    Args:
        address: The socket: a file system path, or an abstract name starting with ``@``.
    """

    def __init__(self, address: str) -> None:
        self.address = address
        self._target: str | bytes = (
            b"\0" + address[1:].encode() if address.startswith("@") else address
        )
        self._socket = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
        self._socket.setblocking(False)
        self._failing = False
        self.sent = 0
        """Messages sent."""
        self.dropped = 0
        """Messages that could not be sent."""

    @classmethod
    def from_environment(cls, environ: Mapping[str, str] | None = None) -> Notifier | None:
        """The notifier ``NOTIFY_SOCKET`` asks for, or None when it is unset.

        Args:
            environ: The environment (default: ``os.environ``).

        Returns:
            A notifier, or None outside a service manager (or with an address systemd would
            not send, such as a relative path).
        """
        env = os.environ if environ is None else environ
        address = env.get("NOTIFY_SOCKET", "")
        if address.startswith(("/", "@")) and len(address) > 1:
            return cls(address)
        if address:
            logger.warning(
                "NOTIFY_SOCKET=%r is neither a path nor @abstract; not notifying", address
            )
        return None

    def notify(self, **fields: str) -> bool:
        """Send one message of ``KEY=VALUE`` lines, e.g. ``notify(READY="1", STATUS="ok")``.

        Args:
            **fields: The variables, in order; newlines in a value become spaces.

        Returns:
            True if the datagram was sent.
        """
        text = "\n".join(f"{key}={' '.join(value.splitlines())}" for key, value in fields.items())
        try:
            self._socket.sendto(text.encode(), self._target)
        except OSError as exc:
            self.dropped += 1
            if not self._failing:
                self._failing = True
                logger.warning("systemd notification to %s failed: %s", self.address, exc)
            return False
        if self._failing:
            self._failing = False
            logger.info("systemd notifications to %s go through again", self.address)
        self.sent += 1
        return True

    def close(self) -> None:
        """Close the socket."""
        self._socket.close()
