"""Stages overlapped across threads: the split pipeline and a head's two-stage compute task."""

from __future__ import annotations

import asyncio
import os
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from avoidd.bench.vision import _head, _matcher, synthetic_frames
from avoidd.config import PerceptionConfig
from avoidd.daemon.head import Head
from avoidd.evaluation.near import near_suite
from avoidd.evaluation.scenes import noisy_frame, suite_head
from avoidd.loading import load_all
from avoidd.pipeline import STAGES, HeadPipeline, HeadResult, Matched
from avoidd.sources.scene import render_pair
from avoidd.types import FramePose, SectorScan, StereoFrame
from avoidd.vision import nearfield, postprocess
from avoidd.vision.calibration import Calibration
from avoidd.vision.postprocess import postprocess_disparity, texture_gate

ROOT = Path(__file__).resolve().parent.parent


def _near_frames() -> tuple[HeadPipeline, list[StereoFrame]]:
    """Rendered scenes with a surface nearer than the main search range (the near-field pass
    finds it), one pipeline for all of them."""
    cases = near_suite(4, seed=3030)
    frames = [
        noisy_frame(case, render_pair(case.scene, case.rig), 1.5)._replace(seq=seq)
        for seq, case in enumerate(cases)
    ]
    calibration = Calibration(cases[0].rig, None, Path("near"))
    return HeadPipeline(suite_head(cases[0], 64), calibration, 20.0), frames


@pytest.mark.parametrize("scenes", ["rendered", "near"])
def test_matching_the_next_frame_while_finishing_this_one_changes_no_result(scenes: str) -> None:
    """The two halves share nothing mutable: run side by side they give what one thread gives
    (near scenes: the near-field pass runs in the finishing half beside the next match)."""
    if scenes == "near":
        pipeline, frames = _near_frames()
    else:
        frame_set = synthetic_frames(320, 240, 6)
        pipeline = HeadPipeline(_head(_matcher("sgbm", 64)), frame_set.calibration, 20.0)
        frames = frame_set.pairs
    sequential = [pipeline.process(frame, with_obstacles=True) for frame in frames]
    overlapped: list[HeadResult] = []
    with ThreadPoolExecutor(2) as pool:
        matched = pipeline.match(frames[0])
        for frame in [*frames[1:], None]:
            finishing = pool.submit(pipeline.finish, matched, None, True)
            if frame is not None:
                matched = pool.submit(pipeline.match, frame).result()
            overlapped.append(finishing.result())
    assert [r.seq for r in overlapped] == [r.seq for r in sequential]
    for one, two in zip(sequential, overlapped, strict=True):
        np.testing.assert_array_equal(one.scan.distance_m, two.scan.distance_m)
        np.testing.assert_array_equal(one.depth_m, two.depth_m)
        assert [o.distance_m for o in one.obstacles] == [o.distance_m for o in two.obstacles]
        assert set(one.timing_ms) == set(two.timing_ms) == set(STAGES)
    if scenes == "near":
        # Two of the four (a wall at 0.75 m, a pole at 0.43 m) lie in the near field.
        assert sum(result.near_pixels > 1000 for result in overlapped) >= 2


def test_the_near_field_pass_runs_in_the_finishing_half() -> None:
    """The matching half hands on the main matcher's map alone; the finishing half adds the
    near-field pass (it balances the two threads), and the result is what one call gives."""
    case = near_suite(4, seed=3030)[0]  # a surface nearer than the main search range
    frame = noisy_frame(case, render_pair(case.scene, case.rig), 1.5)
    calibration = Calibration(case.rig, None, Path("near"))
    pipeline = HeadPipeline(suite_head(case, 64), calibration, 20.0)
    assert pipeline.near_field is not None
    main_range_px = 64 - 1
    matched = pipeline.match(frame)
    assert np.nanmax(matched.disparity) <= main_range_px  # no near-field reading yet
    finished = pipeline.finish(matched)
    assert finished.near_pixels > 1000
    whole = pipeline.process(frame)
    assert whole.near_pixels == finished.near_pixels
    np.testing.assert_array_equal(whole.depth_m, finished.depth_m)
    assert set(whole.timing_ms) == set(finished.timing_ms) == set(STAGES)


def test_a_near_frame_computes_the_texture_gate_once(monkeypatch: pytest.MonkeyPatch) -> None:
    """The near-field pass and post-processing test the same view's texture with the same
    window and threshold: the finishing half computes it once, and the map is the same."""
    case = near_suite(4, seed=3030)[0]
    frame = noisy_frame(case, render_pair(case.scene, case.rig), 1.5)
    pipeline = HeadPipeline(suite_head(case, 64), Calibration(case.rig, None, Path("near")), 20.0)
    assert pipeline.near_field is not None
    matched = pipeline.match(frame)
    near = pipeline.near_field.apply(matched.left, matched.right, matched.disparity)
    assert near.texture_gate is not None  # the pass saw something near
    config = suite_head(case, 64).postprocess
    args = (matched.left, matched.right, near.disparity, config, matched.texture, None)
    shared = postprocess_disparity(*args, near.texture_gate).disparity.copy()
    fresh = postprocess_disparity(*args).disparity
    np.testing.assert_array_equal(shared, fresh)
    calls: list[int] = []

    def counted(*args: Any, **kwargs: Any) -> Any:
        calls.append(1)
        return texture_gate(*args, **kwargs)

    monkeypatch.setattr(postprocess, "texture_gate", counted)
    monkeypatch.setattr(nearfield, "texture_gate", counted)
    result = pipeline.finish(matched)
    assert calls == [1]
    np.testing.assert_array_equal(result.depth_m, pipeline.process(frame).depth_m)


class _SlowPipeline:
    """Stands in for the vision stages: each half sleeps, and every call is logged."""

    def __init__(self, real: HeadPipeline, stage_s: float) -> None:
        self.real = real
        self.stage_s = stage_s
        self.log: list[tuple[str, int, float, float]] = []  # stage, seq, start, end
        self.busy = 0
        self.most_busy = 0
        self.threads: set[tuple[str, str]] = set()
        self.nice: set[tuple[str, int]] = set()  # stage, the nice of the thread it ran on
        self._lock = threading.Lock()

    def _enter(self) -> float:
        with self._lock:
            self.busy += 1
            self.most_busy = max(self.most_busy, self.busy)
        return time.monotonic()

    def _leave(self, stage: str, seq: int, started: float) -> None:
        with self._lock:
            self.busy -= 1
            self.threads.add((stage, threading.current_thread().name))
            self.nice.add((stage, os.getpriority(os.PRIO_PROCESS, threading.get_native_id())))
            self.log.append((stage, seq, started, time.monotonic()))

    def match(self, frame: StereoFrame) -> Matched:
        started = self._enter()
        time.sleep(self.stage_s)
        self._leave("match", frame.seq, started)
        empty = np.zeros((2, 2), np.float32)
        return Matched(frame, frame.left, frame.right, None, empty, None, None, {}, {})

    def finish(self, matched: Matched, pose: FramePose | None = None) -> HeadResult:
        started = self._enter()
        time.sleep(self.stage_s)
        frame = matched.frame
        self._leave("finish", frame.seq, started)
        scan = SectorScan(frame.t_capture_ns, np.full(72, np.inf, dtype=np.float32))
        return HeadResult("front", frame.seq, frame.t_capture_ns, scan, matched.disparity, 1.0, {})


def _run_head(
    overlap: bool, seconds: float, matcher_nice: int = 0
) -> tuple[Head, _SlowPipeline, list[int], int]:
    """A head fed a frame every 5 ms for ``seconds``; its published seqs and frames offered."""
    config, calibrations = load_all(ROOT / "config" / "demo.yaml")
    published: list[int] = []

    async def main() -> tuple[Head, _SlowPipeline, int]:
        loop = asyncio.get_running_loop()
        stop = threading.Event()
        head_config = config.heads[0]

        def announce(severity: int, text: str, key: str | None = None) -> None:
            del severity, text, key

        head = Head(
            head_config,
            calibrations[head_config.name],
            20.0,
            loop,
            stop,
            announce,
            PerceptionConfig(),
            lambda frame: FramePose(0.0, 0.0, 1.5, "test", "test"),
            lambda *args, **kwargs: None,  # type: ignore[arg-type,return-value]
            overlap=overlap,
            matcher_nice=matcher_nice,
        )
        slow = _SlowPipeline(head.pipeline, 0.04)
        head.pipeline = slow  # type: ignore[assignment]
        image = np.zeros((480, 640), np.uint8)
        offered = 0

        def feed() -> None:
            nonlocal offered
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                head.slot.put(StereoFrame(offered, time.monotonic_ns(), image, image))
                offered += 1
                time.sleep(0.005)

        task = asyncio.create_task(head.compute())
        last: HeadResult | None = None

        async def watch() -> None:
            nonlocal last
            while True:
                if head.latest is not last and head.latest is not None:
                    last = head.latest
                    published.append(last.seq)
                await asyncio.sleep(0.001)

        watcher = asyncio.create_task(watch())
        await asyncio.to_thread(feed)
        await asyncio.sleep(0.2)
        task.cancel()
        watcher.cancel()
        await asyncio.gather(task, watcher, return_exceptions=True)
        return head, slow, offered

    head, slow, offered = asyncio.run(main())
    return head, slow, published, offered


def test_overlapped_head_matches_the_next_frame_while_finishing_and_keeps_order() -> None:
    own_nice = os.getpriority(os.PRIO_PROCESS, threading.get_native_id())
    head, slow, published, offered = _run_head(overlap=True, seconds=1.5, matcher_nice=4)
    matches = [(seq, s, e) for stage, seq, s, e in slow.log if stage == "match"]
    finishes = [(seq, s, e) for stage, seq, s, e in slow.log if stage == "finish"]
    # The two halves ran side by side.
    assert slow.most_busy == 2
    overlapping = sum(1 for _, ms, me in matches for _, fs, fe in finishes if ms < fe and fs < me)
    assert overlapping >= len(finishes) // 2
    # Results keep their order, and each frame is finished once, after its match.
    finished = [seq for seq, _, _ in sorted(finishes, key=lambda f: f[1])]
    assert finished == sorted(finished) and len(set(finished)) == len(finished)
    assert published == sorted(published) and len(set(published)) == len(published)
    matched_at = {seq: e for seq, _, e in matches}
    assert all(matched_at[seq] <= s for seq, s, _ in finishes)
    # Latest wins: the camera is faster than the stages; frames are skipped, never queued.
    assert head.slot.skipped > offered // 2
    assert len(matches) - len(finishes) <= 2
    assert head.stats.processed == len(finishes)
    # Each stage always on its own thread (their scratch arrays are per thread).
    names = dict(slow.threads)
    assert len(slow.threads) == 2 and names["match"] != names["finish"]
    # The matcher is nicer (pipeline.matcher_nice), so the finisher gets a core first.
    assert slow.nice == {("match", min(19, own_nice + 4)), ("finish", own_nice)}


def test_head_without_overlap_runs_one_stage_at_a_time() -> None:
    own_nice = os.getpriority(os.PRIO_PROCESS, threading.get_native_id())
    head, slow, published, _ = _run_head(overlap=False, seconds=0.8, matcher_nice=4)
    assert {nice for _, nice in slow.nice} == {own_nice}  # one thread: nothing to favour
    assert slow.most_busy == 1
    assert len({name for _, name in slow.threads}) == 1  # one thread for both
    assert published == sorted(published) and len(published) >= 3
    assert head.stats.processed == sum(1 for stage, *_ in slow.log if stage == "finish")
