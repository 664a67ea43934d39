"""Faults that recur every frame or retry give one log line per state change, not one per event."""

from __future__ import annotations

import asyncio
import logging
import os
import shutil
import socket
import subprocess
import sys
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from avoidd.config import MavlinkConfig
from avoidd.config.connection import parse_connection
from avoidd.daemon import Daemon
from avoidd.daemon.head import LOST_AFTER_BROKEN
from avoidd.loading import load_all
from avoidd.logrepeat import RepeatLimiter
from avoidd.mavlink import codec as mav
from avoidd.mavlink.link import MavLink
from avoidd.mavlink.transport import create_transport
from tests.helpers import REPO, open_udp_peer, synthetic_config, wait_for


class FakeClock:
    def __init__(self) -> None:
        self.now_s = 0.0

    def __call__(self) -> float:
        return self.now_s


def test_repeats_are_counted_and_summarised(caplog: pytest.LogCaptureFixture) -> None:
    clock = FakeClock()
    limiter = RepeatLimiter(logging.getLogger("test.repeat"), 60.0, clock)
    caplog.set_level(logging.INFO, logger="test.repeat")
    assert limiter.report(logging.WARNING, "missing", "frame 0 missing")
    for frame in range(1, 200):  # 10 a second for 20 s, then 10 a second until 199
        clock.now_s = frame / 10.0 if frame < 100 else 10.0 + frame * 0.5
        assert not limiter.report(logging.WARNING, "missing", f"frame {frame} missing")
    limiter.clear("frames again")
    lines = [r.getMessage() for r in caplog.records]
    assert lines[0] == "frame 0 missing"
    summaries = [line for line in lines if "repeated" in line]
    # One summary per 60 s of repeats, one when the state ends; every repeat counted once.
    assert len(lines) == len(summaries) + 2 and 2 <= len(summaries) <= 3, lines
    counts = [int(line.split("repeated ")[1].split(" times")[0]) for line in summaries]
    assert sum(counts) == 199
    assert lines[-1] == "frames again"
    assert not limiter.clear("nothing to clear")


def _write_pairs(folder: Path, count: int) -> None:
    rng = np.random.default_rng(0)
    for side in ("left", "right"):
        (folder / side).mkdir(parents=True)
        for index in range(count):
            image = rng.integers(0, 255, (240, 320), dtype=np.uint8)
            cv2.imwrite(str(folder / side / f"{index:03d}.png"), image)


async def test_deleted_input_folder_is_reported_once_as_camera_lost(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, capfd: pytest.CaptureFixture[str]
) -> None:
    recording = tmp_path / "recording"
    _write_pairs(recording, 4)
    source = {"kind": "files", "path": str(recording), "fps": 40, "loop": True}
    peer = await open_udp_peer()
    config, calibrations = load_all(
        synthetic_config(tmp_path, f"udpout:127.0.0.1:{peer.port}", source=source)
    )
    daemon = Daemon(config, calibrations)
    caplog.set_level(logging.INFO)
    task = asyncio.create_task(daemon.run())
    try:
        assert await wait_for(lambda: bool(daemon.heads), 20.0)
        head = daemon.heads[0]
        assert await wait_for(lambda: head.stats.captured >= 6, 20.0)
        # Moved away at once and back at once: no frame sees half a folder or half a file.
        recording.rename(tmp_path / "gone")
        shutil.rmtree(tmp_path / "gone")
        assert await wait_for(lambda: head.stats.broken >= 60, 20.0), head.stats
        _write_pairs(tmp_path / "new", 4)
        (tmp_path / "new").rename(recording)
        captured = head.stats.captured
        assert await wait_for(lambda: head.stats.captured > captured + 3, 20.0)
        assert await wait_for(
            lambda: any("camera back" in m.text for m in peer.of_type("STATUSTEXT")), 10.0
        )
    finally:
        daemon.stop()
        assert await asyncio.wait_for(task, timeout=10.0) == 0
        peer.close()
    head_lines = [r.getMessage() for r in caplog.records if r.name == "avoidd.daemon.head"]
    missing = [line for line in head_lines if "dropped" in line]
    # 60+ unreadable frames: the first is logged, the rest summarised when frames come back.
    assert len(missing) == 2, head_lines
    assert "repeated" in missing[1]
    assert sum("camera lost" in line for line in head_lines) == 1
    assert sum("readable again" in line for line in head_lines) == 1
    texts = [m.text for m in peer.of_type("STATUSTEXT")]
    assert texts.count("avoidd: front camera lost") == 1, texts
    assert texts.count("avoidd: front camera back") == 1, texts
    assert head.stats.broken >= LOST_AFTER_BROKEN
    assert "WARN" not in capfd.readouterr().err  # nothing from OpenCV either


def test_opencv_warnings_are_silenced_at_start(tmp_path: Path) -> None:
    missing = tmp_path / "gone.png"
    env = {k: v for k, v in os.environ.items() if k != "OPENCV_LOG_LEVEL"}
    env["PYTHONPATH"] = str(REPO)
    probe = f"import cv2; cv2.imread({str(missing)!r})"
    loud = subprocess.run(
        [sys.executable, "-c", probe], env=env, capture_output=True, text=True, check=True
    )
    assert "gone.png" in loud.stderr  # OpenCV warns by itself, so the check below can fail
    quiet = subprocess.run(
        [sys.executable, "-c", f"from avoidd.cli import _quiet_opencv; _quiet_opencv(); {probe}"],
        env=env,
        capture_output=True,
        text=True,
        check=True,
    )
    assert quiet.stderr == ""
    already_loaded = f"{probe}; from avoidd.cli import _quiet_opencv; _quiet_opencv(); {probe}"
    again = subprocess.run(
        [sys.executable, "-c", already_loaded], env=env, capture_output=True, text=True, check=True
    )
    assert again.stderr.count("gone.png") == 1


def _closed_tcp_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


async def test_tcp_connect_failures_are_said_once_per_state(
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.INFO, logger="avoidd.mavlink.transport")
    port = _closed_tcp_port()
    transport: Any = create_transport(parse_connection(f"tcp:127.0.0.1:{port}"), lambda _: None)
    await transport.open()
    server = None
    try:
        assert await wait_for(lambda: transport.connect_failures >= 8, 20.0)
        refused = [r for r in caplog.records if "cannot connect" in r.getMessage()]
        assert len(refused) == 1 and refused[0].levelno == logging.INFO
        assert "connection refused" in refused[0].getMessage()
        server = await asyncio.start_server(lambda r, w: None, "127.0.0.1", port)
        assert await wait_for(lambda: transport.connected, 20.0)
    finally:
        await transport.close()
        if server is not None:
            server.close()
    lines = [r.getMessage() for r in caplog.records]
    assert sum("repeated" in line and "connection refused" in line for line in lines) == 1
    assert sum(line.endswith(": connected") for line in lines) == 1

    caplog.clear()
    unknown: Any = create_transport(parse_connection("tcp:no-such-host.invalid:5760"), print)
    await unknown.open()
    try:
        assert await wait_for(lambda: unknown.connect_failures >= 3, 30.0)
    finally:
        await unknown.close()
    lines = [r.getMessage() for r in caplog.records if "cannot connect" in r.getMessage()]
    assert len(lines) == 1 and "unknown host" in lines[0], lines


def test_refused_signatures_are_counted_not_logged(caplog: pytest.LogCaptureFixture) -> None:
    # A peer with a wrong key: each frame is refused by avoidd's own signature check (no
    # pymavlink line per packet, which made 700 lines in 11 s), counted by why.
    caplog.set_level(logging.DEBUG)
    sender, receiver = mav.Codec(1, 1), mav.Codec(7, 196)
    sender.enable_signing(bytes(range(32)), 1_000_000, lambda _: False)
    receiver.enable_signing(bytes(32), 1_000_000, lambda _: False)
    data = b"".join(sender.pack(sender.heartbeat(4)) for _ in range(300))
    assert receiver.decode(data) == []
    assert receiver.signature_rejects == 300
    assert [r for r in caplog.records if r.name.startswith(("pymavlink", "avoidd"))] == []
    # ... and the counts are in the link's counters (the "avoidd stopped" line, the stats).
    link = MavLink(MavlinkConfig(connection="udpout:127.0.0.1:9").link, receiver)
    assert link.counters()["signature_refused"] == {"mismatch": 300, "replay": 0, "stale": 0}
    assert isinstance(link.counters()["pymavlink_notes"], dict)
