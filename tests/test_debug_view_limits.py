"""The debug view's limits (issue 52, items 7, 8 and 9): viewers and connections capped with 503,
silent connections closed, other sites' host names refused, aiohttp's and the loop's errors
one counted line each. Real sockets on loopback against the daemon of ``test_debug_view``.
"""

from __future__ import annotations

import asyncio
import errno
import http.client
import logging
import socket
import time
from pathlib import Path

import pytest

from avoidd import foreignlog
from avoidd.config import DebugServerConfig
from avoidd.debugview.gate import host_allowed
from tests.test_debug_view import read_parts, running


def _stream(port: int, path: str = "/stream/polar.mjpg") -> http.client.HTTPResponse:
    connection = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
    connection.request("GET", path)
    return connection.getresponse()


def _wait(predicate: object, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():  # type: ignore[operator]
            return True
        time.sleep(0.02)
    return bool(predicate())  # type: ignore[operator]


def test_streams_beyond_max_viewers_get_503_and_a_freed_place_is_served(tmp_path: Path) -> None:
    with running(tmp_path, max_viewers=2, max_connections=8) as rig:
        first, second = _stream(rig.server.port), _stream(rig.server.port)
        assert (first.status, second.status) == (200, 200)
        assert len(read_parts(first, 1)) == 1 and len(read_parts(second, 1)) == 1
        third = _stream(rig.server.port, "/stream/head/front.mjpg")
        assert third.status == 503 and third.headers["Retry-After"] == "5"
        assert b"debug_server.max_viewers" in third.read()
        assert rig.get("/api/stats")[0] == 200  # the rest of the view is still served
        first.close()
        assert _wait(lambda: rig.server.viewers == 1, 10.0)
        again = _stream(rig.server.port)
        assert again.status == 200 and len(read_parts(again, 1)) == 1
        again.close()
        second.close()


def test_connections_beyond_max_connections_get_503_and_close(tmp_path: Path) -> None:
    with running(tmp_path, max_viewers=2, max_connections=4) as rig:
        idle = [socket.create_connection(("127.0.0.1", rig.server.port)) for _ in range(4)]
        try:
            assert _wait(lambda: rig.server.gate.open == 4, 10.0)
            extra = socket.create_connection(("127.0.0.1", rig.server.port), timeout=10)
            extra.sendall(b"GET /api/stats HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
            answer = b""
            while chunk := extra.recv(4096):
                answer += chunk
            extra.close()
            assert answer.startswith(b"HTTP/1.1 503 Service Unavailable\r\n"), answer
            assert b"too many connections" in answer
            assert rig.server.gate.refused >= 1
        finally:
            for connection in idle:
                connection.close()
        assert _wait(lambda: rig.server.gate.open == 0, 10.0)
        assert rig.get("/api/stats")[0] == 200


def test_a_connection_that_sends_nothing_is_closed(tmp_path: Path) -> None:
    with running(tmp_path) as rig:
        rig.server.gate.first_bytes_s = 0.5  # the next connections only
        silent = socket.create_connection(("127.0.0.1", rig.server.port), timeout=10)
        assert silent.recv(1) == b""  # closed by the view, not by this end
        silent.close()
        assert rig.server.gate.silent == 1
        assert rig.get("/api/stats")[0] == 200  # one that speaks is served


def test_a_host_header_of_another_name_is_refused(tmp_path: Path) -> None:
    with running(tmp_path, host_names=["drone.local"]) as rig:
        port = rig.server.port
        for host in (f"127.0.0.1:{port}", f"localhost:{port}", "drone.local", "[::1]:80"):
            assert rig.get("/api/stats", {"Host": host})[0] == 200, host
        for host in (f"evil.example:{port}", "attacker.test", "127.0.0.1.evil.example"):
            status, _, body = rig.get("/api/stats", {"Host": host})
            assert status == 421 and b"DNS rebinding" in body, host
        assert rig.server.refused_hosts == 3


def test_host_allowed_takes_addresses_and_known_names_only() -> None:
    assert host_allowed(None, [])
    assert host_allowed("192.168.1.7:8080", []) and host_allowed("[fe80::1]:80", [])
    assert host_allowed("LOCALHOST.", []) and host_allowed("Drone.Local:80", ["drone.local"])
    assert not host_allowed("drone.local", []) and not host_allowed("localhost.evil", [])


def test_a_bracketed_ipv6_host_listens_on_the_address_inside(tmp_path: Path) -> None:
    assert DebugServerConfig(host="[::1]").host == "::1"
    with pytest.raises(ValueError, match="brackets hold an IPv6 address"):
        DebugServerConfig(host="[localhost]")
    with running(tmp_path, host="[::1]") as rig:
        connection = http.client.HTTPConnection("::1", rig.server.port, timeout=10)
        connection.request("GET", "/api/stats")
        assert connection.getresponse().status == 200
        connection.close()


def test_malformed_requests_are_one_counted_line_without_a_traceback(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO)
    with running(tmp_path) as rig:
        for _ in range(100):
            bad = socket.create_connection(("127.0.0.1", rig.server.port), timeout=10)
            bad.sendall(b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nBad\x01Header: y\r\n\r\n")
            assert bad.recv(64).split(b" ")[1] == b"400"
            bad.close()
    foreign = [r for r in caplog.records if r.name.startswith("aiohttp")]
    assert foreign == [], foreign[:1]
    said = [r.getMessage() for r in caplog.records if r.name == "avoidd.foreignlog"]
    assert len(said) == 2, said  # the first at once, the other 99 counted at stop
    assert "aiohttp.server: Error handling request" in said[0] and "BadHttpMessage" in said[0]
    assert "99 more" in said[1] and "(100 in all)" in said[1]
    assert not any(r.exc_info for r in caplog.records)


async def test_the_loops_accept_failures_are_one_line_and_a_count(
    caplog: pytest.LogCaptureFixture,
) -> None:
    # What asyncio reports each time accept() fails for want of descriptors.
    loop = asyncio.get_running_loop()
    clock = {"s": 0.0}
    errors = foreignlog.ForeignErrors(clock=lambda: clock["s"])
    loop.set_exception_handler(errors.loop_handler)
    caplog.set_level(logging.INFO)
    try:
        for step in range(2000):
            clock["s"] = step * 0.01  # 20 s
            loop.call_exception_handler(
                {
                    "message": "socket.accept() out of system resource",
                    "exception": OSError(errno.EMFILE, "Too many open files"),
                }
            )
    finally:
        loop.set_exception_handler(None)
    errors.flush()
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 2, lines
    assert lines[0].startswith("asyncio: socket.accept() out of system resource: OSError")
    assert "1999 more" in lines[1] and "(2000 in all)" in lines[1]
    assert not any(r.exc_info for r in caplog.records)
