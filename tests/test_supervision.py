"""The daemon keeps going through a camera that fails to open, breaks frames and gets lost."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from avoidd.daemon import Daemon, build_link
from avoidd.errors import SourceError
from avoidd.loading import load_all
from avoidd.sources import open_source as real_open_source
from avoidd.types import StereoFrame
from tests.helpers import open_udp_peer, synthetic_config, wait_for


class FlakyCamera:
    """Wraps a real source: one frame of the wrong size, then the device is lost."""

    def __init__(self, inner: Any, lose_after: int | None) -> None:
        self._inner = inner
        self._lose_after = lose_after
        self.reads = 0

    @property
    def description(self) -> str:
        return "flaky camera"

    def read(self) -> StereoFrame:
        self.reads += 1
        if self._lose_after is not None and self.reads > self._lose_after:
            raise SourceError("camera 'front': /dev/video0 no frame (device lost?)")
        frame: StereoFrame = self._inner.read()
        if self.reads == 3:
            return frame._replace(left=np.zeros((10, 10), dtype=np.uint8))
        return frame

    def close(self) -> None:
        self._inner.close()


async def test_lost_camera_is_reopened_with_backoff_and_reported(tmp_path: Path) -> None:
    opens: list[float] = []
    loop = asyncio.get_running_loop()

    def flaky_open(*args: Any, **kwargs: Any) -> Any:
        opens.append(loop.time())
        if len(opens) <= 2:
            raise SourceError("camera 'front': /dev/video0 does not exist; is it plugged in?")
        return FlakyCamera(real_open_source(*args, **kwargs), 12 if len(opens) == 3 else None)

    peer = await open_udp_peer()
    config, calibrations = load_all(synthetic_config(tmp_path, f"udpout:127.0.0.1:{peer.port}"))
    daemon = Daemon(config, calibrations, open_source=flaky_open)
    task = asyncio.create_task(daemon.run())
    try:
        assert await wait_for(lambda: len(opens) >= 4, 20.0), f"opened {len(opens)} times"
        head = daemon.heads[0]
        processed = head.stats.processed
        assert await wait_for(lambda: head.stats.processed > processed + 5, 10.0)
        assert await wait_for(
            lambda: sum("camera back" in m.text for m in peer.of_type("STATUSTEXT")) >= 2, 5.0
        )
    finally:
        daemon.stop()
        assert await asyncio.wait_for(task, timeout=10.0) == 0
        peer.close()
    stats = daemon.heads[0].stats
    assert stats.source_errors == 3  # two failed opens, one lost device
    assert stats.restarts == 2
    assert stats.broken == 2  # the wrong-size frame of each flaky camera: dropped, counted
    gaps = np.diff(opens[:3])
    assert gaps[0] >= 0.45 and gaps[1] >= 0.95  # backoff doubles from 0.5 s
    texts = [m.text for m in peer.of_type("STATUSTEXT")]
    assert texts.count("avoidd: front camera lost") == 2
    assert texts.count("avoidd: front camera back") == 2


class SilentCamera:
    """Opens, but every read fails (a camera that enumerates and streams nothing)."""

    description = "silent camera"

    def read(self) -> StereoFrame:
        raise SourceError("camera 'front': no frame within 1 s")

    def close(self) -> None:
        pass


async def test_a_camera_that_opens_but_gives_no_frame_stays_lost_without_flapping(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """Reopened with backoff, said lost once (log and STATUSTEXT), never "back" until a frame
    arrives; then back once."""
    opens: list[float] = []
    loop = asyncio.get_running_loop()

    def silent_open(*args: Any, **kwargs: Any) -> Any:
        opens.append(loop.time())
        if len(opens) <= 4:
            return SilentCamera()
        return real_open_source(*args, **kwargs)

    peer = await open_udp_peer()
    config, calibrations = load_all(synthetic_config(tmp_path, f"udpout:127.0.0.1:{peer.port}"))
    daemon = Daemon(config, calibrations, open_source=silent_open)
    task = asyncio.create_task(daemon.run())
    try:
        assert await wait_for(lambda: len(opens) >= 4, 20.0), f"opened {len(opens)} times"
        texts = [m.text for m in peer.of_type("STATUSTEXT")]
        assert texts.count("avoidd: front camera lost") == 1
        assert "avoidd: front camera back" not in texts
        head = daemon.heads[0]
        assert await wait_for(lambda: head.stats.processed > 3, 15.0)
        assert await wait_for(
            lambda: any("camera back" in m.text for m in peer.of_type("STATUSTEXT")), 5.0
        )
    finally:
        daemon.stop()
        assert await asyncio.wait_for(task, timeout=10.0) == 0
        peer.close()
    texts = [m.text for m in peer.of_type("STATUSTEXT")]
    assert texts.count("avoidd: front camera lost") == 1
    assert texts.count("avoidd: front camera back") == 1
    assert daemon.heads[0].stats.restarts == 1
    gaps = np.diff(opens[:4])
    assert gaps[0] >= 0.45 and gaps[1] >= 0.95 and gaps[2] >= 1.95  # backoff doubles
    lost_lines = [r for r in caplog.records if "source lost" in r.getMessage()]
    # One line, then one summary of the repeats (not a line per attempt).
    assert len(lost_lines) == 2 and "repeated 3 times" in lost_lines[1].getMessage()


async def test_a_dead_task_stops_the_daemon_with_an_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def broken_encoder(*args: Any, **kwargs: Any) -> bytes:
        raise RuntimeError("encoder bug")

    peer = await open_udp_peer()
    config, calibrations = load_all(synthetic_config(tmp_path, f"udpout:127.0.0.1:{peer.port}"))
    daemon = Daemon(config, calibrations)
    monkeypatch.setattr(daemon.codec, "obstacle_distance", broken_encoder)
    try:
        code = await asyncio.wait_for(daemon.run(), timeout=10.0)
    finally:
        peer.close()
    assert code == 1


async def test_an_injected_link_is_the_one_used(tmp_path: Path) -> None:
    peer = await open_udp_peer()
    config, calibrations = load_all(synthetic_config(tmp_path, f"udpout:127.0.0.1:{peer.port}"))
    link = build_link(config.mavlink)
    daemon = Daemon(config, calibrations, link=link)
    assert daemon.link is link and daemon.codec is link.codec
    task = asyncio.create_task(daemon.run())
    try:
        assert await wait_for(lambda: link.sent["OBSTACLE_DISTANCE"] >= 3, 10.0)
        assert len(peer.of_type("OBSTACLE_DISTANCE")) >= 1
    finally:
        daemon.stop()
        assert await asyncio.wait_for(task, timeout=10.0) == 0
        peer.close()
