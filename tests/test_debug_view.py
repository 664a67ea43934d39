"""The debug view: its config, endpoints over a real loopback socket, the token, the MJPEG
streams (encoded only while watched), /metrics, and the page in a real headless Chromium."""

from __future__ import annotations

import asyncio
import contextlib
import http.client
import json
import os
import shutil
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from prometheus_client.parser import text_string_to_metric_families

from avoidd.config import DebugServerConfig, load_config
from avoidd.debugview import render
from avoidd.errors import ConfigError
from tests.helpers import free_udp_port, synthetic_config, write_rectified_calibration
from tests.test_config import BASE, write

TOKEN = "s3cret-token-for-tests"
CHROMIUM = Path("/usr/bin/chromium")
CHROMEDRIVER = Path("/usr/bin/chromedriver")


# --- configuration -------------------------------------------------------------------------


def test_debug_server_is_off_and_on_loopback_by_default(tmp_path: Path) -> None:
    config = load_config(write(tmp_path, BASE)).debug_server
    assert config == DebugServerConfig()
    assert (config.enabled, config.host, config.port, config.token) == (
        False,
        "127.0.0.1",
        8080,
        None,
    )
    for host in ("127.0.0.1", "127.0.0.53", "::1", "localhost"):
        assert (
            load_config(
                write(tmp_path, BASE + f"debug_server: {{enabled: true, host: '{host}'}}\n")
            ).debug_server.host
            == host
        )


@pytest.mark.parametrize(
    ("section", "expected"),
    [
        (
            "debug_server:\n  enabled: true\n  host: 0.0.0.0\n",
            "avoidd.yaml:14: debug_server.host: '0.0.0.0' is not a loopback address",
        ),
        (
            "debug_server:\n  enabled: true\n  host: drone.local\n  token: " + TOKEN + "\n",
            "avoidd.yaml:14: debug_server.host: 'drone.local' is not a loopback address",
        ),
        (
            "debug_server:\n  allow_remote: true\n  host: 192.168.1.5\n",
            "avoidd.yaml:14: debug_server.host: serving on '192.168.1.5' needs a token",
        ),
        (
            "debug_server:\n  enabled: true\n  token: short\n",
            "avoidd.yaml:14: debug_server.token: String should have at least 16 characters",
        ),
        (
            "debug_server:\n  enabled: true\n  port: 70000\n",
            "avoidd.yaml:14: debug_server.port: Input should be less than or equal to 65535",
        ),
    ],
)
def test_a_non_loopback_address_needs_allow_remote_and_a_token(
    tmp_path: Path, section: str, expected: str
) -> None:
    with pytest.raises(ConfigError) as info:
        load_config(write(tmp_path, BASE + section))
    assert len(info.value.lines) == 1, info.value.lines
    assert (
        info.value.lines[0].endswith(expected.split(": ", 2)[2])
        or expected in (info.value.lines[0])
    ), info.value.lines[0]
    assert info.value.lines[0].startswith(str(tmp_path / expected.split(":")[0])), info.value


def test_a_remote_address_with_allow_remote_and_a_token_loads(tmp_path: Path) -> None:
    text = BASE + f"debug_server:\n  allow_remote: true\n  token: {TOKEN}\n  host: 0.0.0.0\n"
    config = load_config(write(tmp_path, text)).debug_server
    assert (config.host, config.token) == ("0.0.0.0", TOKEN)


# --- pictures --------------------------------------------------------------------------------


def _pixel(image: np.ndarray, bearing_deg: float, fraction: float) -> tuple[int, ...]:
    """The plot's pixel at a bearing and a fraction of its radius (see ``polar_panel``)."""
    size = image.shape[0]
    cx, cy, radius = size // 2, size // 2 + 10, size // 2 - 30
    b = np.radians(bearing_deg)
    x = round(cx + fraction * radius * np.sin(b))
    y = round(cy - fraction * radius * np.cos(b))
    return tuple(int(v) for v in image[y, x])


def test_the_polar_plot_draws_the_bins_where_the_message_puts_them() -> None:
    # ArduPilot's layout: bin j at -20 + 5 j degrees. Bin 0 (-20 deg) a reading at 10 m,
    # bin 4 (0 deg, ahead) clear, bin 40 (180 deg) unknown, everything else clear.
    values = [2001] * 72
    values[0], values[40] = 1000, 65535
    sent = render.SentScan(tuple(values), 5.0, -20.0, 20, 2000)
    image = render.polar_panel(sent, 480)
    assert _pixel(image, -20.0, 0.3) == render.NEAR_BGR
    assert _pixel(image, -20.0, 0.8) != render.NEAR_BGR  # the reading ends at 10 of 20 m
    assert _pixel(image, 0.0, 0.9) == render.CLEAR_BGR
    assert _pixel(image, 180.0, 0.6) == render.UNKNOWN_BGR
    # PX4's layout: 36 bins of 10 degrees from 0; slots 36 to 71 are unused, not drawn.
    px4 = [65535] * 72
    px4[9] = 500  # 90 deg (right), 5 m
    image = render.polar_panel(render.SentScan(tuple(px4), 10.0, 0.0, 20, 2000), 480)
    assert _pixel(image, 90.0, 0.2) == render.NEAR_BGR
    assert _pixel(image, 270.0, 0.2) == render.UNKNOWN_BGR
    assert [render.bin_kind(v, 20, 2000) for v in (65535, 2001, 20, 2000, 0, 3000)] == [
        "unknown",
        "clear",
        "near",
        "near",
        "invalid",
        "invalid",
    ]


def test_obstacle_boxes_outline_regions_nearest_first() -> None:
    mask = np.zeros((120, 160), dtype=bool)
    depth = np.full((120, 160), np.nan, dtype=np.float32)
    mask[10:50, 20:40], depth[10:50, 20:40] = True, 8.0
    mask[60:100, 100:150], depth[60:100, 100:150] = True, 3.0
    mask[0:2, 0:2] = True  # a speck: no box
    boxes = render.obstacle_boxes(mask, depth)
    assert [(b.x, b.y, b.width, b.height) for b in boxes] == [(100, 60, 50, 40), (20, 10, 20, 40)]
    assert [b.distance_m for b in boxes] == [3.0, 8.0]
    picture = render.left_panel(np.zeros((120, 160), np.uint8), boxes, 20.0, "front")
    assert picture.shape == (120, 160, 3) and picture.any()
    assert render.depth_panel(depth, 20.0).shape == (120, 160, 3)


def test_planner_arrows_are_turned_into_the_body_frame() -> None:
    from types import SimpleNamespace

    from avoidd.debugview.views import planner_bearings
    from avoidd.mavlink.attitude import Attitude
    from avoidd.planner.core import Decision, Goal

    decision = Decision((1.0, 0.0, 0.0), 0.0, "moving", direction_deg=30.0)
    daemon: Any = SimpleNamespace(
        avoidance=SimpleNamespace(
            config=SimpleNamespace(enabled=True), goal=Goal(10.0, 10.0, 2.0), last_decision=decision
        ),
        vehicle=SimpleNamespace(
            attitude_at=lambda t_ns: Attitude(t_ns, 0.0, 0.0, np.radians(90.0)),
            position=SimpleNamespace(north_m=0.0, east_m=0.0),
        ),
    )
    goal_deg, direction_deg = planner_bearings(daemon)  # heading east
    assert goal_deg == pytest.approx(45.0 - 90.0)
    assert direction_deg == pytest.approx(30.0 - 90.0)
    daemon.vehicle.attitude_at = lambda t_ns: None  # no yaw: no arrows
    assert planner_bearings(daemon) == (None, None)


# --- a real daemon with its debug view -------------------------------------------------------


class RunningDaemon:
    """A daemon on the synthetic test rig run in a thread with its own event loop."""

    def __init__(
        self, folder: Path, debug_server: dict[str, Any], heads: list[str] | None = None
    ) -> None:
        from avoidd.daemon import Daemon
        from avoidd.loading import load_all

        source = {"kind": "synthetic", "fps": 10, "seed": 3}
        calibration = str(write_rectified_calibration(folder))
        path = synthetic_config(
            folder,
            f"udpout:127.0.0.1:{free_udp_port()}",  # nobody there: no autopilot
            source=source,
            heads=None
            if heads is None
            else [
                {
                    "name": name,
                    "calibration": calibration,
                    "source": source | {"seed": 3 + k},
                    "mount": {"yaw_deg": 60.0 * k},
                }
                for k, name in enumerate(heads)
            ],
            sections={"debug_server": {"enabled": True, "port": 0, **debug_server}},
        )
        config, calibrations = load_all(path)
        self.daemon = Daemon(config, calibrations)
        self.code: int | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread = threading.Thread(target=self._run, name="test-daemon")

    def _run(self) -> None:
        async def main() -> int:
            self._loop = asyncio.get_running_loop()
            return await self.daemon.run()

        self.code = asyncio.run(main())

    @property
    def server(self) -> Any:
        return self.daemon.debug_server

    def start(self) -> None:
        self._thread.start()
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline:
            heads = self.daemon.heads
            if self.server is not None and self.server.port and heads and heads[0].latest:
                return
            time.sleep(0.05)
        raise AssertionError("the daemon did not serve a processed frame within 30 s")

    def stop(self) -> None:
        if self._loop is not None:
            self._loop.call_soon_threadsafe(self.daemon.stop)
        self._thread.join(30.0)
        assert not self._thread.is_alive()
        assert self.code == 0

    def get(self, path: str, headers: dict[str, str] | None = None) -> tuple[int, Any, bytes]:
        connection = http.client.HTTPConnection("127.0.0.1", self.server.port, timeout=10)
        try:
            connection.request("GET", path, headers=headers or {})
            response = connection.getresponse()
            return response.status, response.headers, response.read()
        finally:
            connection.close()


@contextlib.contextmanager
def running(
    folder: Path, heads: list[str] | None = None, **debug_server: Any
) -> Iterator[RunningDaemon]:
    daemon = RunningDaemon(folder, debug_server, heads)
    daemon.start()
    try:
        yield daemon
    finally:
        daemon.stop()


def read_parts(response: http.client.HTTPResponse, count: int) -> list[bytes]:
    """The next ``count`` JPEG parts of a multipart/x-mixed-replace response."""
    parts = []
    while len(parts) < count:
        line = response.readline()
        assert line, "stream ended"
        if line.lower().startswith(b"content-length:"):
            length = int(line.split(b":", 1)[1])
            assert response.readline() == b"\r\n"
            parts.append(response.read(length))
    return parts


def test_endpoints_over_loopback(tmp_path: Path) -> None:
    with running(tmp_path) as rig:
        status, headers, body = rig.get("/")
        assert status == 200 and headers["Content-Type"].startswith("text/html")
        page = body.decode()
        assert 'src="/stream/head/front.mjpg"' in page and 'src="/stream/polar.mjpg"' in page
        time.sleep(1.2)  # a second since the server's first snapshot: rates
        status, headers, body = rig.get("/api/stats")
        assert status == 200 and headers["Content-Type"].startswith("application/json")
        stats = json.loads(body)
        (head,) = stats["heads"]
        assert head["name"] == "front"
        assert 3.0 < head["captured_fps"] < 15.0, head
        # Over one window, frames captured before it may be processed in it (at most three in
        # flight: one waiting in the slot, one matching, one in the rest of the pipeline); the
        # counts never invent a frame.
        assert head["processed_fps"] > 0.0, head
        assert head["processed"] + head["skipped"] <= head["captured"], head
        in_flight_fps = 3.0 / stats["interval_s"]
        assert head["processed_fps"] <= head["captured_fps"] + in_flight_fps, head
        assert head["skipped_fps"] >= 0.0
        assert set(head["stage_ms"]) == {
            "rectify",
            "preprocess",
            "match",
            "post",
            "depth",
            "obstacles",
        }
        assert stats["link"]["up"] is False and stats["link"]["sent"]["HEARTBEAT"] >= 1
        status, headers, body = rig.get("/metrics")
        assert status == 200 and headers["Content-Type"].startswith("text/plain")
        families = {f.name: f for f in text_string_to_metric_families(body.decode())}
        for name in (
            "avoidd_frames_captured",
            "avoidd_frames_processed",
            "avoidd_frames_skipped",
            "avoidd_mavlink_sent_messages",
            "avoidd_debugview_jpeg_encodes",
        ):
            assert families[name].type == "counter", name
            assert all(s.name == f"{name}_total" for s in families[name].samples), name
        for name in ("avoidd_latency_seconds", "avoidd_stage_seconds", "avoidd_link_up"):
            assert families[name].type == "gauge", name
        stages = {s.labels["stage"]: s.value for s in families["avoidd_stage_seconds"].samples}
        assert 0.0 < stages["match"] < 5.0  # seconds, not milliseconds
        sent = {s.labels["type"]: s.value for s in families["avoidd_mavlink_sent_messages"].samples}
        assert sent["HEARTBEAT"] >= 1
        # The process itself (from /proc), the head's recent rate and its latency histogram.
        assert families["process_cpu_seconds"].samples[0].value > 0.0
        assert families["process_resident_memory_bytes"].samples[0].value > 10e6
        (fps,) = families["avoidd_head_fps"].samples
        assert fps.labels["head"] == "front" and 0.5 < fps.value < 15.0, fps
        latency = families["avoidd_capture_to_result_seconds"]
        assert latency.type == "histogram"
        buckets = [s for s in latency.samples if s.name.endswith("_bucket")]
        counts = [s.value for s in buckets]
        assert counts == sorted(counts) and buckets[-1].labels["le"] == "+Inf"
        (count,) = [s.value for s in latency.samples if s.name.endswith("_count")]
        (total_s,) = [s.value for s in latency.samples if s.name.endswith("_sum")]
        assert count == counts[-1] >= 1 and 0.0 < total_s / count < 5.0
        status, headers, body = rig.get("/snapshot/head/front.jpg")
        assert status == 200 and headers["Content-Type"] == "image/jpeg"
        picture = cv2.imdecode(np.frombuffer(body, np.uint8), cv2.IMREAD_COLOR)
        assert picture.shape == (240, 640, 3)  # left view and depth side by side
        assert rig.get("/snapshot/polar.jpg")[0] == 200
        assert rig.get("/snapshot/head/nosuch.jpg")[0] == 404
        assert rig.get("/stream/head/nosuch.mjpg")[0] == 404


def test_every_request_needs_the_token(tmp_path: Path) -> None:
    with running(tmp_path, token=TOKEN) as rig:
        for path in ("/", "/api/stats", "/metrics", "/snapshot/polar.jpg", "/stream/polar.mjpg"):
            status, headers, _ = rig.get(path)
            assert status == 401, path
            assert headers["WWW-Authenticate"].startswith("Bearer")
            assert rig.get(f"{path}?token=wrong-token-of-some-length")[0] == 401, path
            assert rig.get(path, {"Authorization": "Bearer nope"})[0] == 401, path
        for path in ("/api/stats", "/metrics", "/snapshot/polar.jpg"):
            assert rig.get(f"{path}?token={TOKEN}")[0] == 200, path
            assert rig.get(path, {"Authorization": f"Bearer {TOKEN}"})[0] == 200, path
        status, _, body = rig.get("/", {"Authorization": f"Bearer {TOKEN}"})
        assert status == 200
        # An img cannot send a header: the page's URLs carry the token.
        assert f'src="/stream/head/front.mjpg?token={TOKEN}"' in body.decode()


def test_streams_are_encoded_only_while_watched(tmp_path: Path) -> None:
    with running(tmp_path) as rig:
        processed = rig.daemon.heads[0].stats.processed
        for path in ("/", "/api/stats", "/metrics"):
            assert rig.get(path)[0] == 200
        time.sleep(1.5)
        assert rig.daemon.heads[0].stats.processed > processed  # frames went by ...
        assert rig.server.counter.encodes == 0  # ... and nobody watched: nothing encoded
        connection = http.client.HTTPConnection("127.0.0.1", rig.server.port, timeout=10)
        connection.request("GET", "/stream/head/front.mjpg")
        response = connection.getresponse()
        assert response.status == 200
        assert response.headers["Content-Type"].startswith("multipart/x-mixed-replace")
        parts = read_parts(response, 4)
        assert rig.server.viewers == 1
        for part in parts:
            assert part[:2] == b"\xff\xd8" and part[-2:] == b"\xff\xd9"  # whole JPEGs
            assert cv2.imdecode(np.frombuffer(part, np.uint8), cv2.IMREAD_COLOR) is not None
        assert len(set(parts)) == len(parts)  # each a newer frame
        assert rig.server.counter.encodes >= 4
        connection.close()
        deadline = time.monotonic() + 5.0
        while rig.server.viewers and time.monotonic() < deadline:
            time.sleep(0.05)
        assert rig.server.viewers == 0
        encodes = rig.server.counter.encodes
        time.sleep(1.0)
        assert rig.server.counter.encodes == encodes
        # A viewer still watching does not hold up the daemon's shutdown.
        watching = http.client.HTTPConnection("127.0.0.1", rig.server.port, timeout=10)
        watching.request("GET", "/stream/polar.mjpg")
        assert len(read_parts(watching.getresponse(), 1)) == 1
    watching.close()


# --- the page in a real browser --------------------------------------------------------------


def _colour_share(image: np.ndarray, bgr: tuple[int, int, int], tolerance: int = 40) -> float:
    close = np.all(np.abs(image.astype(np.int16) - np.array(bgr)) <= tolerance, axis=2)
    return float(close.mean())


def _badges(driver: Any) -> list[tuple[str, str]]:
    """The badges' texts and colours, read in one script (the page redraws them every second,
    so elements looked up one by one may be gone by the time they are read)."""
    found = driver.execute_script(
        "return Array.from(document.querySelectorAll('#badges .badge')).map("
        "b => [b.textContent, getComputedStyle(b).backgroundColor]);"
    )
    return [(str(text), str(colour)) for text, colour in found]


def test_the_page_in_headless_chromium(tmp_path: Path) -> None:
    if not (CHROMIUM.exists() and CHROMEDRIVER.exists()):
        pytest.skip("Debian's chromium and chromium-driver are not installed (.ci/run does it)")
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    options = webdriver.ChromeOptions()
    options.binary_location = str(CHROMIUM)
    for flag in (
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--window-size=1400,1000",
        f"--user-data-dir={tmp_path / 'chromium-profile'}",
    ):
        options.add_argument(flag)
    with running(tmp_path, ["front", "right"], token=TOKEN) as rig:
        driver = webdriver.Chrome(service=Service(str(CHROMEDRIVER)), options=options)
        try:
            driver.set_window_size(1400, 1000)
            driver.get(f"http://127.0.0.1:{rig.server.port}/?token={TOKEN}")
            wait = WebDriverWait(driver, 20)
            wait.until(lambda d: "fps" in d.find_element(By.ID, "status").text)
            for element_id in ("polar", "head-front", "head-right"):
                wait.until(
                    lambda d, i=element_id: (
                        d.execute_script(
                            "return document.getElementById(arguments[0]).naturalWidth", i
                        )
                        > 0
                    )
                )
            head = driver.find_element(By.ID, "head-front")
            first = head.screenshot_as_png
            time.sleep(1.0)
            assert head.screenshot_as_png != first  # the stream moves on
            time.sleep(2.5)  # a few seconds of history
            boxes = driver.execute_script(
                "const out = {};"
                "for (const id of arguments[0]) {"
                " const r = document.getElementById(id).getBoundingClientRect();"
                " out[id] = [r.left, r.top, r.right, r.bottom]; }"
                "out.viewport = [window.innerWidth, window.innerHeight];"
                "return out;",
                ["nearest", "badges", "polar", "history", "head-front", "head-right", "status"],
            )
            nearest_px = float(
                driver.execute_script(
                    "return parseFloat(getComputedStyle(document.getElementById("
                    "'nearest')).fontSize)"
                )
            )
            badges = _badges(driver)
            page = tmp_path / "debugview.png"
            assert driver.save_screenshot(str(page))
            polar_png = driver.find_element(By.ID, "polar").screenshot_as_png
            history_png = driver.find_element(By.ID, "history").screenshot_as_png
            status = driver.find_element(By.ID, "status").text
            # The page's own drawing of a state this rig cannot show: a head gone stale
            # beside a fresh one, the autopilot heard, nothing near.
            stale_head = {
                "processed_fps": 0.0,
                "captured_fps": 0.0,
                "skipped_fps": 0.0,
                "mean_latency_ms": 0.0,
            }
            driver.execute_script(
                "clearInterval(timer); show(arguments[0]);",
                {
                    "heads": [
                        stale_head | {"name": "front", "stale": False, "processed_fps": 10.0},
                        stale_head | {"name": "right", "stale": True},
                    ],
                    "link": {
                        "up": True,
                        "autopilot": "ArduPilot",
                        "system_id": 1,
                        "mode": "GUIDED",
                        "armed": True,
                    },
                    "healthy": False,
                    "fresh_data": True,
                    "nearest": None,
                    "planner": None,
                },
            )
            stale_badges = _badges(driver)
            nothing_near = driver.find_element(By.ID, "nearest").text
        finally:
            driver.quit()
    target = os.environ.get("AVOIDD_SCREENSHOT")
    if target:
        shutil.copyfile(page, target)
    # Everything fits a 1400x1000 window, and the two heads stand side by side.
    width, height = boxes.pop("viewport")
    for name, (left, top, right, bottom) in boxes.items():
        assert 0 <= left < right <= width and 0 <= top < bottom <= height, (name, boxes)
    front, right = boxes["head-front"], boxes["head-right"]
    assert abs(front[1] - right[1]) < 2 and right[0] >= front[2], boxes
    assert front[2] - front[0] >= 400  # each head at least 400 px wide
    assert nearest_px >= 32
    # No autopilot on the link: the amber NO LINK badge (no OK beside it).
    assert [text for text, _ in badges] == ["NO LINK"], badges
    assert badges[0][1] in ("rgb(176, 122, 0)", "rgba(176, 122, 0, 1)"), badges
    # A stale head: its red badge, and neither NO LINK (the link is up) nor OK.
    assert [text for text, _ in stale_badges] == ["STALE right"], stale_badges
    assert stale_badges[0][1] in ("rgb(179, 38, 30)", "rgba(179, 38, 30, 1)"), stale_badges
    assert nothing_near == "nothing near"
    screenshot = cv2.imread(str(page), cv2.IMREAD_COLOR)
    assert screenshot is not None and screenshot.std() > 20.0  # not blank
    polar = cv2.imdecode(np.frombuffer(polar_png, np.uint8), cv2.IMREAD_COLOR)
    assert polar.shape[1] >= 380
    # The plot's colours: unknown bins (no head looks back), clear ones ahead, readings.
    assert _colour_share(polar, render.UNKNOWN_BGR) > 0.15
    assert _colour_share(polar, render.CLEAR_BGR) > 0.002
    assert _colour_share(polar, render.NEAR_BGR) > 0.001
    # The history has drawn its lines (fps in blue, latency in amber).
    history = cv2.imdecode(np.frombuffer(history_png, np.uint8), cv2.IMREAD_COLOR)
    assert _colour_share(history, (255, 204, 102), 40) > 0.0001  # #6cf
    assert _colour_share(history, (102, 204, 255), 40) > 0.0001  # #fc6
    assert "front:" in status and "right:" in status and "no autopilot heard" in status
