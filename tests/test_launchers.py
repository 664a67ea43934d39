"""The SITL launchers leave nothing behind when an autopilot never answers (no SITL needed:
a stand-in binary that starts and stays silent)."""

from __future__ import annotations

import asyncio
import contextlib
import os
import signal
import stat
import tempfile
from pathlib import Path

import pytest

from avoidd.errors import LinkError
from avoidd.sim import ardupilot, px4
from avoidd.sim import process as process_module
from avoidd.sim.process import end_process_group
from tests.helpers import free_udp_port


def _silent_binary(path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("#!/bin/sh\nexec sleep 300\n")
    path.chmod(path.stat().st_mode | stat.S_IXUSR)


def _group_gone(pid: int) -> bool:
    try:
        os.killpg(pid, 0)
    except ProcessLookupError:
        return True
    return False


@pytest.fixture
def ended(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> list[int]:
    """Pids of the processes the launchers ended; their work folders go under tmp_path/tmp."""
    pids: list[int] = []
    real = process_module.end_process_group

    async def end(process: asyncio.subprocess.Process | None, grace_s: float = 3.0) -> None:
        if process is not None:
            pids.append(process.pid)
        await real(process, grace_s)

    monkeypatch.setattr(process_module, "end_process_group", end)
    (tmp_path / "tmp").mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp"))
    return pids


async def test_a_px4_that_never_answers_leaves_no_process_socket_or_folder(
    tmp_path: Path, ended: list[int]
) -> None:
    if not all(px4._udp_free(p) for p in (*px4.PX4_PORTS, px4.GCS_PORT)):
        pytest.skip("PX4's fixed UDP ports are in use (another PX4 or ground station runs)")
    _silent_binary(tmp_path / "px4" / "bin" / "px4")
    (tmp_path / "px4" / "etc").mkdir()
    sitl = px4.Px4Sitl(tmp_path / "px4")
    with pytest.raises(LinkError, match="heartbeat"):
        await sitl.start(timeout_s=0.5)
    assert len(ended) == 1 and _group_gone(ended[0])
    assert sitl.process is None and sitl.gcs is None
    assert not any((tmp_path / "tmp").iterdir())  # the work folder is gone
    assert px4._udp_free(px4.GCS_PORT)  # the ground station's socket is closed


async def test_an_ardupilot_that_never_answers_leaves_no_process_or_folder(
    tmp_path: Path, ended: list[int]
) -> None:
    _silent_binary(tmp_path / "ap" / "arducopter")
    (tmp_path / "ap" / "copter.parm").write_text("")
    sitl = ardupilot.ArduPilotSitl(tmp_path / "ap", free_udp_port())
    with pytest.raises(LinkError):
        await sitl.start(timeout_s=0.5)
    assert len(ended) == 1 and _group_gone(ended[0])
    assert sitl.process is None and sitl.gcs is None
    assert not any((tmp_path / "tmp").iterdir())


async def test_a_stop_cancelled_in_its_grace_time_still_ends_the_group() -> None:
    """A process group that ignores SIGTERM, and a stop cancelled while it waits (a test torn
    down): the forced signal goes out before the cancellation does."""
    process = await asyncio.create_subprocess_exec(
        "sh",
        "-c",
        'trap "" TERM; echo ready; exec sleep 300',  # an ignored signal stays so across exec
        stdout=asyncio.subprocess.PIPE,
        start_new_session=True,
    )
    try:
        assert process.stdout is not None
        assert await asyncio.wait_for(process.stdout.readline(), 10.0) == b"ready\n"
        stopping = asyncio.create_task(end_process_group(process, grace_s=30.0))
        await asyncio.sleep(0.3)
        assert not _group_gone(process.pid)  # SIGTERM ignored: still there
        stopping.cancel()
        with pytest.raises(asyncio.CancelledError):
            await stopping
        await asyncio.wait_for(process.wait(), 10.0)
        assert _group_gone(process.pid)
    finally:  # a failure above leaves nothing running either
        with contextlib.suppress(ProcessLookupError):
            os.killpg(process.pid, signal.SIGKILL)
