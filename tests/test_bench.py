"""The benchmarks' figures: fed known timings, they must report exactly the figures those give."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
import types
from pathlib import Path
from typing import Any, ClassVar

import cv2
import numpy as np
import pytest

from avoidd.bench import link as link_bench
from avoidd.bench import vision as vision_bench
from avoidd.daemon.head import StageClock
from avoidd.mavlink.codec import Codec
from avoidd.pipeline import HeadPipeline
from avoidd.types import SectorScan, StereoFrame
from tests.helpers import REPO

# Per-stage milliseconds the fake pipeline reports: the warm-up frame is far slower, and the
# measured frames take these times 1, 4 and 2 (median 2, mean 2.33).
WARM_UP_MS = 1000.0
BASE_MS = {"rectify": 0.5, "preprocess": 1.0, "match": 10.0, "post": 2.0, "depth": 0.25}
BASE_MS["obstacles"] = 3.0
FACTORS = (1.0, 4.0, 2.0)
ENCODE_S = 0.000125
SGBM_S = (1.0, 0.008, 0.002, 0.004)  # warm-up, then three frames: median 4 ms


class FakeClock:
    """A ``perf_counter`` that moves only when a fake piece of work says so."""

    def __init__(self) -> None:
        self.now_s = 50.0

    def perf_counter(self) -> float:
        return self.now_s


class FakePipeline:
    """Stands in for HeadPipeline: reports scripted stage timings and remembers its frames."""

    created: ClassVar[list[FakePipeline]] = []

    def __init__(self, head: Any, calibration: Any, max_range_m: float) -> None:
        self.matcher = head.matcher.kind
        self.seqs: list[int] = []
        self.listed: list[int] = []
        FakePipeline.created.append(self)

    def process(self, frame: StereoFrame, with_obstacles: bool = False) -> Any:
        if with_obstacles:
            self.listed.append(frame.seq)
            return types.SimpleNamespace(timing_ms={"obstacles": 7.0})
        self.seqs.append(frame.seq)
        calls = len(self.seqs)
        factor = FACTORS[calls - 2] if calls > 1 else None
        timing = {k: WARM_UP_MS if factor is None else v * factor for k, v in BASE_MS.items()}
        scan = SectorScan(0, np.full(72, np.inf, dtype=np.float32))
        return types.SimpleNamespace(scan=scan, timing_ms=timing)


def _fake_sgbm(clock: FakeClock) -> Any:
    """A ``cv2.StereoSGBM`` whose ``compute`` takes the scripted times on the fake clock."""

    class Matcher:
        def __init__(self) -> None:
            self.calls = 0

        def compute(self, left: Any, right: Any) -> None:
            clock.now_s += SGBM_S[self.calls]
            self.calls += 1

    return types.SimpleNamespace(create=lambda **_: Matcher())


def _fake_codec(clock: FakeClock) -> Any:
    """A codec whose ``pack`` takes ENCODE_S on the fake clock."""

    class TimedCodec(Codec):
        def pack(self, message: Any) -> bytes:
            clock.now_s += ENCODE_S
            return super().pack(message)

    return TimedCodec


def test_vision_bench_reports_medians_of_the_asked_frames(monkeypatch: pytest.MonkeyPatch) -> None:
    clock = FakeClock()
    FakePipeline.created = []
    monkeypatch.setattr(vision_bench, "HeadPipeline", FakePipeline)
    monkeypatch.setattr(vision_bench, "Codec", _fake_codec(clock))
    monkeypatch.setattr(
        vision_bench,
        "time",
        types.SimpleNamespace(perf_counter=clock.perf_counter, monotonic_ns=time.monotonic_ns),
    )
    monkeypatch.setattr(cv2, "StereoSGBM", _fake_sgbm(clock))
    threads_before = cv2.getNumThreads()

    records = vision_bench.run_bench(["sgbm", "census"], ((320, 240),), (64,), frames=3)

    assert cv2.getNumThreads() == threads_before
    # Two matchers, each with one thread and all: four pipelines, each fed the warm-up frame
    # and then exactly the three frames asked for, in order.
    assert [p.matcher for p in FakePipeline.created] == ["sgbm", "census"] * 2
    assert all(p.seqs == [0, 0, 1, 2] for p in FakePipeline.created)
    all_threads = cv2.getNumberOfCPUs()
    assert [(r["matcher"], r["threads"]) for r in records] == [
        ("sgbm", 1),
        ("census", 1),
        ("sgbm", all_threads),
        ("census", all_threads),
    ]
    expected_stages = {
        "rectify": 1.0,
        "preprocess": 2.0,
        "match": 20.0,
        "post": 4.0,
        "depth": 0.5,
        "obstacles": 6.0,
        "encode": 0.125,
    }
    for record in records:
        assert (record["width"], record["height"], record["disparities"]) == (320, 240, 64)
        assert record["stages_ms"] == pytest.approx(expected_stages, abs=1e-3)
        assert record["total_ms"] == pytest.approx(33.625, abs=1e-3)
        assert record["opencv_sgbm_ms"] == pytest.approx(4.0, abs=1e-3)
        assert record["match_vs_opencv"] == pytest.approx(5.0, abs=1e-3)
        assert record["total_vs_opencv"] == pytest.approx(8.406, abs=1e-3)
        assert record["non_match_vs_match"] == pytest.approx(0.681, abs=1e-3)


def test_vision_bench_times_real_frames_through_the_real_pipeline(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    seen: list[tuple[int, tuple[int, ...]]] = []
    real_process = HeadPipeline.process

    def counting(self: HeadPipeline, frame: StereoFrame, *args: Any, **kwargs: Any) -> Any:
        seen.append((frame.seq, frame.left.shape))
        return real_process(self, frame, *args, **kwargs)

    monkeypatch.setattr(HeadPipeline, "process", counting)
    (record, _) = vision_bench.run_bench(["sad"], ((320, 240),), (64,), frames=2)
    # Warm-up plus the two frames asked for, per thread setting; raw 320x240 colour frames.
    assert [seq for seq, _ in seen] == [0, 0, 1] * 2
    assert {shape[:2] for _, shape in seen} == {(240, 320)}
    assert record["matcher"] == "sad" and record["threads"] == 1
    # The bench calibration is distorted, so rectify does real work: it is never free.
    assert record["stages_ms"]["rectify"] > 0.0


def test_vision_bench_command_writes_what_it_was_asked(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from avoidd.cli import main

    FakePipeline.created = []
    monkeypatch.setattr(vision_bench, "HeadPipeline", FakePipeline)
    # The worst-case sets, small: rendering them at 640x480 takes seconds.
    monkeypatch.setattr(vision_bench, "WORST_CASE_SIZE", (160, 120))
    out = tmp_path / "bench.json"
    assert main(["bench", "--matcher", "sad", "--quick", "--frames", "3", "--json", str(out)]) == 0
    written = json.loads(out.read_text())
    # --quick: 320x240 and 640x480 at 64 disparities, then the worst-case sets, each with one
    # thread and all.
    assert [(r["matcher"], r["source"], r["width"], r["disparities"]) for r in written] == [
        ("sad", "synthetic", 320, 64),
        ("sad", "synthetic", 320, 64),
        ("sad", "synthetic", 640, 64),
        ("sad", "synthetic", 640, 64),
        *[("sad", name, 160, 64) for name in vision_bench.WORST_CASE for _ in range(2)],
    ]
    # Every frame is timed without the obstacle list and then with it (its own column).
    assert all(p.seqs == [0, 0, 1, 2] and p.listed == [0, 1, 2] for p in FakePipeline.created)
    assert len(FakePipeline.created) == 12
    assert all(r["obstacles_list_ms"] == 7.0 for r in written)
    assert all(r["filled"] is None for r in written[:4])
    assert all(r["filled"] > 0.7 for r in written[4:])
    # Without --matcher: every matcher, in the bench's order.
    assert main(["bench", "--quick", "--frames", "1", "--json", str(out)]) == 0
    written = json.loads(out.read_text())
    assert [r["matcher"] for r in written[:4]] == ["sgbm", "sad", "census", "segment"]
    assert len(written) == 48


def test_worst_case_frames_are_mostly_obstacle() -> None:
    # Each worst-case set fills most of the view with obstacles, and most of its pixels become
    # obstacle points (the wall at 8 m less: the height band cuts the rows above and below).
    least_candidates = {"wall-1m": 0.6, "wall-3m": 0.5, "wall-8m": 0.2, "poles": 0.4}
    assert set(least_candidates) == set(vision_bench.WORST_CASE)
    for name in vision_bench.WORST_CASE:
        frames = vision_bench.worst_case_frames(name, 320, 240, 1)
        assert frames.source == name and len(frames.pairs) == 1
        assert frames.filled is not None and 0.75 <= frames.filled <= 0.95, (name, frames.filled)
        head = vision_bench._head(vision_bench._matcher("sgbm", 64), frames.mount)
        result = HeadPipeline(head, frames.calibration, 20.0).process(frames.pairs[0])
        share = result.obstacle_points / (320 * 240)
        assert share >= least_candidates[name], (name, share)
        if name.startswith("wall-"):
            # The wall is where it says, straight ahead.
            distance_m = float(name[5:-1])
            assert result.scan.distance_m[0] == pytest.approx(distance_m, rel=0.05)


def test_bench_table_shows_the_worst_case_rows_and_the_list_column() -> None:
    records = vision_bench.run_bench(
        ["sgbm"],
        (),
        (64,),
        frames=1,
        recorded=[vision_bench.worst_case_frames("wall-3m", 160, 120, 1)],
        with_list=True,
    )
    assert [r["source"] for r in records] == ["wall-3m", "wall-3m"]
    assert all(r["obstacles_list_ms"] > 0 and r["candidates"] > 0.3 for r in records)
    table = vision_bench.format_bench(records).splitlines()
    assert "+list" in table[0] and "cand%" in table[0] and "fill%" in table[0]
    assert all(line.split()[1] == "wall-3m" for line in table[1:])


async def test_link_bench_figures_come_from_the_measured_window(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # The real link and a real mock autopilot process over loopback; the clock and the CPU
    # counter are fakes that say the window lasted 2 s and cost 0.5 s of CPU, and that note
    # the link's message count at the instants the bench reads them.
    links: list[Any] = []

    class RecordedLink(link_bench.MavLink):
        def __init__(self, *args: Any, **kwargs: Any) -> None:
            super().__init__(*args, **kwargs)
            links.append(self)

    counts: list[int] = []
    wall = iter([10.0, 12.0])
    cpu = iter([1.0, 1.5])

    def perf_counter() -> float:
        counts.append(sum(links[0].received.values()))
        return next(wall)

    monkeypatch.setattr(link_bench, "MavLink", RecordedLink)
    monkeypatch.setattr(link_bench, "time", types.SimpleNamespace(perf_counter=perf_counter))
    monkeypatch.setattr(link_bench, "_cpu_s", lambda: next(cpu))
    report = await link_bench.run_bench(200.0, 0.5)

    assert len(counts) == 2
    count = counts[1] - counts[0]
    assert count > 0, "no message arrived in the window"
    assert report["rate_asked_hz"] == 200.0
    assert report["seconds"] == 2.0
    assert report["received_per_s"] == round(count / 2.0, 1)
    assert report["cpu_percent_one_core"] == 25.0
    assert report["cpu_us_per_message"] == round(0.5e6 / count, 2)
    assert report["parse_errors"] == 0
    assert 0.0 <= report["max_own_loop_lag_ms"] <= report["max_loop_lag_ms"]
    # The mock streams ATTITUDE, LOCAL_POSITION_NED and DISTANCE_SENSOR as 2:1:1.
    received = links[0].received
    assert received["ATTITUDE"] > 0 and received["DISTANCE_SENSOR"] > 0
    assert (
        abs(received["ATTITUDE"] - 2 * received["LOCAL_POSITION_NED"])
        <= 0.05 * received["ATTITUDE"] + 4
    )


def test_link_bench_command_runs_and_writes_json(tmp_path: Path) -> None:
    out = tmp_path / "link.json"
    command = ["bench-link", "--rate=100", "--seconds=0.5", f"--json={out}"]
    done = subprocess.run(
        [sys.executable, "-m", "avoidd", *command],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    report = json.loads(out.read_text())
    assert report["rate_asked_hz"] == 100.0 and report["parse_errors"] == 0
    assert report["received_per_s"] > 0.0
    assert f"received          {report['received_per_s']:.0f} msg/s" in done.stdout


def test_link_bench_stranger_counts_a_flood_dropped_unread(tmp_path: Path) -> None:
    """``bench-link --stranger``: the stream comes from a stranger: counted, never decoded."""
    out = tmp_path / "stranger.json"
    command = ["bench-link", "--stranger", "--rate=2000", "--seconds=1", f"--json={out}"]
    done = subprocess.run(
        [sys.executable, "-m", "avoidd", "--log-level=ERROR", *command],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    report = json.loads(out.read_text())
    assert report["streams"] == "stranger" and report["parse_errors"] == 0
    # Only the adopted autopilot's heartbeats were decoded; the flood was counted.
    assert set(report["received_per_s_by_type"]) == {"HEARTBEAT"}
    assert report["received_per_s"] > 100.0
    assert "a stranger's 2000 msg/s, dropped unread" in done.stdout


def test_link_bench_asked_streams_come_at_the_configured_ratio(tmp_path: Path) -> None:
    """``bench-link --asked``: avoidd asks the mock for its streams (ATTITUDE 50 Hz,
    LOCAL_POSITION_NED and DISTANCE_SENSOR 10 Hz, SYSTEM_TIME 1 Hz by default) and every one
    of them arrives; the fast one five times as often as the position (a ratio, which load on
    the machine leaves alone far better than a rate)."""
    out = tmp_path / "asked.json"
    done = subprocess.run(
        [sys.executable, "-m", "avoidd", "bench-link", "--asked", "--seconds=3", f"--json={out}"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=90,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    report = json.loads(out.read_text())
    assert report["streams"] == "asked" and report["parse_errors"] == 0
    rates = report["received_per_s_by_type"]
    assert {"ATTITUDE", "LOCAL_POSITION_NED", "DISTANCE_SENSOR", "SYSTEM_TIME"} <= rates.keys()
    assert rates["ATTITUDE"] == pytest.approx(5 * rates["LOCAL_POSITION_NED"], rel=0.3)
    assert rates["DISTANCE_SENSOR"] == pytest.approx(rates["LOCAL_POSITION_NED"], rel=0.3)


def test_a_stage_clock_counts_the_part_of_a_run_inside_a_window() -> None:
    """A run going on counts up to the moment asked about; a finished one counts whole, once."""
    clock = StageClock()
    assert clock.busy_s(123.0) == 0.0
    clock.start()
    assert clock.since_s is not None
    began_s = clock.since_s
    assert clock.busy_s(began_s + 2.0) == pytest.approx(2.0)
    clock.stop()
    took_s = clock.total_s
    assert took_s >= 0.0 and clock.since_s is None
    assert clock.busy_s(began_s + 1000.0) == took_s
    clock.stop()  # a second stop adds nothing
    assert clock.total_s == took_s
    ((ended_s, ms),) = clock.recent
    assert ended_s == pytest.approx(began_s + took_s) and ms == pytest.approx(took_s * 1000.0)


def test_daemon_bench_reports_what_the_demo_daemon_sent(tmp_path: Path) -> None:
    """``bench --daemon``: the demo daemon's scans all see the demo's obstacle, its heartbeat
    never says BOOT once it has a result, and the figures agree with each other."""
    out = tmp_path / "daemon.json"
    command = ["bench", "--daemon", "config/demo.yaml", "--seconds=3", f"--json={out}"]
    done = subprocess.run(
        [sys.executable, "-m", "avoidd", "--log-level=ERROR", *command],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    report = json.loads(out.read_text())
    assert report["obstacle_distance_configured_hz"] == 15.0
    assert report["scans"] > 0
    assert report["scans_with_obstacle_percent"] == 100.0
    assert set(report["heartbeat_states"]) <= {"ACTIVE", "CRITICAL"}
    assert [head["name"] for head in report["heads"]] == ["front"]
    # The rate is over the window's measured length (at least 3 s; a loaded machine overruns it).
    assert report["seconds"] >= 3.0
    assert report["obstacle_distance_hz"] == pytest.approx(
        report["scans"] / report["seconds"], rel=0.005
    )


def test_daemon_bench_compares_thread_counts_on_a_faster_camera(tmp_path: Path) -> None:
    """``bench --daemon --threads 1 --threads 2 --source-fps``: one report per thread count,
    each run with that many vision threads, latencies ordered, and the comparison printed."""
    out = tmp_path / "threads.json"
    command = [
        *("bench", "--daemon", "config/demo.yaml", "--seconds=2", f"--json={out}"),
        *("--threads", "1", "--threads", "2", "--source-fps", "60"),
    ]
    done = subprocess.run(
        [sys.executable, "-m", "avoidd", "--log-level=ERROR", *command],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=180,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    reports = json.loads(out.read_text())
    assert [report["threads"] for report in reports] == [1, 2]
    for report in reports:
        (head,) = report["heads"]
        assert head["fps"] > 0
        assert 0 < head["latency_ms"]["p50"] <= head["latency_ms"]["p99"]
        send = report["capture_to_send_ms"]
        assert 0 < send["p50"] <= send["p99"]
        # Stage times: each stage was busy for part of the window, and a frame takes both.
        assert head["match_ms"] > 0 and head["finish_ms"] > 0
        assert 0 < head["match_busy"] <= 1.001 and 0 < head["finish_busy"] <= 1.001
        assert head["latency_ms"]["p50"] >= 0.9 * (head["match_ms"] + head["finish_ms"])
        assert 0 < report["cpu_cores_busy"] <= os.cpu_count() + 0.2
        assert report["cpu_ms_per_frame"] > 0
    # One thread runs a frame's stages one after the other, never together: their busy
    # shares add up to at most the whole window. Two threads overlap them.
    one, two = (report["heads"][0] for report in reports)
    assert one["match_busy"] + one["finish_busy"] <= 1.002  # rounded to 3 decimals each
    assert two["match_busy"] + two["finish_busy"] > 1.0
    assert "process CPU" in done.stdout and "(busy " in done.stdout
    assert "2 threads: " in done.stdout and "the one-thread frame rate" in done.stdout


def test_daemon_bench_refuses_a_camera_rate_for_a_recorded_source(tmp_path: Path) -> None:
    config = tmp_path / "files.yaml"
    calibration = (REPO / "config" / "calibration" / "synthetic-640x480.yaml").resolve()
    for side in ("left", "right"):
        (tmp_path / side).mkdir()
        cv2.imwrite(str(tmp_path / side / "000001.png"), np.zeros((480, 640), np.uint8))
    config.write_text(
        "version: 1\nheads:\n  - name: front\n"
        f"    calibration: {calibration}\n"
        f"    source: {{kind: files, path: {tmp_path}}}\n"
    )
    done = subprocess.run(
        [sys.executable, "-m", "avoidd", "bench", "--daemon", str(config), "--source-fps=60"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert done.returncode == 2, done.stderr
    assert "--source-fps" in done.stderr and "'front' reads files" in done.stderr
