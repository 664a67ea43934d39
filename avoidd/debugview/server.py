"""The debug view's HTTP server (aiohttp): the page, MJPEG streams, ``/api/stats``, ``/metrics``.

Endpoints (every one needs the token when one is configured: ``?token=`` or
``Authorization: Bearer``):

- ``/``: the rig's page;
- ``/stream/head/{name}.mjpg``, ``/stream/polar.mjpg``: MJPEG (``multipart/x-mixed-replace``)
  at ``stream_fps``; ``/snapshot/head/{name}.jpg``, ``/snapshot/polar.jpg``: one picture;
- ``/api/stats``: JSON, rates over the time since the previous call (at least a second);
- ``/metrics``: Prometheus text exposition.
"""

from __future__ import annotations

import asyncio
import hmac
import json
import logging
import time
from collections.abc import Awaitable, Callable, Mapping
from concurrent.futures import ThreadPoolExecutor
from typing import TYPE_CHECKING

from aiohttp import web
from prometheus_client import (
    CONTENT_TYPE_LATEST,
    CollectorRegistry,
    ProcessCollector,
    generate_latest,
)

from avoidd.config import DebugServerConfig
from avoidd.debugview import metrics, views
from avoidd.debugview.gate import ConnectionGate, host_allowed
from avoidd.debugview.page import page_html

if TYPE_CHECKING:
    from avoidd.daemon.core import Daemon
    from avoidd.daemon.stats import DaemonStats

logger = logging.getLogger(__name__)

_BOUNDARY = "avoiddframe"
_RATE_WINDOW_NS = 1_000_000_000
_RETRY_BIND_S = 10.0
_KEEPALIVE_S = 10.0
"""An idle kept-alive connection is closed after this long (aiohttp's default is 75 s)."""

Handler = Callable[[web.Request], Awaitable[web.StreamResponse]]


class DebugServer:
    """Serves the debug view of a running daemon.

    Args:
        config: The ``debug_server`` section.
        daemon: The daemon (its heads, outputs, avoidance loop and snapshot are read, never
            changed).

    Attributes:
        port: The port listened on, once started (the chosen one when configured as 0).
        counter: JPEG pictures encoded so far, and their cost.
        viewers: Streams being watched now.
        gate: Bounds the open connections, once serving.
        refused_hosts: Requests refused for their ``Host`` header.
    """

    def __init__(self, config: DebugServerConfig, daemon: Daemon) -> None:
        self.config = config
        self.daemon = daemon
        self.port: int | None = None
        self.counter = views.EncodeCounter()
        self.viewers = 0
        self.gate: ConnectionGate | None = None
        self.refused_hosts = 0
        # One thread of its own draws every picture: however many streams are watched, the
        # view never draws two at once nor takes asyncio's default threads. (Niced, it was no
        # better: 50 viewers beside two busy loops gave the same gaps, and a niced thread
        # holding the interpreter lock makes the others wait while it waits for a CPU.)
        self._draw_pool = ThreadPoolExecutor(1, thread_name_prefix="debugview-draw")
        self._streams: dict[str, views.Stream] = {}
        self._previous: DaemonStats | None = None
        self._closing = False
        self.registry = CollectorRegistry(auto_describe=False)
        self.registry.register(metrics.DaemonCollector(self._snapshot, self._own_counters))
        # The process's CPU seconds, resident memory and open files, read from /proc.
        ProcessCollector(registry=self.registry)

    def _snapshot(self) -> DaemonStats:
        return self.daemon.snapshot(time.monotonic_ns())

    def _own_counters(self) -> Mapping[str, tuple[str, float]]:
        return {
            "avoidd_debugview_jpeg_encodes": (
                "Pictures the debug view drew and encoded (only while watched).",
                self.counter.encodes,
            ),
            "avoidd_debugview_encode_seconds": (
                "CPU time spent drawing and encoding them.",
                self.counter.seconds,
            ),
        }

    def _stream(self, name: str) -> views.Stream | None:
        """The stream ``polar`` or ``head/NAME``, made on first use (None if no such head)."""
        stream = self._streams.get(name)
        if stream is not None:
            return stream
        quality = self.config.jpeg_quality
        max_range_m = self.daemon.config.mavlink.obstacle_distance.max_distance_cm / 100.0
        if name == "polar":
            stream = views.polar_stream(self.daemon, quality, self.counter, self._draw_pool)
        else:
            head = next((h for h in self.daemon.heads if f"head/{h.name}" == name), None)
            if head is None:
                return None
            stream = views.head_stream(head, max_range_m, quality, self.counter, self._draw_pool)
        self._streams[name] = stream
        return stream

    def app(self) -> web.Application:
        """The aiohttp application (routes, the host check and the token check)."""
        app = web.Application(middlewares=[self._check_host, self._check_token])
        app.router.add_get("/", self._page)
        app.router.add_get("/api/stats", self._stats)
        app.router.add_get("/metrics", self._metrics)
        app.router.add_get("/stream/polar.mjpg", self._mjpeg)
        app.router.add_get("/stream/head/{head}.mjpg", self._mjpeg)
        app.router.add_get("/snapshot/polar.jpg", self._snapshot_jpeg)
        app.router.add_get("/snapshot/head/{head}.jpg", self._snapshot_jpeg)
        return app

    @web.middleware
    async def _check_host(self, request: web.Request, handler: Handler) -> web.StreamResponse:
        header = request.headers.get("Host")
        if not host_allowed(header, [*self.config.host_names, self.config.host]):
            self.refused_hosts += 1
            raise web.HTTPMisdirectedRequest(
                text=f"host '{header}' is not served here (DNS rebinding?); open the view by "
                "its address, e.g. http://127.0.0.1:PORT/, or add the name to "
                "debug_server.host_names\n"
            )
        return await handler(request)

    @web.middleware
    async def _check_token(self, request: web.Request, handler: Handler) -> web.StreamResponse:
        token = self.config.token
        if token is not None and not hmac.compare_digest(
            _given_token(request).encode(), token.encode()
        ):
            raise web.HTTPUnauthorized(
                text="token required: add ?token=... or an Authorization: Bearer header\n",
                headers={"WWW-Authenticate": 'Bearer realm="avoidd"'},
            )
        return await handler(request)

    async def _page(self, request: web.Request) -> web.Response:
        token = _given_token(request) if self.config.token else None
        names = [head.name for head in self.daemon.heads]
        return web.Response(text=page_html(names, token), content_type="text/html")

    async def _stats(self, request: web.Request) -> web.Response:
        now = self._snapshot()
        record = metrics.stats_record(now, self._previous)
        record["debug_view"] = {
            "viewers": self.viewers,
            "jpeg_encodes": self.counter.encodes,
            "encode_seconds": round(self.counter.seconds, 3),
        }
        if self._previous is None or now.t_ns - self._previous.t_ns >= _RATE_WINDOW_NS:
            self._previous = now
        return web.Response(text=json.dumps(record), content_type="application/json")

    async def _metrics(self, request: web.Request) -> web.Response:
        body = await asyncio.to_thread(generate_latest, self.registry)
        return web.Response(body=body, headers={"Content-Type": CONTENT_TYPE_LATEST})

    def _requested(self, request: web.Request) -> views.Stream:
        head = request.match_info.get("head")
        stream = self._stream("polar" if head is None else f"head/{head}")
        if stream is None:
            raise web.HTTPNotFound(text=f"no head '{head}'\n")
        return stream

    async def _snapshot_jpeg(self, request: web.Request) -> web.Response:
        data = await self._requested(request).jpeg()
        if data is None:
            raise web.HTTPServiceUnavailable(text="nothing to show yet\n")
        return web.Response(body=data, content_type="image/jpeg")

    async def _mjpeg(self, request: web.Request) -> web.StreamResponse:
        stream = self._requested(request)
        if self.viewers >= self.config.max_viewers:
            raise web.HTTPServiceUnavailable(
                text=f"{self.viewers} streams are being watched, the most the debug view "
                "serves (debug_server.max_viewers); close one and retry\n",
                headers={"Retry-After": "5"},
            )
        response = web.StreamResponse(
            headers={
                "Content-Type": f"multipart/x-mixed-replace; boundary={_BOUNDARY}",
                "Cache-Control": "no-cache, no-store, must-revalidate",
                "Pragma": "no-cache",
            }
        )
        await response.prepare(request)
        period_s = 1.0 / self.config.stream_fps
        self.viewers += 1
        try:
            await response.write(f"--{_BOUNDARY}\r\n".encode())
            last: bytes | None = None
            while not self._closing:
                transport = request.transport
                if transport is None or transport.is_closing():
                    break
                started_s = time.monotonic()
                data = await stream.jpeg()
                if data is not None and data is not last:
                    head = f"Content-Type: image/jpeg\r\nContent-Length: {len(data)}\r\n\r\n"
                    # Each part ends with the next boundary, so a browser shows it at once.
                    await response.write(head.encode() + data + f"\r\n--{_BOUNDARY}\r\n".encode())
                    last = data
                await asyncio.sleep(max(0.0, period_s - (time.monotonic() - started_s)))
        except ConnectionError:
            pass  # the viewer left
        finally:
            self.viewers -= 1
        return response

    async def run(self) -> None:
        """Serve until cancelled (a daemon loop; never ends on its own).

        A port that cannot be bound is logged and tried again every 10 s: the daemon flies on
        without its debug view.
        """
        runner = web.AppRunner(
            self.app(), access_log=None, shutdown_timeout=1.0, keepalive_timeout=_KEEPALIVE_S
        )
        await runner.setup()
        listening: asyncio.Server | None = None
        try:
            assert runner.server is not None
            self.gate = ConnectionGate(runner.server, self.config.max_connections)
            listening = await self._bind(self.gate)
            self._previous = self._snapshot()  # the first /api/stats has rates since now
            self.port = int(listening.sockets[0].getsockname()[1])
            host = self.config.host
            shown = f"[{host}]" if ":" in host else host
            logger.info(
                "debug view on http://%s:%d/%s",
                shown,
                self.port,
                " (token required)" if self.config.token else "",
            )
            video = self.config.video
            if video.enabled:
                from avoidd.debugview.video import run_video

                await run_video(
                    video, lambda: views.video_drawing(self.daemon, video.width_px, video.height_px)
                )
            await asyncio.Event().wait()
        finally:
            self._closing = True
            if listening is not None:
                listening.close()
            await runner.cleanup()
            self._draw_pool.shutdown(wait=False)

    async def _bind(self, gate: ConnectionGate) -> asyncio.Server:
        loop = asyncio.get_running_loop()
        while True:
            try:
                return await loop.create_server(
                    gate, self.config.host, self.config.port, reuse_address=True
                )
            except OSError as exc:
                logger.error(
                    "debug view: cannot listen on %s port %d (%s); retrying in %.0f s",
                    self.config.host,
                    self.config.port,
                    exc.strerror or exc,
                    _RETRY_BIND_S,
                )
                await asyncio.sleep(_RETRY_BIND_S)


def _given_token(request: web.Request) -> str:
    """The token a request carries (query or bearer header), or an empty string."""
    header = request.headers.get("Authorization", "")
    scheme, _, value = header.partition(" ")
    if scheme.lower() == "bearer" and value.strip():
        return value.strip()
    return request.query.get("token", "")
