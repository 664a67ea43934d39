"""The ``debug_server`` section: the live debug view and metrics over HTTP (off by default)."""

from __future__ import annotations

import importlib.util
import ipaddress
from typing import Annotated

from pydantic import Field, ValidationInfo, field_validator, model_validator

from avoidd.config.base import Strict

LOOPBACK_NAMES = frozenset({"localhost", "localhost.localdomain", "ip6-localhost"})
_LABEL = r"[A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?"
_HOST_NAME = rf"^{_LABEL}(\.{_LABEL})*\.?$"
"""A DNS name: dot-separated labels of letters, digits and inner hyphens."""


def is_loopback(host: str) -> bool:
    """Whether ``host`` (an address or a name) can only be reached from this machine."""
    if host.lower() in LOOPBACK_NAMES:
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False  # a name: it may resolve to any interface


class VideoConfig(Strict):
    """The debug view's picture as an H.264 video over RTP/UDP that a ground station opens.

    QGroundControl's "UDP h.264 Video Stream" listens on port 5600; Mission Planner, VLC and
    ffplay open it with the SDP file the daemon writes beside it (see docs/debugview.md). It
    needs PyAV (``pip install 'avoidd[video]'``).

    Attributes:
        enabled: Send the video (off by default).
        host: Where to send it: loopback unless ``allow_remote`` (the ground station's
            address, for instance).
        allow_remote: Let ``host`` be an address other than loopback (the picture shows what
            the cameras see, unencrypted).
        port: UDP port of the receiver.
        fps: Frames per second.
        width_px: Width of the picture (even).
        height_px: Height of the picture (even).
        bitrate_kbps: The encoder's target rate.
        sdp_path: Where to write the stream's SDP description (None: not written).
    """

    enabled: bool = False
    host: str = Field("127.0.0.1", min_length=1, max_length=255)
    allow_remote: bool = False
    port: int = Field(5600, ge=1, le=65535)
    fps: float = Field(10.0, ge=1.0, le=30.0)
    width_px: int = Field(1280, ge=320, le=1920, multiple_of=2)
    height_px: int = Field(720, ge=240, le=1080, multiple_of=2)
    bitrate_kbps: int = Field(1500, ge=100, le=20000)
    sdp_path: str | None = None

    @model_validator(mode="after")
    def _loopback_unless_allowed(self) -> VideoConfig:
        if not is_loopback(self.host) and not self.allow_remote:
            raise ValueError(
                f"video host '{self.host}' is not a loopback address: the cameras' picture "
                "would go out on the network; use 127.0.0.1, or set allow_remote: true"
            )
        if self.enabled and importlib.util.find_spec("av") is None:
            raise ValueError(
                "video.enabled needs PyAV, which is not installed: pip install 'avoidd[video]' "
                "(or turn the video off)"
            )
        return self


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
            ``allow_remote`` and ``token``). An IPv6 address may be written in brackets as in
            a URL (``[::1]``).
        port: TCP port (0: any free port, logged at start).
        stream_fps: Frames per second of the image streams (each is encoded only while
            someone watches it).
        jpeg_quality: JPEG quality of the streams (higher: sharper, more CPU and bandwidth).
        max_viewers: Image streams served at once; one more is answered 503 (each costs
            the daemon's event loop a write per picture).
        max_connections: HTTP connections open at once; one more is answered 503 and
            closed (the view shares the daemon's file descriptors with cameras and link).
        host_names: Names besides loopback ones (``localhost``) the view may be reached by
            (``drone.local``); a request whose ``Host`` is another name is refused, which
            stops DNS rebinding. Addresses (``127.0.0.1``, ``192.168.1.7``) always pass.
        video: The page's picture as a video a ground station shows (off by default).
    """

    enabled: bool = False
    allow_remote: bool = False
    token: str | None = Field(None, min_length=16, max_length=256, pattern=r"^[!-~]+$")
    host: str = Field("127.0.0.1", min_length=1, max_length=255)
    port: int = Field(8080, ge=0, le=65535)
    stream_fps: float = Field(10.0, ge=0.5, le=30.0)
    jpeg_quality: int = Field(75, ge=20, le=95)
    max_viewers: int = Field(8, ge=1, le=64)
    max_connections: int = Field(32, ge=2, le=256)
    # pydantic copies a mutable default per instance; ruff cannot see that Strict is a model.
    host_names: list[Annotated[str, Field(pattern=_HOST_NAME)]] = []  # noqa: RUF012
    video: VideoConfig = VideoConfig()

    @model_validator(mode="after")
    def _video_with_the_view(self) -> DebugServerConfig:
        if self.video.enabled and not self.enabled:
            raise ValueError(
                "video.enabled needs the debug view itself: set debug_server.enabled: true "
                "(it may stay on loopback), or turn the video off"
            )
        return self

    @model_validator(mode="after")
    def _viewers_fit(self) -> DebugServerConfig:
        if self.max_connections <= self.max_viewers:
            raise ValueError(
                f"max_connections ({self.max_connections}) must exceed max_viewers "
                f"({self.max_viewers}): the page and /api/stats need connections too"
            )
        return self

    @field_validator("host")
    @classmethod
    def _remote_needs_token(cls, value: str, info: ValidationInfo) -> str:
        if value.startswith("[") or value.endswith("]"):
            # A URL's brackets: the server listens on the address inside them.
            inner = value.removeprefix("[").removesuffix("]")
            try:
                ipaddress.IPv6Address(inner)
            except ValueError:
                raise ValueError(
                    f"'{value}': brackets hold an IPv6 address; write the address (::1) "
                    "or a name without them"
                ) from None
            value = inner
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
