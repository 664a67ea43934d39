"""The ``debug_server`` section: the live debug view and metrics over HTTP (off by default)."""

from __future__ import annotations

import ipaddress

from pydantic import Field, ValidationInfo, field_validator

from avoidd.config.base import Strict

LOOPBACK_NAMES = frozenset({"localhost", "localhost.localdomain", "ip6-localhost"})


def is_loopback(host: str) -> bool:
    """Whether ``host`` (an address or a name) can only be reached from this machine."""
    if host.lower() in LOOPBACK_NAMES:
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False  # a name: it may resolve to any interface


class DebugServerConfig(Strict):
    """A web page per rig (images, the sent scan, status), ``/api/stats`` and ``/metrics``.

    The page and the metrics show what the cameras see and where the vehicle is going: by
    default they are served on the loopback interface only (reach them through an SSH tunnel).
    Serving them on another address takes both ``allow_remote: true`` and a ``token``.

    Attributes:
        enabled: Start the server with the daemon.
        allow_remote: Let ``host`` be an address other than loopback (needs a ``token``).
        token: When set, every request must carry it (``?token=...`` or
            ``Authorization: Bearer ...``); at least 16 characters.
        host: Address to listen on (``127.0.0.1``, ``::1``, ``localhost``; others need
            ``allow_remote`` and ``token``).
        port: TCP port (0: any free port, logged at start).
        stream_fps: Frames per second of the image streams (each is encoded only while
            someone watches it).
        jpeg_quality: JPEG quality of the streams (higher: sharper, more CPU and bandwidth).
    """

    enabled: bool = False
    allow_remote: bool = False
    token: str | None = Field(None, min_length=16, max_length=256, pattern=r"^[!-~]+$")
    host: str = Field("127.0.0.1", min_length=1, max_length=255)
    port: int = Field(8080, ge=0, le=65535)
    stream_fps: float = Field(10.0, ge=0.5, le=30.0)
    jpeg_quality: int = Field(75, ge=20, le=95)

    @field_validator("host")
    @classmethod
    def _remote_needs_token(cls, value: str, info: ValidationInfo) -> str:
        if is_loopback(value):
            return value
        if not info.data.get("allow_remote", False):
            raise ValueError(
                f"'{value}' is not a loopback address: the debug view would be reachable from "
                "the network; use 127.0.0.1 (and an SSH tunnel), or set allow_remote: true "
                "and a token"
            )
        if info.data.get("token") is None:
            raise ValueError(
                f"serving on '{value}' needs a token (16 or more characters) so that only "
                "those who know it see the cameras; add token: ..."
            )
        return value
