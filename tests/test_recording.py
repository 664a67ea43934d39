"""Recording (``avoidd record``, ``avoidd run --record``) and its replay, round trip."""

from __future__ import annotations

import asyncio
import csv
import itertools
import json
import math
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from avoidd.config import SyntheticSourceConfig, load_config
from avoidd.mavlink.messages import UNKNOWN_CM
from avoidd.perception.temporal import SectorFilter
from avoidd.record import CaptureState, Recorder
from avoidd.sources.synthetic import SyntheticSource
from avoidd.types import FramePose, RectifiedRig, SectorScan, StereoFrame
from tests.helpers import RIG_320, free_udp_port, synthetic_config

SOURCE = {
    "kind": "synthetic",
    "fps": 10,
    "seed": 2,
    "obstacles": [{"shape": "box", "forward_m": 3.0, "right_m": -0.8, "width_m": 0.8}],
}
RIG = RectifiedRig(**{k if k != "doffs" else "doffs_px": v for k, v in RIG_320.items()})
MOCK_YAW_RATE_DEG_S = math.degrees(0.5)  # avoidd.mavlink.mock_autopilot.default_attitude


def avoidd(*args: str, **kwargs: Any) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "avoidd", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        **kwargs,
    )


@pytest.fixture
def autopilot() -> Iterator[int]:
    """A mock ArduPilot on a free UDP port (its own process); yields the port."""
    port = free_udp_port()
    process = avoidd("mock-autopilot", "--system-id", "7", f"udpin:127.0.0.1:{port}")
    time.sleep(0.5)
    yield port
    process.send_signal(signal.SIGINT)
    process.communicate(timeout=30)


def rows_of(folder: Path) -> list[dict[str, str]]:
    with (folder / "frames.csv").open(encoding="utf-8", newline="") as index:
        return list(csv.DictReader(index))


def assert_consistent(folder: Path) -> list[dict[str, str]]:
    """Every row names two images on disk and every image on disk has its row."""
    rows = rows_of(folder)
    for side in ("left", "right"):
        on_disk = sorted(p.name for p in (folder / side).iterdir())
        assert on_disk == [r[side] for r in rows]
    return rows


def replay(config: Path, out: Path, *extra: str) -> list[dict[str, Any]]:
    process = avoidd("replay", "--config", str(config), "--out", str(out), *extra)
    _, err = process.communicate(timeout=300)
    assert process.returncode == 0, err
    return [json.loads(line) for line in out.read_text().splitlines()]


def test_record_then_replay_gives_the_live_sectors(tmp_path: Path, autopilot: int) -> None:
    config = synthetic_config(tmp_path, f"udpout:127.0.0.1:{autopilot}", source=SOURCE)
    rec = tmp_path / "rec"
    process = avoidd("record", "--config", str(config), "--out", str(rec), "--duration", "4")
    _, err = process.communicate(timeout=120)
    assert process.returncode == 0, err
    assert "recording stopped: duration of 4 s reached" in err
    assert "Traceback" not in err
    rows = assert_consistent(rec / "front")
    assert len(rows) >= 10  # 10 fps for 4 s, on a busy machine
    assert (rec / "calibration" / "front.yaml").is_file()
    assert (rec / "original.yaml").read_text() == config.read_text()

    # Pose columns: the synthetic camera's own attitude and height (it is rendered level at
    # 1.5 m, whatever the autopilot says), the autopilot's heading and position.
    for row in rows:
        assert (row["roll_deg"], row["pitch_deg"], row["height_m"]) == ("0.0", "0.0", "1.5")
        assert (row["attitude_source"], row["height_source"]) == ("synthetic", "synthetic")
    seqs = [int(r["seq"]) for r in rows]
    assert seqs == list(range(len(rows)))
    times = [int(r["t_capture_ns"]) for r in rows]
    assert all(b > a for a, b in itertools.pairwise(times))
    stamped = [r for r in rows if r["yaw_deg"]]
    assert len(stamped) >= max(len(rows) // 4, 3)  # the streams start within a second
    for row in stamped:
        assert -180.0 <= float(row["yaw_deg"]) <= 180.0
    rates = []
    for a, b in itertools.pairwise(stamped):
        dt_s = (int(b["t_capture_ns"]) - int(a["t_capture_ns"])) / 1e9
        turn = math.remainder(float(b["yaw_deg"]) - float(a["yaw_deg"]), 360.0)
        rates.append(turn / dt_s)
    assert np.median(rates) == pytest.approx(MOCK_YAW_RATE_DEG_S, rel=0.15)
    positioned = [r for r in rows if r["north_m"]]
    assert positioned
    for row in positioned:
        assert [float(row[k]) for k in ("north_m", "east_m", "down_m")] == [0.0, 0.0, -1.5]

    # Lossless: the pixels of the frame the camera delivered (a seeded synthetic source
    # renders the same frame for the same number).
    camera = SyntheticSource(SyntheticSourceConfig.model_validate(SOURCE), RIG, paced=False)
    frames = [camera.read() for _ in range(len(rows))]
    for row, frame in zip(rows, frames, strict=True):
        left = cv2.imread(str(rec / "front" / "left" / row["left"]), cv2.IMREAD_UNCHANGED)
        right = cv2.imread(str(rec / "front" / "right" / row["right"]), cv2.IMREAD_UNCHANGED)
        assert np.array_equal(left, frame.left) and np.array_equal(right, frame.right)

    # Replayed from the recording, and straight from the source: the same sectors per frame.
    recorded = replay(rec / "avoidd.yaml", tmp_path / "recorded.jsonl")
    direct = replay(config, tmp_path / "direct.jsonl", "--max-frames", str(len(rows)))
    assert len(recorded) == len(direct) == len(rows)
    # The temporal filter holds a vanished reading for hold_ms of capture time, and the
    # recording's clock and the source's nominal 100 ms steps differ by a fraction of a
    # millisecond: a reading that blinks (the box's far corner in bin 71) can be held in one
    # and dropped in the other. So the filter is checked on the same scans at the same times:
    # the source's raw scans at the recording's times give the recording's sectors.
    app = load_config(config)
    max_cm = app.mavlink.obstacle_distance.max_distance_cm
    temporal = SectorFilter(app.perception.temporal)
    for mine, theirs, row in zip(recorded, direct, rows, strict=True):
        assert mine["t_capture_ns"] == int(row["t_capture_ns"])
        assert mine["raw_sectors_cm"] == theirs["raw_sectors_cm"]
        raw_m = [
            math.nan if cm == UNKNOWN_CM else math.inf if cm > max_cm else cm / 100.0
            for cm in theirs["raw_sectors_cm"]
        ]
        scan = SectorScan(mine["t_capture_ns"], np.array(raw_m, dtype=np.float32))
        filtered = temporal.update(scan).distance_m
        expected = [
            UNKNOWN_CM if math.isnan(m) else max_cm + 1 if math.isinf(m) else round(m * 100.0)
            for m in filtered.tolist()
        ]
        assert mine["sectors_cm"] == expected
        assert mine["nearest"] == theirs["nearest"]
        pose = mine["pose"]
        assert (pose["roll_deg"], pose["pitch_deg"], pose["height_m"]) == (0.0, 0.0, 1.5)
        vehicle = mine["vehicle"]
        assert (vehicle["yaw_deg"] is None) == (row["yaw_deg"] == "")
    assert any(r["nearest"] is not None for r in recorded)


def test_record_stops_before_the_size_limit(tmp_path: Path, autopilot: int) -> None:
    config = synthetic_config(tmp_path, f"udpout:127.0.0.1:{autopilot}", source=SOURCE)
    rec = tmp_path / "rec"
    limit_gb = 0.001  # 1 MB: a few 320x240 pairs
    process = avoidd("record", "--config", str(config), "--out", str(rec), "--max-gb", "0.001")
    _, err = process.communicate(timeout=120)
    assert process.returncode == 0, err
    stops = [line for line in err.splitlines() if "recording stopped" in line]
    assert len(stops) == 1 and "size limit of 0.001 GB reached" in stops[0]
    rows = assert_consistent(rec / "front")
    assert rows
    size = sum(p.stat().st_size for p in rec.rglob("*") if p.is_file())
    assert size <= limit_gb * 1e9


def test_record_stops_cleanly_on_sigterm(tmp_path: Path, autopilot: int) -> None:
    config = synthetic_config(tmp_path, f"udpout:127.0.0.1:{autopilot}", source=SOURCE)
    rec = tmp_path / "rec"
    process = avoidd("record", "--config", str(config), "--out", str(rec))
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        if (rec / "front" / "frames.csv").is_file() and len(rows_of(rec / "front")) >= 3:
            break
        time.sleep(0.1)
    process.send_signal(signal.SIGTERM)
    _, err = process.communicate(timeout=60)
    assert process.returncode == 0, err
    assert "recording stopped: SIGTERM received" in err
    assert len(assert_consistent(rec / "front")) >= 3


def test_record_refuses_a_folder_that_is_not_empty(tmp_path: Path) -> None:
    config = synthetic_config(tmp_path, "udpout:127.0.0.1:9", source=SOURCE)
    process = avoidd("record", "--config", str(config), "--out", str(tmp_path))
    _, err = process.communicate(timeout=60)
    assert process.returncode == 2
    assert "exists and is not an empty folder; give a new folder" in err


def test_run_record_records_while_the_daemon_sends(tmp_path: Path, autopilot: int) -> None:
    config = synthetic_config(tmp_path, f"udpout:127.0.0.1:{autopilot}", source=SOURCE)
    rec = tmp_path / "flight-%Y"
    process = avoidd("run", "--config", str(config), "--record", str(rec))
    folder = tmp_path / time.strftime("flight-%Y")
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        if (folder / "front" / "frames.csv").is_file() and len(rows_of(folder / "front")) >= 5:
            break
        time.sleep(0.1)
    process.send_signal(signal.SIGTERM)
    _, err = process.communicate(timeout=60)
    assert process.returncode == 0, err
    assert "Traceback" not in err
    rows = assert_consistent(folder / "front")
    assert len(rows) >= 5
    assert "recording closed: front" in err
    replayed = replay(folder / "avoidd.yaml", tmp_path / "flight.jsonl")
    assert len(replayed) == len(rows)


def _frame(seq: int) -> StereoFrame:
    image = np.full((240, 320, 3), seq % 256, dtype=np.uint8)
    return StereoFrame(seq, seq * 100_000_000, image, image.copy())


def test_a_slow_disk_drops_frames_and_never_blocks(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from avoidd import record

    original = record._HeadFolder.write

    def slow_write(self: Any, left: bytes, right: bytes, line: str) -> None:
        time.sleep(0.2)
        original(self, left, right, line)

    monkeypatch.setattr(record._HeadFolder, "write", slow_write)
    tmp_path.joinpath("rec").mkdir()
    recorder = Recorder(tmp_path / "rec", ["front"], queue_bytes=4 * 240 * 320 * 3 * 2)
    pose = FramePose(0.0, 0.0, 1.5)

    async def main() -> float:
        recorder.start(asyncio.get_running_loop(), lambda frame: CaptureState(pose))
        slowest = 0.0
        for seq in range(40):
            started = time.perf_counter()
            await asyncio.to_thread(recorder.offer, "front", _frame(seq))
            slowest = max(slowest, time.perf_counter() - started)
            await asyncio.sleep(0.01)
        await recorder.aclose()
        return slowest

    slowest = asyncio.run(main())
    counts = recorder.counts["front"]
    assert slowest < 0.1  # never waits for the disk (a write takes 0.2 s)
    assert counts.dropped > 20
    assert counts.recorded + counts.dropped == 40
    rows = assert_consistent(tmp_path / "rec" / "front")
    assert len(rows) == counts.recorded
    assert [int(r["seq"]) for r in rows] == sorted(int(r["seq"]) for r in rows)


def test_replay_realtime_takes_the_recorded_time(tmp_path: Path) -> None:
    config = synthetic_config(tmp_path, "udpout:127.0.0.1:9", source=SOURCE)
    folder = tmp_path / "pairs"
    (folder / "left").mkdir(parents=True)
    (folder / "right").mkdir()
    camera = SyntheticSource(SyntheticSourceConfig.model_validate(SOURCE), RIG, paced=False)
    rows = ["t_capture_ns,left,right"]
    span_s = 2.0
    for i in range(5):
        frame = camera.read()
        cv2.imwrite(str(folder / "left" / f"{i}.png"), frame.left)
        cv2.imwrite(str(folder / "right" / f"{i}.png"), frame.right)
        rows.append(f"{5_000_000_000 + int(i * span_s / 4 * 1e9)},{i}.png,{i}.png")
    (folder / "frames.csv").write_text("\n".join(rows) + "\n")
    started = time.monotonic()
    records = replay(config, tmp_path / "rt.jsonl", "--input", str(folder), "--realtime")
    elapsed = time.monotonic() - started
    assert len(records) == 5
    assert elapsed >= 0.8 * span_s


def _stderr_of_replay(config: Path, out: Path, stderr: int) -> None:
    process = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "avoidd",
            "--log-level",
            "WARNING",
            "replay",
            "--config",
            str(config),
            "--max-frames",
            "3",
            "--out",
            str(out),
        ],
        stdout=subprocess.DEVNULL,
        stderr=stderr,
    )
    assert process.wait(timeout=300) == 0


def test_progress_bar_on_a_terminal_only(tmp_path: Path) -> None:
    import pty

    config = synthetic_config(tmp_path, "udpout:127.0.0.1:9", source=SOURCE)
    master, slave = pty.openpty()
    try:
        _stderr_of_replay(config, tmp_path / "a.jsonl", slave)
        os.close(slave)
        drawn = b""
        while True:
            try:
                chunk = os.read(master, 4096)
            except OSError:  # EIO: the other end is closed and everything was read
                break
            if not chunk:
                break
            drawn += chunk
    finally:
        os.close(master)
    assert b"3/3" in drawn and b"[" in drawn and b"#" in drawn
    piped = tmp_path / "stderr.txt"
    with piped.open("wb") as sink:
        _stderr_of_replay(config, tmp_path / "b.jsonl", sink.fileno())
    assert b"3/3" not in piped.read_bytes() and b"#" not in piped.read_bytes()


RUN = (sys.executable, "-m", "avoidd", "run")


def test_a_recording_limit_in_the_daemon_stops_only_the_recording(
    tmp_path: Path, autopilot: int
) -> None:
    config = synthetic_config(tmp_path, f"udpout:127.0.0.1:{autopilot}", source=SOURCE)
    rec = tmp_path / "rec"
    log = tmp_path / "stderr.txt"
    with log.open("w") as sink:
        process = subprocess.Popen(
            [*RUN, "--config", str(config), "--record", str(rec), "--record-max-gb", "0.001"],
            stdout=subprocess.DEVNULL,
            stderr=sink,
        )
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and "recording stopped" not in log.read_text():
            time.sleep(0.1)
        time.sleep(1.0)
        assert process.poll() is None  # the daemon flies on
        process.send_signal(signal.SIGTERM)
        assert process.wait(timeout=60) == 0
    err = log.read_text()
    assert "recording stopped: size limit of 0.001 GB reached; the daemon goes on" in err
    assert "Traceback" not in err
    assert assert_consistent(rec / "front")


def test_the_recorded_config_keeps_no_signing_key_and_loads(tmp_path: Path) -> None:
    from avoidd.loading import load_all
    from avoidd.record import prepare_folder

    (tmp_path / "signing.key").write_text("ab" * 32)
    config_path = synthetic_config(
        tmp_path,
        "udpout:127.0.0.1:9",
        source=SOURCE,
        mavlink={"signing": {"key_file": "signing.key"}},
    )
    config, _ = load_all(config_path)
    rec = tmp_path / "rec"
    prepare_folder(rec, config_path, config)
    text = (rec / "avoidd.yaml").read_text()
    assert "signing" not in text and "ab" * 32 not in text
    (rec / "front" / "left").mkdir(parents=True)
    (rec / "front" / "right").mkdir()
    camera = SyntheticSource(SyntheticSourceConfig.model_validate(SOURCE), RIG, paced=False)
    frame = camera.read()
    cv2.imwrite(str(rec / "front" / "left" / "0.png"), frame.left)
    cv2.imwrite(str(rec / "front" / "right" / "0.png"), frame.right)
    replayed, calibrations = load_all(rec / "avoidd.yaml")
    assert replayed.mavlink.signing is None
    assert replayed.heads[0].source.kind == "files"
    assert calibrations["front"].rig == RIG


def test_record_signs_for_a_signing_autopilot(tmp_path: Path) -> None:
    key = tmp_path / "signing.key"
    key.write_text("5a" * 32)
    port = free_udp_port()
    mock = avoidd(
        "mock-autopilot", "--system-id", "7", "--key-file", str(key), f"udpin:127.0.0.1:{port}"
    )
    try:
        time.sleep(0.5)
        config = synthetic_config(
            tmp_path,
            f"udpout:127.0.0.1:{port}",
            source=SOURCE,
            mavlink={"signing": {"key_file": "signing.key"}},
        )
        rec = tmp_path / "rec"
        process = avoidd("record", "--config", str(config), "--out", str(rec), "--duration", "3")
        _, err = process.communicate(timeout=120)
        assert process.returncode == 0, err
    finally:
        mock.send_signal(signal.SIGINT)
        mock.communicate(timeout=30)
    assert any(r["yaw_deg"] for r in assert_consistent(rec / "front"))


def test_a_camera_without_its_own_pose_records_the_autopilot_attitude(
    tmp_path: Path, autopilot: int
) -> None:
    pairs = tmp_path / "pairs"
    (pairs / "left").mkdir(parents=True)
    (pairs / "right").mkdir()
    camera = SyntheticSource(SyntheticSourceConfig.model_validate(SOURCE), RIG, paced=False)
    for i in range(3):
        frame = camera.read()
        cv2.imwrite(str(pairs / "left" / f"{i}.png"), frame.left)
        cv2.imwrite(str(pairs / "right" / f"{i}.png"), frame.right)
    source = {"kind": "files", "path": str(pairs), "loop": True, "fps": 10}
    config = synthetic_config(tmp_path, f"udpout:127.0.0.1:{autopilot}", source=source)
    rec = tmp_path / "rec"
    process = avoidd("record", "--config", str(config), "--out", str(rec), "--duration", "3")
    _, err = process.communicate(timeout=120)
    assert process.returncode == 0, err
    rows = [r for r in assert_consistent(rec / "front") if r["attitude_source"] == "mavlink"]
    assert len(rows) >= 5
    # The mock sways: roll 0.2 sin(1.3 t) rad, pitch 0.1 cos(0.7 t) rad.
    rolls = [float(r["roll_deg"]) for r in rows]
    pitches = [float(r["pitch_deg"]) for r in rows]
    assert max(abs(v) for v in rolls) <= math.degrees(0.2) + 1e-6
    assert max(abs(v) for v in pitches) <= math.degrees(0.1) + 1e-6
    assert max(rolls) - min(rolls) > 1.0  # it moved during 3 s
    for row in rows:
        if row["height_source"] == "rangefinder":  # 1.5 m, corrected for the tilt
            assert 1.45 <= float(row["height_m"]) <= 1.5
    assert any(r["height_source"] == "rangefinder" for r in rows)
    # Replayed, each frame is interpreted with its recorded attitude.
    replayed = replay(rec / "avoidd.yaml", tmp_path / "r.jsonl")
    by_time = {r["t_capture_ns"]: r["pose"] for r in replayed}
    for row in rows:
        pose = by_time[int(row["t_capture_ns"])]
        assert pose["roll_deg"] == round(float(row["roll_deg"]), 2)
        assert pose["source"] == "recording"


def test_run_record_into_a_folder_in_use_takes_the_next_free_name(
    tmp_path: Path, autopilot: int
) -> None:
    config = synthetic_config(tmp_path, f"udpout:127.0.0.1:{autopilot}", source=SOURCE)
    used = tmp_path / "flight"
    used.mkdir()
    (used / "earlier.txt").write_text("an earlier flight")
    process = avoidd("run", "--config", str(config), "--record", str(used))
    folder = tmp_path / "flight-2"
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        if (folder / "front" / "frames.csv").is_file() and len(rows_of(folder / "front")) >= 2:
            break
        time.sleep(0.1)
    process.send_signal(signal.SIGTERM)
    _, err = process.communicate(timeout=60)
    assert process.returncode == 0, err
    assert f"--record {used}: in use; recording into {folder} instead" in err
    assert len(assert_consistent(folder / "front")) >= 2
    assert sorted(p.name for p in used.iterdir()) == ["earlier.txt"]
