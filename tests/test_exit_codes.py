"""Honest exit codes: a replay that processed nothing fails with the reason; the mock autopilot
stops on SIGTERM and Ctrl-C with its summary and without a traceback."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from avoidd.cli import main
from avoidd.mavlink import codec as mav
from tests.helpers import REPO, free_udp_port
from tests.test_offline_config import SOURCE, _config, _pairs


def _replay(config: Path, out: Path, *extra: str) -> int:
    return main(["replay", "--config", str(config), "--out", str(out), *extra])


def _errors(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.levelname == "ERROR"]


def test_replay_of_a_video_without_frames_fails_with_the_reason(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    video = tmp_path / "empty.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (640, 240))
    writer.release()  # a valid container holding no frame
    config = _config(tmp_path, SOURCE, mavlink=False)
    assert _replay(config, tmp_path / "out.jsonl", "--input", str(video)) == 1
    [error] = _errors(caplog)
    assert "replay: no frame processed from side-by-side video" in error
    assert "it delivered no frame" in error


def test_replay_of_a_truncated_video_says_how_many_of_its_frames_it_had(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, capsys: pytest.CaptureFixture[str]
) -> None:
    video = tmp_path / "flight.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (640, 240))
    rng = np.random.default_rng(4)
    for _ in range(30):
        writer.write(rng.integers(0, 256, (240, 640, 3), dtype=np.uint8))
    writer.release()
    config = _config(tmp_path, SOURCE, mavlink=False)
    # Whole: no word of it.
    assert _replay(config, tmp_path / "whole.jsonl", "--input", str(video)) == 0
    assert "ended early" not in capsys.readouterr().out
    assert len((tmp_path / "whole.jsonl").read_text().splitlines()) == 30
    # Cut short (a recording whose writer died): what it had is replayed, and it is said.
    data = video.read_bytes()
    video.write_bytes(data[: len(data) * 2 // 5])
    assert _replay(config, tmp_path / "cut.jsonl", "--input", str(video)) == 0
    lines = len((tmp_path / "cut.jsonl").read_text().splitlines())
    assert 0 < lines < 30
    said = f"ended after {lines} of the 30 frames its header announces: the file is truncated"
    assert f"input ended early: side-by-side video {video} {said}" in capsys.readouterr().out
    assert any(said in r.getMessage() and r.levelname == "WARNING" for r in caplog.records)


def test_replay_whose_every_frame_is_unusable_fails_with_the_reason(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    folder = tmp_path / "broken"
    for side in ("left", "right"):
        (folder / side).mkdir(parents=True)
        for i in range(3):
            (folder / side / f"{i:03d}.png").write_bytes(b"not a png")
    config = _config(tmp_path, SOURCE, mavlink=False)
    assert _replay(config, tmp_path / "out.jsonl", "--input", str(folder)) == 1
    errors = _errors(caplog)
    assert len(errors) == 1
    assert f"no frame processed from image folder {folder}" in errors[0]
    assert "all 3 frames were unusable" in errors[0]


def test_replay_asked_for_no_frame_is_a_usage_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    config = _config(tmp_path, SOURCE, mavlink=False)
    assert _replay(config, tmp_path / "out.jsonl", "--max-frames", "0") == 2
    assert "--max-frames 0: give 1 or more" in capsys.readouterr().err


@pytest.mark.timeout(60)  # a hang guard: a looping recording used to replay for ever
def test_replay_reads_a_looping_recording_once(tmp_path: Path) -> None:
    _pairs(tmp_path / "rec", 2, "t_capture_ns\n0\n100000000\n")
    config = _config(tmp_path, {"kind": "files", "path": "rec", "loop": True}, mavlink=False)
    out = tmp_path / "out.jsonl"
    assert _replay(config, out) == 0
    assert len(out.read_text().splitlines()) == 2


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_mock_autopilot_stops_on_a_signal_with_its_summary(signum: int) -> None:
    port = free_udp_port()
    process = subprocess.Popen(
        [sys.executable, "-m", "avoidd", "mock-autopilot", f"udpin:127.0.0.1:{port}"],
        stderr=subprocess.PIPE,
        text=True,
        cwd=REPO,
        env={**os.environ, "PYTHONPATH": str(REPO)},
    )
    try:
        sender = mav.Codec(9, 190)
        heartbeat = sender.pack(sender.build("HEARTBEAT", mav.MAV_TYPE_GCS, 8, 0, 0, 4))
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as peer:
            peer.settimeout(0.5)
            answered = False
            for _ in range(40):  # at most 20 s: until it runs, hears us and answers
                peer.sendto(heartbeat, ("127.0.0.1", port))
                try:
                    answered = bool(peer.recv(4096))
                except TimeoutError:
                    continue
                break
        assert answered
        process.send_signal(signum)
        _, err = process.communicate(timeout=20)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    assert process.returncode == 0, err
    assert "Traceback" not in err
    summary = [line for line in err.splitlines() if "mock autopilot stopped; heard" in line]
    assert len(summary) == 1 and "'HEARTBEAT':" in summary[0].split("sent")[0], err
