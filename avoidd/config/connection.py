"""Parse pymavlink-style connection strings (udpout:, udpin:, tcp:, tcpin:, /dev/tty...,baud)."""

from __future__ import annotations

import ipaddress
from dataclasses import dataclass
from typing import Literal

LinkKind = Literal["udpout", "udpin", "tcp", "tcpin", "serial"]

DEFAULT_BAUD = 115200
STANDARD_BAUDS = (
    9600,
    19200,
    38400,
    57600,
    115200,
    230400,
    460800,
    500000,
    921600,
    1000000,
    1500000,
    2000000,
    3000000,
)


@dataclass(frozen=True)
class LinkSpec:
    """Where a MAVLink link goes.

    Attributes:
        kind: ``udpout`` (send to host:port), ``udpin`` (listen on host:port; avoidd's link
            answers the autopilot once heard, see ``avoidd.mavlink.link``), ``tcp`` (client to
            host:port), ``tcpin`` (server on host:port, one client at a time) or ``serial``.
        host: Host name or address for network links.
        port: Port for network links.
        device: Device path for serial links.
        baud: Baud rate for serial links.
    """

    kind: LinkKind
    host: str = ""
    port: int = 0
    device: str = ""
    baud: int = 0

    def __str__(self) -> str:
        if self.kind == "serial":
            prefix = "" if self.device.startswith("/dev/") else "serial:"
            return f"{prefix}{self.device},{self.baud}"
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{self.kind}:{host}:{self.port}"


def parse_connection(text: str) -> LinkSpec:
    """Parse a connection string.

    Args:
        text: ``udpout:HOST:PORT``, ``udpin:HOST:PORT``, ``tcp:HOST:PORT``, ``tcpin:HOST:PORT`` or
            ``/dev/ttyX[,BAUD]`` or ``serial:/absolute/path[,BAUD]`` (IPv6 hosts in brackets,
            e.g. ``udpout:[::1]:14550``).

    Returns:
        The parsed specification.

    Raises:
        ValueError: The string is malformed; the message says what a valid one looks like.
    """
    text = text.strip()
    if text.startswith("/dev/"):
        return _parse_serial(text, "/dev/")
    if text.startswith("serial:"):
        # Any absolute path, e.g. a udev or pty symlink: serial:/run/fc/ttyACM,115200
        return _parse_serial(text.removeprefix("serial:"), "/")
    scheme, sep, rest = text.partition(":")
    kinds: dict[str, LinkKind] = {
        "udpout": "udpout",
        "udpin": "udpin",
        "tcp": "tcp",
        "tcpin": "tcpin",
    }
    if not sep or scheme not in kinds:
        raise ValueError(
            f"unknown connection '{text}'; use udpout:HOST:PORT, udpin:HOST:PORT, "
            "tcp:HOST:PORT, tcpin:HOST:PORT or /dev/ttyX,BAUD"
        )
    host, port = _split_host_port(text, rest)
    kind = kinds[scheme]
    if kind in ("udpout", "tcp") and host in ("0.0.0.0", "::"):
        raise ValueError(f"'{text}': {kind} needs a destination address, not a wildcard")
    return LinkSpec(kind=kind, host=host, port=port)


def _split_host_port(text: str, rest: str) -> tuple[str, int]:
    if rest.startswith("["):
        host, bracket, tail = rest[1:].partition("]")
        if not bracket or not tail.startswith(":"):
            raise ValueError(f"'{text}': an IPv6 host needs brackets and a port, e.g. [::1]:14550")
        port_text = tail[1:]
        try:
            ipaddress.IPv6Address(host)
        except ValueError as exc:
            raise ValueError(f"'{text}': '{host}' is not an IPv6 address") from exc
    else:
        host, colon, port_text = rest.rpartition(":")
        if not colon or not host:
            raise ValueError(f"'{text}': missing host or port; write e.g. udpout:127.0.0.1:14550")
    if not port_text.isdigit() or not 1 <= int(port_text) <= 65535:
        raise ValueError(f"'{text}': port must be a number from 1 to 65535")
    return host, int(port_text)


def _parse_serial(text: str, prefix: str) -> LinkSpec:
    device, _, baud_text = text.partition(",")
    if not device.startswith(prefix) or len(device) <= len(prefix):
        raise ValueError(
            f"'{text}': a serial link is /dev/ttyX[,BAUD] or serial:/absolute/path[,BAUD]"
        )
    if not baud_text:
        return LinkSpec(kind="serial", device=device, baud=DEFAULT_BAUD)
    if not baud_text.isdigit():
        raise ValueError(f"'{text}': baud rate '{baud_text}' is not a number")
    baud = int(baud_text)
    if baud not in STANDARD_BAUDS:
        choices = ", ".join(str(b) for b in STANDARD_BAUDS)
        raise ValueError(f"'{text}': unsupported baud rate {baud}; use one of {choices}")
    return LinkSpec(kind="serial", device=device, baud=baud)


def parse_address(text: str) -> tuple[str, int | None]:
    """Parse a peer's address: ``HOST`` or ``HOST:PORT`` (IPv6 as ``[ADDR]`` or ``[ADDR]:PORT``).

    The host must be an IP address (a datagram's sender is one; a name could resolve to
    another address later).

    Returns:
        The address as text and the port (None when not given).

    Raises:
        ValueError: Not an address with an optional port; the message says what is.
    """
    text = text.strip()
    port_text = ""
    if text.startswith("["):
        host, bracket, tail = text[1:].partition("]")
        if not bracket or (tail and not tail.startswith(":")):
            raise ValueError(f"'{text}': write an IPv6 address as [ADDR] or [ADDR]:PORT")
        port_text = tail[1:]
    elif text.count(":") == 1:
        host, _, port_text = text.partition(":")
    else:
        host = text
    try:
        ipaddress.ip_address(host)
    except ValueError:
        raise ValueError(
            f"'{text}': not an IP address (a name is not taken: the autopilot's datagrams "
            "come from an address); write e.g. 127.0.0.1, 192.168.1.5:14550 or [::1]"
        ) from None
    if not port_text:
        return host, None
    if not port_text.isdigit() or not 1 <= int(port_text) <= 65535:
        raise ValueError(f"'{text}': port must be a number from 1 to 65535")
    return host, int(port_text)
