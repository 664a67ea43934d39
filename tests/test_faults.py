"""The fault suite (issue 21, item 7): every fault answered without a crash or a traceback, in
one clear log line, with the right STATUSTEXT and HEARTBEAT state, and nothing stale or
invented sent as clear.

Each case runs the real daemon in this process against the mock autopilot over real sockets
(UDP; TCP and a pty for the link faults). Camera faults use a fake V4L2 device under the real
:class:`V4l2Source` (the camera hardware is the edge of the world); files faults use real files
through the real files source; compute faults wrap the real matcher. What the autopilot hears
is decoded from the bytes.

Faults and where they are tested. Every case of a running daemon asserts: no crash, no traceback
(logged or on stderr), the one clear line (a regex; a handful of lines in all, not a line per
frame), the STATUSTEXT and HEARTBEAT state the autopilot hears, and that nothing it cannot vouch
for goes out as known (data captured during the fault: every bin unknown; older data: never
beyond max_age_ms). Rows marked *also* have more detailed tests elsewhere.

=====================================  =========================================================
fault                                  test
=====================================  =========================================================
camera: device missing at start        ``test_camera_fault[missing]`` (then plugged in)
camera: vanishing and returning        ``test_camera_fault[vanishing]``; *also*
                                       test_supervision.py (backoff, counters)
camera: frozen (same image, new time)  ``test_camera_fault[frozen|frozen-ardupilot]``,
                                       ``test_frame_check_drops_repeats_and_says_frozen_once``
camera: black / saturated              ``test_camera_fault[black|saturated]``; the texture gate
                                       alone: ``test_blind_views_give_no_clear_bin``
camera: no texture (fog, blank wall)   ``test_a_view_without_texture_sends_nothing_to_ardupilot``
camera: wrong size / pixel format      ``test_camera_fault[wrong-size|pixel-format]``
camera: one side missing               ``test_camera_fault[one-side-missing]``
camera: the two sides out of sync      ``test_camera_fault[out-of-sync]``
compute: matcher raises / stalls       ``test_camera_fault[matcher-raises|matcher-stalls]``,
                                       ``...[matcher-stalls-ardupilot]`` (every case prints
                                       its measured times to CRITICAL)
files: empty folder, unequal counts,   ``test_files_fault_at_start``: a configuration error
first image corrupt, garbage           (exit 2, one line, nothing started); *also*
frames.csv, empty video                test_bad_input.py (more frames.csv cases)
files: corrupt/truncated images        ``test_files_fault_mid_run[corrupt-*]`` (ridden out;
mid-run                                lost when every later frame is bad)
files: truncated video                 ``test_files_fault_mid_run[truncated-video]``
link: peer gone and back (UDP)         ``test_link_fault[peer-gone-udp]``; *also*
                                       test_autopilot_link.py ``test_link_down_and_up...``
link: TCP reset, serial port closed    ``test_link_fault[tcp-reset|serial-closed-and-reopened]``;
and reopened                           *also* test_autopilot_link.py ``test_reconnect...``
                                       (timing, loop lag, with a separate process)
link: autopilot reboot                 ``test_link_fault[autopilot-reboot]``; *also*
                                       test_autopilot_link.py ``test_a_quick_reboot...``
link: system id change                 ``test_link_fault[system-id-change|...-configured]``
link: garbage bytes, every transport   ``test_link_fault[garbage-udp|garbage-tcp|garbage-serial]``;
                                       *also* test_link_fuzz.py, test_udpin_strangers.py
config: 47 broken configurations       *elsewhere*: test_config_corpus.py
soak                                   *elsewhere*: test_soak.py
=====================================  =========================================================
"""

from __future__ import annotations

import asyncio
import functools
import itertools
import logging
import re
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from avoidd.daemon import Daemon
from avoidd.loading import load_all
from avoidd.mavlink import codec as mav
from avoidd.mavlink.layout import UNKNOWN_CM
from avoidd.mavlink.mock_autopilot import MockAutopilot
from avoidd.sources.scene import Pole, Scene, render_pair, to_uint8
from avoidd.sources.v4l2 import V4l2Source
from avoidd.types import RectifiedRig
from tests.helpers import RIG_320, free_udp_port, synthetic_config, wait_for, write_yaml

RIG = RectifiedRig(*(RIG_320[k] for k in ("width", "height", "fx", "fy", "cx", "cy", "baseline_m")))
FPS = 15.0
MAX_AGE_MS = 400
CLEAR_CM = 2001
"""A measured, clear bin (max_distance_cm + 1)."""
POLE_CM = 190
"""The truth of the pole's bins (every other bin's truth is clear)."""
REACT_S = 8.0
"""Generous bound on the daemon's answer to a fault (the target is 1 s on an idle machine)."""
SCENE = Scene(1.5, 0.0, (Pole(2.0, 0.0, 0.2, 3.0),), 45.0, 11)
"""A pole 1.9 m straight ahead, a tree line at 45 m: most bins in view are clear."""


@functools.cache
def views(count: int = 8) -> list[tuple[np.ndarray, np.ndarray]]:
    """Rendered BGR pairs of the scene, each with its own sensor noise (rendered once)."""
    rendered = render_pair(SCENE, RIG)
    rng = np.random.default_rng(5)

    def noisy(view: np.ndarray) -> np.ndarray:
        return to_uint8(view, rng.normal(0.0, 1.5, view.shape).astype(np.float32))

    return [(noisy(rendered.left), noisy(rendered.right)) for _ in range(count)]


# --- the fake camera --------------------------------------------------------------------------


@dataclass
class CameraWorld:
    """Two fake V4L2 devices ("0" left, "1" right) and the fault they show now."""

    fault: str | None = None
    opens: int = 0
    _pairs: Iterator[tuple[np.ndarray, np.ndarray]] = field(
        default_factory=lambda: itertools.cycle(views())
    )
    _pair: tuple[np.ndarray, np.ndarray] = field(default_factory=lambda: views()[0])
    _t0_s: float = field(default_factory=time.monotonic)

    def device(self, name: str) -> FakeDevice:
        return FakeDevice(self, int(name))

    def next_pair(self) -> tuple[np.ndarray, np.ndarray]:
        if self.fault != "frozen":
            self._pair = next(self._pairs)
        return self._pair

    def view(self, side: int) -> tuple[bool, np.ndarray | None]:
        fault = self.fault
        image = self._pair[side]
        if fault == "black":
            return True, np.random.default_rng().integers(0, 4, image.shape, dtype=np.uint8)
        if fault == "saturated":
            return True, np.full(image.shape, 255, dtype=np.uint8)
        if fault == "textureless":  # fog, a blank wall: mid grey and sensor noise
            noise = np.random.default_rng().normal(128.0, 1.5, image.shape)
            return True, noise.astype(np.uint8)
        if fault == "wrong-size":
            return True, image[::2, ::2].copy()
        if fault == "pixel-format":
            return True, image[:, :, 0].astype(np.uint16) * 256
        if fault == "one-side-missing" and side == 1:
            return False, None
        return True, image.copy()


class FakeDevice:
    """One V4L2 device of a :class:`CameraWorld` (the ``Capture`` protocol of the source)."""

    def __init__(self, world: CameraWorld, side: int) -> None:
        self.world = world
        self.side = side
        self.stamp_ms = 0.0
        if side == 0:
            world.opens += 1

    def isOpened(self) -> bool:  # noqa: N802 - OpenCV's name
        return self.world.fault not in ("missing", "vanishing")

    def set(self, prop: int, value: float) -> bool:
        return True

    def get(self, prop: int) -> float:
        sizes = {cv2.CAP_PROP_FRAME_WIDTH: RIG.width, cv2.CAP_PROP_FRAME_HEIGHT: RIG.height}
        if prop in sizes:
            return float(sizes[prop])
        if prop == cv2.CAP_PROP_FPS:
            return FPS
        if prop == cv2.CAP_PROP_FOURCC:
            return float(cv2.VideoWriter.fourcc(*"MJPG"))
        if prop == cv2.CAP_PROP_POS_MSEC:
            return self.stamp_ms
        return 0.0

    def grab(self) -> bool:
        world = self.world
        if world.fault in ("missing", "vanishing"):
            return False
        if self.side == 0:
            time.sleep(1.0 / FPS)  # a camera delivers at its rate
            world.next_pair()
        self.stamp_ms = (time.monotonic() - world._t0_s) * 1000.0 + 1.0
        if world.fault == "out-of-sync" and self.side == 1:
            self.stamp_ms += 40.0  # more than half a frame (33 ms at 15 fps)
        return True

    def retrieve(self) -> tuple[bool, np.ndarray | None]:
        return self.world.view(self.side)

    def release(self) -> None:
        pass


class FaultyMatcher:
    """Wraps the real matcher: raises or stalls while its world says so."""

    def __init__(self, inner: Any, world: CameraWorld, release: threading.Event) -> None:
        self._inner = inner
        self._world = world
        self._release = release

    def __getattr__(self, name: str) -> Any:
        return getattr(self._inner, name)

    def compute(self, left: np.ndarray, right: np.ndarray) -> Any:
        if self._world.fault == "matcher-raises":
            raise RuntimeError("matcher bug: index out of range")
        if self._world.fault == "matcher-stalls":
            self._release.wait(30.0)
        return self._inner.compute(left, right)


# --- running a case ---------------------------------------------------------------------------


@dataclass
class Heard:
    """What the autopilot heard, with the monotonic time it heard it."""

    autopilot: MockAutopilot

    def since(self, kind: str, t_ns: int) -> list[Any]:
        return [
            r.message
            for r in self.autopilot.recorded
            if r.received_ns >= t_ns and r.message.get_type() == kind
        ]

    def first(self, kind: str, t_ns: int, test: Callable[[Any], bool]) -> int | None:
        for r in self.autopilot.recorded:
            if r.received_ns >= t_ns and r.message.get_type() == kind and test(r.message):
                return r.received_ns
        return None

    def state_since(self, t_ns: int, state: int) -> int | None:
        return self.first("HEARTBEAT", t_ns, lambda m: m.system_status == state)

    def text_since(self, t_ns: int, pattern: str) -> Any | None:
        found = [m for m in self.since("STATUSTEXT", t_ns) if re.search(pattern, m.text)]
        return found[0] if found else None


def _known(message: Any) -> list[int]:
    return [d for d in message.distances if d != UNKNOWN_CM]


def _check_nothing_vouched(heard: Heard, fault_ns: int, end_ns: int) -> None:
    """While the fault lasts nothing is sent as known that the daemon cannot vouch for.

    Data captured during the fault says nothing new: every bin unknown, but for an obstacle
    the temporal filter still holds (never clear, never farther than the pole, the nearest
    truth); data captured before it may still be sent, but never older than max_age_ms (plus
    the way to the autopilot).
    """
    for record in heard.autopilot.recorded:
        message = record.message
        if message.get_type() != "OBSTACLE_DISTANCE" or not fault_ns <= record.received_ns < end_ns:
            continue
        captured_ns = message.time_usec * 1000
        if captured_ns >= fault_ns:
            invented = [d for d in _known(message) if d > POLE_CM * 1.06]
            assert not invented, f"data captured during the fault sent: {_known(message)}"
        else:
            age_ms = (record.received_ns - captured_ns) / 1e6
            assert age_ms <= MAX_AGE_MS + 500, f"pre-fault data sent {age_ms:.0f} ms old"


def _warnings_since(caplog: pytest.LogCaptureFixture, t_s: float) -> list[logging.LogRecord]:
    return [r for r in caplog.records if r.created >= t_s and r.levelno >= logging.WARNING]


def _check_logs(
    caplog: pytest.LogCaptureFixture, capfd: pytest.CaptureFixture[str], t_s: float, pattern: str
) -> list[str]:
    """One clear line for the fault, no flood, no traceback anywhere."""
    lines = [r.getMessage() for r in _warnings_since(caplog, t_s)]
    matching = [line for line in lines if re.search(pattern, line)]
    assert matching, f"no line matches {pattern!r}: {lines}"
    assert len(matching) <= 2, matching  # the line, and at most a summary of its repeats
    assert len(lines) <= 8, lines  # the fault and its consequences, not a line per frame
    assert not any(r.exc_info for r in caplog.records), "a traceback was logged"
    assert "Traceback" not in caplog.text
    assert "Traceback" not in capfd.readouterr().err
    return lines


@dataclass(frozen=True)
class CameraCase:
    """A camera or compute fault and how the daemon must answer it."""

    fault: str
    log: str
    """The one clear line (a regex)."""
    statustext: str
    """The CRITICAL STATUSTEXT (a regex)."""
    at_start: bool = False
    """The fault is there when the daemon starts (else it begins once data flows)."""
    recovers: bool = True
    """The fault ends and the daemon must say so."""
    flavour: str = "px4"
    """The autopilot: PX4 hears every bin unknown when nothing is fresh, ArduPilot nothing."""

    @property
    def name(self) -> str:
        return self.fault if self.flavour == "px4" else f"{self.fault}-{self.flavour}"


CAMERA_CASES = [
    CameraCase(
        "missing",
        r"camera 'front': cannot open 0 with V4L2; retrying with backoff",
        r"^avoidd: front camera lost$",
        at_start=True,
    ),
    CameraCase(
        "vanishing",
        r"head 'front': source lost \(.*no frame \(device lost\?\)\); reopening",
        r"^avoidd: front camera lost$",
    ),
    CameraCase(
        "frozen",
        r"head 'front': camera frozen: the same image \d+ times in a row",
        r"^avoidd: front stale, camera frozen$",
    ),
    CameraCase(
        "frozen",
        r"head 'front': camera frozen: the same image \d+ times in a row",
        r"^avoidd: front stale, camera frozen$",
        flavour="ardupilot",
    ),
    CameraCase(
        "black",
        r"head 'front': camera blind: the left view is black",
        r"^avoidd: front stale, camera blind$",
    ),
    CameraCase(
        "saturated",
        r"head 'front': camera blind: the left view is saturated",
        r"^avoidd: front stale, camera blind$",
    ),
    CameraCase(
        "wrong-size",
        r"head 'front': left image is 160x120, calibration says 320x240; frame \d+ dropped",
        r"^avoidd: front camera lost$",
    ),
    CameraCase(
        "pixel-format",
        r"head 'front': left image is uint16 with shape \(240, 320\), expected 8-bit",
        r"^avoidd: front camera lost$",
    ),
    CameraCase(
        "one-side-missing",
        r"camera 'front' \(left/right 0, 1\): right view could not be decoded",
        r"^avoidd: front camera lost$",
    ),
    CameraCase(
        "out-of-sync",
        r"left and right taken 4\d ms apart \(more than half a frame at 15 fps\); frame \d+ "
        r"dropped; are the cameras synchronised\?",
        r"^avoidd: front camera lost$",
    ),
    CameraCase(
        "matcher-raises",
        r"head 'front': frame \d+ failed \(RuntimeError\('matcher bug: index out of range'\)\); "
        r"dropped",
        r"^avoidd: front stale, compute failing$",
    ),
    CameraCase(
        "matcher-stalls",
        r"head 'front': data stale \(compute late\); its sectors are unknown",
        r"^avoidd: front stale, compute late$",
    ),
    CameraCase(
        "matcher-stalls",
        r"head 'front': data stale \(compute late\); its sectors are unknown",
        r"^avoidd: front stale, compute late$",
        flavour="ardupilot",
    ),
]


def _camera_config(tmp_path: Path, port: int) -> Path:
    calibration = tmp_path / "calib.yaml"
    write_yaml(calibration, {"version": 1, "rectified": RIG_320})
    head = {
        "name": "front",
        "calibration": str(calibration),
        "source": {
            "kind": "v4l2",
            "devices": ["0", "1"],
            "width": RIG.width,
            "height": RIG.height,
            "fps": FPS,
            "reopen_min_s": 0.2,
            "reopen_max_s": 0.5,
        },
    }
    return synthetic_config(
        tmp_path,
        f"udpout:127.0.0.1:{port}",
        heads=[head],
        pipeline={"max_age_ms": MAX_AGE_MS, "log_interval_s": 600.0},
    )


@pytest.mark.parametrize("case", CAMERA_CASES, ids=lambda case: case.name)
async def test_camera_fault(
    tmp_path: Path,
    caplog: pytest.LogCaptureFixture,
    capfd: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    case: CameraCase,
) -> None:
    caplog.set_level(logging.INFO, logger="avoidd")
    world = CameraWorld(fault=case.fault if case.at_start else None)
    release = threading.Event()
    import avoidd.pipeline

    real_create = avoidd.pipeline.create_matcher
    monkeypatch.setattr(
        avoidd.pipeline,
        "create_matcher",
        lambda config: FaultyMatcher(real_create(config), world, release),
    )

    def open_camera(config: Any, rig: Any, head: str, paced: bool, input_path: Any = None) -> Any:
        return V4l2Source(config, head, world.device)

    port = free_udp_port()
    autopilot = MockAutopilot(flavour=case.flavour, system_id=7)
    await autopilot.start(f"udpin:127.0.0.1:{port}")
    config, calibrations = load_all(_camera_config(tmp_path, port))
    daemon = Daemon(config, calibrations, open_source=open_camera)
    task = asyncio.create_task(daemon.run())
    heard = Heard(autopilot)
    try:
        started_ns = time.monotonic_ns()
        if not case.at_start:
            assert await wait_for(
                lambda: (
                    heard.state_since(started_ns, mav.MAV_STATE_ACTIVE) is not None
                    and any(_known(m) for m in heard.since("OBSTACLE_DISTANCE", started_ns))
                ),
                30.0,
            ), "never healthy"
            assert CLEAR_CM in heard.since("OBSTACLE_DISTANCE", started_ns)[-1].distances
            world.fault = case.fault
        fault_ns, fault_s = time.monotonic_ns(), time.time()
        # The answer: STATUSTEXT CRITICAL and HEARTBEAT CRITICAL.
        assert await wait_for(
            lambda: heard.text_since(fault_ns, case.statustext) is not None, REACT_S + 5.0
        ), [m.text for m in heard.since("STATUSTEXT", fault_ns)]
        assert heard.text_since(fault_ns, case.statustext).severity == mav.MAV_SEVERITY_CRITICAL
        assert await wait_for(
            lambda: heard.state_since(fault_ns, mav.MAV_STATE_CRITICAL) is not None, REACT_S + 5.0
        )
        critical_ns = heard.state_since(fault_ns, mav.MAV_STATE_CRITICAL)
        assert critical_ns is not None
        text_ns = heard.first("STATUSTEXT", fault_ns, lambda m: re.search(case.statustext, m.text))
        assert text_ns is not None
        await asyncio.sleep(1.5)  # the fault lasts
        end_ns = time.monotonic_ns()
        _check_nothing_vouched(heard, fault_ns, end_ns)
        # While it lasts, the heartbeats say CRITICAL; PX4 still hears OBSTACLE_DISTANCE, every
        # bin unknown, ArduPilot hears nothing (and reports "PRX1: No Data").
        late = [m.system_status for m in heard.since("HEARTBEAT", critical_ns)]
        assert set(late) == {mav.MAV_STATE_CRITICAL}, late
        if case.fault not in ("missing", "vanishing", "matcher-stalls"):
            assert daemon.heads[0].stats.broken > 0  # the frames are dropped and counted
        lines = _check_logs(caplog, capfd, fault_s, case.log)
        if case.flavour == "px4":
            assert heard.since("OBSTACLE_DISTANCE", critical_ns), "PX4 must hear 'no data'"
            unknown_ns = heard.first("OBSTACLE_DISTANCE", fault_ns, lambda m: not _known(m))
            assert unknown_ns is not None
        else:
            assert heard.since("OBSTACLE_DISTANCE", critical_ns) == []
            sent = [r.received_ns for r in autopilot.recorded if r.received_ns >= fault_ns]
            last = [
                r.received_ns
                for r in autopilot.recorded
                if r.message.get_type() == "OBSTACLE_DISTANCE" and r.received_ns >= fault_ns
            ]
            unknown_ns = max(last, default=min(sent))
        print(
            f"{case.name}: nothing known sent after {(unknown_ns - fault_ns) / 1e6:.0f} ms, "
            f"STATUSTEXT after {(text_ns - fault_ns) / 1e6:.0f} ms, HEARTBEAT CRITICAL after "
            f"{(critical_ns - fault_ns) / 1e6:.0f} ms (max_age_ms {MAX_AGE_MS}); "
            f"{len(lines)} warning lines: {lines}"
        )
        if case.recovers:
            world.fault = None
            release.set()
            back_ns = time.monotonic_ns()
            assert await wait_for(
                lambda: heard.text_since(back_ns, r"^avoidd: front recovered$") is not None,
                REACT_S + 5.0,
            )
            assert await wait_for(
                lambda: heard.state_since(back_ns, mav.MAV_STATE_ACTIVE) is not None, 5.0
            )
            assert await wait_for(
                lambda: any(_known(m) for m in heard.since("OBSTACLE_DISTANCE", back_ns)), 5.0
            )
            if case.fault in ("missing", "vanishing"):
                assert world.opens >= 2  # opened again, with backoff, until it was back
    finally:
        release.set()
        daemon.stop()
        assert await asyncio.wait_for(task, timeout=30.0) == 0
        await autopilot.stop()
    assert "Traceback" not in caplog.text


async def test_a_view_without_texture_sends_nothing_to_ardupilot(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, capfd: pytest.CaptureFixture[str]
) -> None:
    """A working camera that sees no texture (fog): fresh data, not one bin known.

    PX4 hears every bin unknown; ArduPilot would read that as a clear view, so it hears
    nothing and says "PRX1: No Data" itself. The camera and the pipeline are fine: ACTIVE.
    """
    caplog.set_level(logging.INFO, logger="avoidd")
    world = CameraWorld()

    def open_camera(config: Any, rig: Any, head: str, paced: bool, input_path: Any = None) -> Any:
        return V4l2Source(config, head, world.device)

    port = free_udp_port()
    autopilot = MockAutopilot(flavour="ardupilot", system_id=7)
    await autopilot.start(f"udpin:127.0.0.1:{port}")
    config, calibrations = load_all(_camera_config(tmp_path, port))
    daemon = Daemon(config, calibrations, open_source=open_camera)
    task = asyncio.create_task(daemon.run())
    heard = Heard(autopilot)
    try:
        started_ns = time.monotonic_ns()
        assert await wait_for(
            lambda: any(_known(m) for m in heard.since("OBSTACLE_DISTANCE", started_ns)), 30.0
        ), "never healthy"
        world.fault = "textureless"
        fault_ns, fault_s = time.monotonic_ns(), time.time()
        head = daemon.heads[0]
        processed = head.stats.processed
        await asyncio.sleep(2.5)
        assert head.stats.processed > processed + 5  # the frames are fine and processed
        late_ns = fault_ns + (MAX_AGE_MS + 500) * 1_000_000
        assert heard.since("OBSTACLE_DISTANCE", late_ns) == []
        _check_nothing_vouched(heard, fault_ns, time.monotonic_ns())
        assert {m.system_status for m in heard.since("HEARTBEAT", fault_ns)} == {
            mav.MAV_STATE_ACTIVE
        }
        _check_logs(caplog, capfd, fault_s, r"fresh data but no bin measured")
        world.fault = None
        back_ns = time.monotonic_ns()
        assert await wait_for(
            lambda: any(_known(m) for m in heard.since("OBSTACLE_DISTANCE", back_ns)), REACT_S
        )
    finally:
        daemon.stop()
        assert await asyncio.wait_for(task, timeout=30.0) == 0
        await autopilot.stop()


# --- the pure parts of the camera answers -----------------------------------------------------


@pytest.mark.parametrize("level", ["black", "saturated", "left-black"])
def test_blind_views_give_no_clear_bin(tmp_path: Path, level: str) -> None:
    """Black and saturated views (were they processed) leave bins unknown, never clear."""
    from avoidd.mavlink.messages import sectors_to_cm
    from avoidd.pipeline import HeadPipeline
    from avoidd.types import StereoFrame

    config, calibrations = load_all(_camera_config(tmp_path, free_udp_port()))
    pipeline = HeadPipeline(config.heads[0], calibrations["front"], 20.0, config.perception)
    rng = np.random.default_rng(1)
    left, right = views()[0]
    black = rng.integers(0, 4, left.shape, dtype=np.uint8)
    white = np.full(left.shape, 255, dtype=np.uint8)
    pairs = {"black": (black, black), "saturated": (white, white), "left-black": (black, right)}
    frame = StereoFrame(0, time.monotonic_ns(), *pairs[level])
    bins = sectors_to_cm(pipeline.process(frame).scan, 20, 2000)
    assert CLEAR_CM not in bins
    assert set(bins) == {UNKNOWN_CM}


def test_frame_check_drops_repeats_and_says_frozen_once(caplog: pytest.LogCaptureFixture) -> None:
    from avoidd.daemon.framecheck import FROZEN_AFTER, FrameCheck
    from avoidd.types import StereoFrame

    caplog.set_level(logging.INFO, logger="avoidd")
    check = FrameCheck("front")
    frames = [StereoFrame(i, i, *views()[i % len(views())]) for i in range(3)]
    assert check.usable(frames[0]) and check.usable(frames[1])
    assert not check.usable(frames[1]._replace(seq=2, t_capture_ns=2))  # one repeat: dropped
    assert check.fault is None and not caplog.records  # ...silently
    assert check.usable(frames[2])
    for _ in range(FROZEN_AFTER + 20):
        assert not check.usable(frames[2])
    assert check.fault == "camera frozen" and check.repeated == 1 + FROZEN_AFTER + 20
    assert check.usable(frames[0]) and check.fault is None
    assert [r.getMessage().split(":")[1] for r in caplog.records] == [
        " camera frozen",
        " camera no longer frozen after 23 repeated frames",
    ]


def test_a_dark_but_textured_view_is_not_blind() -> None:
    from avoidd.daemon.framecheck import blind_view

    left = views()[0][0]
    assert blind_view(left) is None
    assert blind_view((left // 8).astype(np.uint8)) is None  # underexposed, still texture
    assert blind_view(np.zeros_like(left)) == "black"
    assert blind_view(np.full_like(left, 250)) == "saturated"


# --- files ------------------------------------------------------------------------------------


def _write_pairs(folder: Path, count: int) -> Path:
    (folder / "left").mkdir(parents=True)
    (folder / "right").mkdir()
    for index in range(count):
        left, right = views()[index % len(views())]
        cv2.imwrite(str(folder / "left" / f"{index:04d}.png"), left)
        cv2.imwrite(str(folder / "right" / f"{index:04d}.png"), right)
    return folder


def _truncate(path: Path, keep: float = 0.5) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * keep)])


def _write_video(path: Path, count: int) -> Path:
    writer = cv2.VideoWriter(
        str(path), cv2.VideoWriter.fourcc(*"MJPG"), 10.0, (2 * RIG.width, RIG.height)
    )
    assert writer.isOpened()
    for index in range(count):
        writer.write(np.hstack(views()[index % len(views())]))
    writer.release()
    return path


def _files_config(tmp_path: Path, path: Path, port: int, max_age_ms: int = MAX_AGE_MS) -> Path:
    calibration = tmp_path / "calib.yaml"
    write_yaml(calibration, {"version": 1, "rectified": RIG_320})
    head = {
        "name": "front",
        "calibration": str(calibration),
        "source": {"kind": "files", "path": str(path), "fps": 10},
    }
    return synthetic_config(
        tmp_path,
        f"udpout:127.0.0.1:{port}",
        heads=[head],
        pipeline={"max_age_ms": max_age_ms, "log_interval_s": 600.0},
    )


def _empty_folder(tmp_path: Path) -> Path:
    folder = tmp_path / "rec"
    (folder / "left").mkdir(parents=True)
    (folder / "right").mkdir()
    return folder


def _unequal(tmp_path: Path) -> Path:
    folder = _write_pairs(tmp_path / "rec", 3)
    (folder / "right" / "0002.png").unlink()
    return folder


def _first_corrupt(tmp_path: Path) -> Path:
    folder = _write_pairs(tmp_path / "rec", 3)
    _truncate(folder / "left" / "0000.png")
    return folder


def _garbage_csv(tmp_path: Path) -> Path:
    folder = _write_pairs(tmp_path / "rec", 3)
    (folder / "frames.csv").write_bytes(bytes(range(256)) * 4)
    return folder


def _empty_video(tmp_path: Path) -> Path:
    path = tmp_path / "flight.avi"
    path.write_bytes(b"")
    return path


@pytest.mark.parametrize(
    ("make", "fragment"),
    [
        (_empty_folder, "rec: no images in left/"),
        (_unequal, "rec: left/ has 3 images, right/ has 2; pairs are matched by sorted name"),
        (_first_corrupt, "0000.png: truncated image (no end marker); frame 0 dropped"),
        (_garbage_csv, "frames.csv"),
        (_empty_video, "flight.avi: "),
    ],
    ids=[
        "empty-folder",
        "unequal-counts",
        "first-image-corrupt",
        "garbage-frames-csv",
        "empty-video",
    ],
)
def test_files_fault_at_start(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    make: Callable[[Path], Path],
    fragment: str,
) -> None:
    """Unusable input at start is a configuration error: exit 2, one line, nothing started."""
    from avoidd.cli import main

    config = _files_config(tmp_path, make(tmp_path), free_udp_port())
    code = main(["run", "--config", str(config)])
    lines = capsys.readouterr().err.splitlines()
    assert code == 2
    assert len(lines) == 2, lines
    assert "heads.front.source.path" in lines[0] and fragment in lines[0], lines
    assert lines[1] == "configuration invalid; nothing was started"
    assert not any("Traceback" in line for line in lines)


@dataclass(frozen=True)
class FilesCase:
    """Input that breaks while the daemon reads it."""

    name: str
    make: Callable[[Path], Path]
    log: str
    statustext: str | None
    """The CRITICAL STATUSTEXT, or None when the daemon rides the fault out."""
    max_age_ms: int = MAX_AGE_MS
    also: str | None = None
    """Another STATUSTEXT that must be heard (a regex)."""


def _corrupt_some(tmp_path: Path) -> Path:
    folder = _write_pairs(tmp_path / "rec", 60)
    for index in (12, 13):
        _truncate(folder / "left" / f"{index:04d}.png")
    return folder


def _corrupt_rest(tmp_path: Path) -> Path:
    folder = _write_pairs(tmp_path / "rec", 60)
    for index in range(12, 60):
        (folder / "right" / f"{index:04d}.png").write_bytes(bytes(range(256)) * 8)
    return folder


def _truncated_video(tmp_path: Path) -> Path:
    path = _write_video(tmp_path / "flight.avi", 60)
    _truncate(path, 0.25)
    return path


FILES_CASES = [
    FilesCase(
        "corrupt-images-ridden-out",
        _corrupt_some,
        r"0012\.png: truncated image \(no end marker\); frame 12 dropped",
        None,
        max_age_ms=1500,
    ),
    FilesCase(
        "corrupt-images-from-frame-12",
        _corrupt_rest,
        r"0012\.png: truncated image \(no end marker\); frame 12 dropped",
        r"^avoidd: front camera lost$",
    ),
    FilesCase(
        "truncated-video",
        _truncated_video,
        r"head 'front': side-by-side video .*flight\.avi ended after \d+ of the 60 frames its "
        r"header announces: the file is truncated or damaged; no more data",
        r"^avoidd: front stale, ",
        also=r"^avoidd: front source ended$",
    ),
]


@pytest.mark.parametrize("case", FILES_CASES, ids=lambda case: case.name)
async def test_files_fault_mid_run(
    tmp_path: Path,
    caplog: pytest.LogCaptureFixture,
    capfd: pytest.CaptureFixture[str],
    case: FilesCase,
) -> None:
    caplog.set_level(logging.INFO, logger="avoidd")
    port = free_udp_port()
    autopilot = MockAutopilot(flavour="ardupilot", system_id=7)
    await autopilot.start(f"udpin:127.0.0.1:{port}")
    config, calibrations = load_all(
        _files_config(tmp_path, case.make(tmp_path), port, case.max_age_ms)
    )
    daemon = Daemon(config, calibrations)
    task = asyncio.create_task(daemon.run())
    heard = Heard(autopilot)
    start_ns, start_s = time.monotonic_ns(), time.time()
    try:
        assert await wait_for(
            lambda: any(_known(m) for m in heard.since("OBSTACLE_DISTANCE", start_ns)), 30.0
        ), "never healthy"
        head = daemon.heads[0]
        assert await wait_for(lambda: head.stats.broken > 0 or head.ended, 30.0)
        fault_ns = time.monotonic_ns()
        if case.statustext is None:
            # Ridden out: a few frames dropped, data flows on, nothing reported stale.
            assert await wait_for(lambda: head.stats.processed >= 30, 30.0)
            assert head.stats.broken == 2
            texts = [m.text for m in heard.since("STATUSTEXT", start_ns)]
            assert not any("stale" in text or "lost" in text for text in texts), texts
            states = {m.system_status for m in heard.since("HEARTBEAT", fault_ns)}
            assert states == {mav.MAV_STATE_ACTIVE}, states
        else:
            statustext = case.statustext
            assert await wait_for(
                lambda: heard.text_since(start_ns, statustext) is not None, REACT_S + 5.0
            ), [m.text for m in heard.since("STATUSTEXT", start_ns)]
            message = heard.text_since(start_ns, statustext)
            assert message.severity == mav.MAV_SEVERITY_CRITICAL
            assert await wait_for(
                lambda: heard.state_since(fault_ns, mav.MAV_STATE_CRITICAL) is not None, REACT_S
            )
            critical_ns = heard.state_since(fault_ns, mav.MAV_STATE_CRITICAL)
            also = case.also
            if also is not None:
                assert await wait_for(lambda: heard.text_since(start_ns, also) is not None, 5.0)
            await asyncio.sleep(1.5)
            # ArduPilot hears nothing once the data is stale (it then reports "No Data").
            assert heard.since("OBSTACLE_DISTANCE", critical_ns) == []
            late = {m.system_status for m in heard.since("HEARTBEAT", critical_ns)}
            assert late == {mav.MAV_STATE_CRITICAL}, late
            _check_nothing_vouched(heard, fault_ns, time.monotonic_ns())
        lines = _check_logs(caplog, capfd, start_s, case.log)
        # The temporal filter's first frames know no bin yet: not worth a warning at start.
        assert not any("no bin measured" in line for line in lines), lines
        print(f"{case.name}: {len(lines)} warning lines: {lines}")
    finally:
        daemon.stop()
        assert await asyncio.wait_for(task, timeout=30.0) == 0
        await autopilot.stop()


# --- link -------------------------------------------------------------------------------------


@dataclass
class LinkRun:
    """The daemon on the synthetic camera and the mock autopilot it talks to."""

    tmp_path: Path
    kind: str
    autopilot: MockAutopilot
    mock_connection: str = ""
    connection: str = ""
    daemon: Any = None

    async def restart_autopilot(self, system_id: int = 7, wait_down: bool = True) -> None:
        """The autopilot goes away (its socket or pty closed) and comes back."""
        await self.autopilot.stop()
        if wait_down:
            assert await wait_for(lambda: not self.daemon.vehicle.link_up, REACT_S)
        self.autopilot = MockAutopilot(system_id=system_id)
        await self.autopilot.start(self.mock_connection)


async def _peer_gone(run: LinkRun) -> None:
    await run.restart_autopilot()


async def _reboot(run: LinkRun) -> None:
    # A reboot shows as the streams' boot clock going back, or as every delivering stream
    # going silent: wait until each accepted stream has delivered (on a loaded machine the
    # acknowledgements can come before the first messages; a stream accepted but never
    # delivered is one the autopilot has nothing for, and is not watched).
    vehicle = run.daemon.vehicle
    assert await wait_for(
        lambda: all(r.last_ns >= r.acked_ns for r in vehicle.requests if r.acked), REACT_S
    )
    run.autopilot.reboot()
    assert await wait_for(lambda: run.daemon.vehicle.reboots == 1, REACT_S)


async def _system_id_change(run: LinkRun) -> None:
    await run.restart_autopilot(system_id=9)


async def _garbage(run: LinkRun) -> None:
    rng = np.random.default_rng(7)
    assert run.autopilot.transport is not None
    for _ in range(300):
        run.autopilot.transport.send(rng.bytes(int(rng.integers(1, 300))))
        await asyncio.sleep(0)
    assert await wait_for(lambda: run.daemon.link.parse_errors > 0, REACT_S)


@dataclass(frozen=True)
class LinkCase:
    """A link fault, the line that says it and what the autopilot hears afterwards."""

    name: str
    kind: str
    act: Callable[[LinkRun], Any]
    log: str | None
    """The one clear line (None: the fault is counted, not logged)."""
    statustext: str | None
    """What the autopilot hears about it afterwards."""
    system_id: int | str = 7
    speaks_as: int = 7
    """The system id avoidd speaks as afterwards."""


LINK_DOWN = r"MAVLink link down: no heartbeat from system 7 for 1\.5 s"
LINK_UP = r"^avoidd: link up, ArduPilot STABILIZE$"
LINK_CASES = [
    LinkCase("peer-gone-udp", "udp", _peer_gone, LINK_DOWN, LINK_UP),
    LinkCase("tcp-reset", "tcp", _peer_gone, LINK_DOWN, LINK_UP),
    LinkCase("serial-closed-and-reopened", "serial", _peer_gone, LINK_DOWN, LINK_UP),
    LinkCase(
        "autopilot-reboot",
        "udp",
        _reboot,
        r"vehicle 7 rebooted \(.*\); asking for its streams again",
        r"^avoidd: autopilot rebooted$",
    ),
    LinkCase(
        "system-id-change",
        "udp",
        _system_id_change,
        r"MAVLink: the autopilot is now system 9 \(was 7\); following it",
        r"^avoidd: autopilot now system 9$",
        system_id="auto",
        speaks_as=9,
    ),
    LinkCase(
        "system-id-change-configured",
        "udp",
        _system_id_change,
        r"MAVLink: an autopilot speaks as system 9, but mavlink.system_id is 7; ignored",
        r"^avoidd: ignoring autopilot 9, configured 7$",
    ),
    LinkCase("garbage-udp", "udp", _garbage, None, None),
    LinkCase("garbage-tcp", "tcp", _garbage, None, None),
    LinkCase("garbage-serial", "serial", _garbage, None, None),
]


@pytest.mark.parametrize("case", LINK_CASES, ids=lambda case: case.name)
async def test_link_fault(
    tmp_path: Path,
    caplog: pytest.LogCaptureFixture,
    capfd: pytest.CaptureFixture[str],
    case: LinkCase,
) -> None:
    caplog.set_level(logging.INFO, logger="avoidd")
    run = LinkRun(tmp_path, case.kind, MockAutopilot(system_id=7))
    if case.kind == "udp":
        port = free_udp_port()
        run.mock_connection, run.connection = f"udpin:127.0.0.1:{port}", f"udpout:127.0.0.1:{port}"
    elif case.kind == "tcp":
        port = free_udp_port()  # any free number; TCP and UDP ports are separate spaces
        run.mock_connection, run.connection = f"tcpin:127.0.0.1:{port}", f"tcp:127.0.0.1:{port}"
    else:
        path = tmp_path / "ttyAP"
        run.mock_connection, run.connection = f"pty:{path}", f"serial:{path},115200"
    await run.autopilot.start(run.mock_connection)
    mavlink = {"system_id": case.system_id, "link_timeout_s": 1.5}
    config, calibrations = load_all(
        synthetic_config(
            tmp_path,
            run.connection,
            mavlink=mavlink,
            pipeline={"max_age_ms": MAX_AGE_MS, "log_interval_s": 600.0},
        )
    )
    run.daemon = daemon = Daemon(config, calibrations)
    task = asyncio.create_task(daemon.run())
    try:
        assert await wait_for(
            lambda: daemon.vehicle.link_up and daemon.vehicle.streams_acknowledged, 30.0
        )
        fault_ns, fault_s = time.monotonic_ns(), time.time()
        await case.act(run)
        acted_ns = time.monotonic_ns()
        heard = Heard(run.autopilot)  # the autopilot there now
        statustext = case.statustext
        answered_ns = acted_ns
        if statustext is not None:
            assert await wait_for(
                lambda: heard.text_since(fault_ns, statustext) is not None, REACT_S
            ), [m.text for m in heard.since("STATUSTEXT", fault_ns)]
            answered_ns = heard.first(
                "STATUSTEXT", fault_ns, lambda m: re.search(statustext, m.text)
            )
            assert answered_ns is not None
        # The pipeline is fine: the autopilot hears ACTIVE and fresh data, as the right system.
        assert await wait_for(
            lambda: heard.state_since(acted_ns, mav.MAV_STATE_ACTIVE) is not None, REACT_S
        )
        assert await wait_for(
            lambda: any(_known(m) for m in heard.since("OBSTACLE_DISTANCE", acted_ns)), REACT_S
        )
        await asyncio.sleep(1.0)
        after = [r for r in run.autopilot.recorded if r.received_ns >= fault_ns]
        for record in after:
            message = record.message
            assert message.get_srcSystem() == case.speaks_as or record.received_ns <= answered_ns
            if message.get_type() == "OBSTACLE_DISTANCE":
                # Nothing queued during the outage arrives stale afterwards.
                age_ms = (record.received_ns - message.time_usec * 1000) / 1e6
                assert age_ms <= MAX_AGE_MS + 500, f"data {age_ms:.0f} ms old"
        states = {m.system_status for m in heard.since("HEARTBEAT", acted_ns)}
        assert states == {mav.MAV_STATE_ACTIVE}, states
        if case.log is not None:
            lines = _check_logs(caplog, capfd, fault_s, case.log)
        else:
            lines = [r.getMessage() for r in _warnings_since(caplog, fault_s)]
            assert len(lines) <= 2, lines
            assert "Traceback" not in caplog.text + capfd.readouterr().err
        said = f"STATUSTEXT {(answered_ns - acted_ns) / 1e6:.0f} ms after the fault was done; "
        print(f"{case.name}: {said if statustext else ''}{len(lines)} warning lines: {lines}")
    finally:
        daemon.stop()
        assert await asyncio.wait_for(task, timeout=30.0) == 0
        await run.autopilot.stop()
