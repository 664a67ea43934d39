from __future__ import annotations

import logging
import time
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import cv2
import numpy as np
import pytest

from avoidd.config import SyntheticObstacleConfig, SyntheticSourceConfig, V4l2SourceConfig
from avoidd.errors import BrokenFrame, SourceError, SourceExhausted
from avoidd.sources import synthetic
from avoidd.sources.base import Pacer
from avoidd.sources.files import FolderSource, SideBySideVideoSource, open_files
from avoidd.sources.scene import render_pair
from avoidd.sources.synthetic import SyntheticSource, scene_at
from avoidd.sources.truth import nearest_obstacle
from avoidd.sources.v4l2 import V4l2Source
from avoidd.types import FramePose, Mount, RectifiedRig

RIG = RectifiedRig(160, 120, 100.0, 100.0, 79.5, 59.5, 0.12, 0.0)


def make_folder(tmp_path: Path, count: int, csv_rows: list[str] | None = None) -> Path:
    folder = tmp_path / "pairs"
    (folder / "left").mkdir(parents=True)
    (folder / "right").mkdir()
    for i in range(count):
        left = np.full((30, 40, 3), i, dtype=np.uint8)
        right = np.full((30, 40, 3), 100 + i, dtype=np.uint8)
        cv2.imwrite(str(folder / "left" / f"{i:04d}.png"), left)
        cv2.imwrite(str(folder / "right" / f"{i:04d}.png"), right)
    if csv_rows is not None:
        (folder / "frames.csv").write_text("\n".join(csv_rows) + "\n")
    return folder


def test_folder_pairs_by_sorted_name(tmp_path: Path) -> None:
    source = FolderSource(make_folder(tmp_path, 3), None, paced=False, loop=False)
    frames = [source.read() for _ in range(3)]
    assert [f.seq for f in frames] == [0, 1, 2]
    assert [int(f.left[0, 0, 0]) for f in frames] == [0, 1, 2]
    assert [int(f.right[0, 0, 0]) for f in frames] == [100, 101, 102]
    assert [f.t_capture_ns for f in frames] == [0, 100_000_000, 200_000_000]  # 10 fps default
    with pytest.raises(SourceExhausted):
        source.read()


def test_folder_with_frames_csv_times_and_names(tmp_path: Path) -> None:
    rows = ["t_capture_ns,left,right", "5000,0001.png,0001.png", "9000,0000.png,0000.png"]
    source = FolderSource(make_folder(tmp_path, 2, rows), None, paced=False, loop=False)
    first, second = source.read(), source.read()
    assert (first.t_capture_ns, int(first.left[0, 0, 0])) == (5000, 1)
    assert (second.t_capture_ns, int(second.left[0, 0, 0])) == (9000, 0)


def test_folder_loops_when_asked(tmp_path: Path) -> None:
    source = FolderSource(make_folder(tmp_path, 2), None, paced=False, loop=True)
    values = [int(source.read().left[0, 0, 0]) for _ in range(5)]
    assert values == [0, 1, 0, 1, 0]


def test_folder_layout_errors(tmp_path: Path) -> None:
    folder = make_folder(tmp_path, 3)
    (folder / "right" / "0002.png").unlink()
    with pytest.raises(SourceError, match="left/ has 3 images, right/ has 2"):
        FolderSource(folder, None, paced=False, loop=False)
    with pytest.raises(SourceError, match="expected 'left/' and 'right/'"):
        FolderSource(tmp_path, None, paced=False, loop=False)
    bad_csv = make_folder(tmp_path / "b", 2, ["time,left,right", "1,0000.png,0000.png"])
    with pytest.raises(SourceError, match="t_capture_ns"):
        FolderSource(bad_csv, None, paced=False, loop=False)


def test_unreadable_image_is_a_broken_frame_and_reading_goes_on(tmp_path: Path) -> None:
    folder = make_folder(tmp_path, 3)
    # Complete (it ends as a PNG does) but not an image at all.
    (folder / "left" / "0001.png").write_bytes(b"not a png" + b"IEND\xaeB`\x82")
    source = FolderSource(folder, None, paced=False, loop=False)
    assert int(source.read().left[0, 0, 0]) == 0
    with pytest.raises(BrokenFrame, match=r"0001\.png: unreadable image"):
        source.read()
    assert int(source.read().left[0, 0, 0]) == 2


def test_side_by_side_video(tmp_path: Path) -> None:
    path = tmp_path / "sbs.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter.fourcc(*"MJPG"), 20.0, (64, 24))
    assert writer.isOpened()
    for i in range(4):
        frame = np.zeros((24, 64, 3), dtype=np.uint8)
        frame[:, :32] = 40 * i
        frame[:, 32:] = 200
        writer.write(frame)
    writer.release()
    source = open_files(path, None, paced=False, loop=False)
    assert isinstance(source, SideBySideVideoSource)
    frames = []
    with pytest.raises(SourceExhausted):
        while True:
            frames.append(source.read())
    assert len(frames) == 4
    assert frames[0].left.shape == (24, 32, 3) and frames[0].right.shape == (24, 32, 3)
    assert [round(float(f.left.mean()) / 40) for f in frames] == [0, 1, 2, 3]
    assert all(abs(float(f.right.mean()) - 200) < 3 for f in frames)
    assert frames[1].t_capture_ns - frames[0].t_capture_ns == pytest.approx(50e6, rel=0.05)
    source.close()


class FakeCamera:
    """Stands in for a V4L2 device: negotiates a mode and delivers numbered frames."""

    def __init__(self, mode: tuple[int, int, float, str], fail_after: int | None = None) -> None:
        self.width, self.height, self.fps, self.fourcc = mode
        self.fail_after = fail_after
        self.grabs = 0
        self.released = False

    def isOpened(self) -> bool:  # noqa: N802
        return True

    def set(self, prop: int, value: float) -> bool:
        return True

    def get(self, prop: int) -> float:
        if prop == cv2.CAP_PROP_FRAME_WIDTH:
            return float(self.width)
        if prop == cv2.CAP_PROP_FRAME_HEIGHT:
            return float(self.height)
        if prop == cv2.CAP_PROP_FPS:
            return self.fps
        if prop == cv2.CAP_PROP_FOURCC:
            return float(cv2.VideoWriter.fourcc(*self.fourcc))
        return 0.0

    def grab(self) -> bool:
        self.grabs += 1
        return self.fail_after is None or self.grabs <= self.fail_after

    def retrieve(self) -> tuple[bool, np.ndarray]:
        image = np.zeros((self.height, self.width, 3), dtype=np.uint8)
        image[:, : self.width // 2] = self.grabs
        image[:, self.width // 2 :] = 200
        return True, image

    def release(self) -> None:
        self.released = True


def v4l2_config(devices: list[str], fps: float = 30.0) -> V4l2SourceConfig:
    return V4l2SourceConfig(kind="v4l2", devices=devices, width=320, height=240, fps=fps)


def test_v4l2_side_by_side_splits_and_reports_mode(caplog: pytest.LogCaptureFixture) -> None:
    camera = FakeCamera((640, 240, 15.0, "YUYV"))
    with caplog.at_level(logging.WARNING):
        source = V4l2Source(v4l2_config(["7"]), "front", lambda device: camera)
    assert "runs at 15.0 fps YUYV, asked 30.0 fps MJPG" in caplog.text
    frame = source.read()
    assert frame.left.shape == (240, 320, 3) and frame.right.shape == (240, 320, 3)
    assert int(frame.left[0, 0, 0]) == 1 and int(frame.right[0, 0, 0]) == 200
    assert abs(frame.t_capture_ns - time.monotonic_ns()) < 1e9
    source.close()
    assert camera.released


def test_v4l2_wrong_size_is_an_error_that_names_the_fix() -> None:
    camera = FakeCamera((1280, 720, 30.0, "MJPG"))
    with pytest.raises(SourceError, match=r"delivers 1280x720, asked 640x240; pick a mode"):
        V4l2Source(v4l2_config(["3"]), "front", lambda device: camera)
    assert camera.released


def test_v4l2_lost_device_raises_source_error() -> None:
    cameras = [FakeCamera((320, 240, 30.0, "MJPG"), fail_after=2) for _ in range(2)]
    source = V4l2Source(v4l2_config(["1", "2"]), "front", lambda device: cameras[int(device) - 1])
    source.read()
    source.read()
    with pytest.raises(SourceError, match="no frame"):
        source.read()


def test_v4l2_missing_device_names_it(tmp_path: Path) -> None:
    with pytest.raises(SourceError, match=r"/dev/video-absent does not exist; is it plugged in"):
        V4l2Source(v4l2_config(["/dev/video-absent"]), "front")


def synthetic_config(**overrides: object) -> SyntheticSourceConfig:
    base: dict[str, object] = {
        "kind": "synthetic",
        "fps": 10,
        "seed": 4,
        "obstacles": [
            SyntheticObstacleConfig(shape="box", forward_m=5.0, right_m=0.0, width_m=1.0),
        ],
    }
    base.update(overrides)
    return SyntheticSourceConfig.model_validate(base)


def test_synthetic_static_scene_is_reproducible_with_fresh_noise() -> None:
    a = SyntheticSource(synthetic_config(), RIG, paced=False)
    b = SyntheticSource(synthetic_config(), RIG, paced=False)
    fa, fb = a.read(), b.read()
    assert np.array_equal(fa.left, fb.left)
    second = a.read()
    assert second.seq == 1 and second.t_capture_ns == 100_000_000
    assert not np.array_equal(fa.left, second.left)  # the sensor noise changes
    assert np.abs(fa.left.astype(int) - second.left.astype(int)).mean() < 4
    assert fa.truth is not None
    nearest = nearest_obstacle(fa.truth, Mount(), FramePose(0.0, 0.0, 1.5))
    assert nearest is not None
    assert nearest.distance_m == pytest.approx(4.5, abs=0.02)
    assert abs(nearest.bearing_deg) < 1.0


def test_synthetic_obstacles_approach_and_loop() -> None:
    config = synthetic_config(approach_speed_mps=2.0, min_forward_m=2.0)
    distances = []
    source = SyntheticSource(config, RIG, paced=False)
    for _ in range(14):
        frame = source.read()
        assert frame.truth is not None
        nearest = nearest_obstacle(frame.truth, Mount(), FramePose(0.0, 0.0, 1.5))
        assert nearest is not None
        distances.append(nearest.distance_m)
    # 2 m/s at 10 fps: 0.2 m per frame until the box front reaches 2 m, then it starts over.
    assert distances[1] == pytest.approx(distances[0] - 0.2, abs=0.02)
    assert min(distances) == pytest.approx(2.1, abs=0.15)
    assert distances[13] > 4.0
    assert scene_at(config, 0.0).obstacles == scene_at(config, 1.25).obstacles


def test_synthetic_truth_follows_the_mount() -> None:
    frame = SyntheticSource(synthetic_config(), RIG, paced=False).read()
    assert frame.truth is not None
    nearest = nearest_obstacle(
        frame.truth, Mount(yaw_deg=90.0, position_m=(0.0, 0.2, 0.0)), FramePose(0.0, 0.0, 1.5)
    )
    assert nearest is not None
    assert nearest.bearing_deg == pytest.approx(90.0, abs=1.5)
    assert nearest.distance_m == pytest.approx(4.7, abs=0.03)


def test_pacer_spaces_frames_and_does_not_burst_after_a_stall(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """On a fake clock (sleeping advances it): slots 20 ms apart; after a stall of five
    periods the next frame comes at once and the ones after it 20 ms apart again, with no
    burst of frames to catch up."""
    clock = [1_000_000_000]

    def sleep(seconds: float) -> None:
        clock[0] += round(seconds * 1e9)

    fake = SimpleNamespace(monotonic_ns=lambda: clock[0], sleep=sleep)
    monkeypatch.setattr("avoidd.sources.base.time", fake)
    pacer = Pacer(50.0)
    stamps = [pacer.wait() for _ in range(5)]
    assert list(np.diff(stamps)) == [20_000_000] * 4
    clock[0] += 100_000_000  # a stall of five periods
    stalled_at = clock[0]
    after = [pacer.wait() for _ in range(3)]
    assert after[0] == stalled_at
    assert list(np.diff(after)) == [20_000_000] * 2


@pytest.mark.parametrize(("render_ms", "warned"), [(12.0, True), (3.0, False)])
def test_paced_moving_scene_says_when_it_cannot_keep_up(
    monkeypatch: pytest.MonkeyPatch,
    caplog: pytest.LogCaptureFixture,
    render_ms: float,
    warned: bool,
) -> None:
    """At 200 fps a frame has 5 ms: a renderer made to take 12 ms is reported (once), one
    that takes 3 ms is not. The source reads a fake clock that only the renderer advances."""
    clock = [0.0]

    def render(scene: Any, rig: RectifiedRig) -> Any:
        clock[0] += render_ms / 1000.0
        return render_pair(scene, rig)

    monkeypatch.setattr(synthetic, "render_pair", render)
    monkeypatch.setattr(synthetic, "time", SimpleNamespace(perf_counter=lambda: clock[0]))
    config = synthetic_config(approach_speed_mps=1.0, fps=200)
    source = SyntheticSource(config, RectifiedRig(320, 240, 200.0, 200.0, 159.5, 119.5, 0.12), True)
    with caplog.at_level(logging.WARNING):
        source.read()
        source.read()
    warnings = [r.getMessage() for r in caplog.records if "moving scene" in r.getMessage()]
    assert clock[0] == pytest.approx(2 * render_ms / 1000.0)  # both frames were rendered
    if not warned:
        assert warnings == []
        return
    assert len(warnings) == 1
    assert "takes 12 ms per frame" in warnings[0]
    assert "about 83.3 fps, not 200.0; lower fps or the resolution, or use replay" in warnings[0]


def test_frames_csv_carries_the_recorded_attitude_and_height(tmp_path: Path) -> None:
    rows = [
        "t_capture_ns,roll_deg,pitch_deg,height_m",
        "1000,12.5,-3.0,2.25",
        "2000,-4.0,7.5,1.75",
    ]
    source = FolderSource(make_folder(tmp_path, 2, rows), None, paced=False, loop=False)
    first, second = source.read(), source.read()
    assert first.pose == FramePose(12.5, -3.0, 2.25, "recording", "recording")
    assert second.pose == FramePose(-4.0, 7.5, 1.75, "recording", "recording")
    # Attitude without height: the height is left to the rangefinder or the config.
    rows = ["t_capture_ns,roll_deg,pitch_deg", "1000,1.0,2.0"]
    pose = FolderSource(make_folder(tmp_path / "b", 1, rows), None, False, False).read().pose
    assert pose is not None and (pose.roll_deg, pose.pitch_deg) == (1.0, 2.0)
    assert pose.height_source == "none"


@pytest.mark.parametrize(
    ("rows", "message"),
    [
        (["t_capture_ns,roll_deg", "1,2.0"], "give both or neither"),
        (["t_capture_ns,height_m", "1,2.0"], "needs roll_deg and pitch_deg"),
        (["t_capture_ns,roll_deg,pitch_deg", "1,abc,2"], r"frames.csv:2: roll_deg is not a number"),
        (["t_capture_ns,roll_deg,pitch_deg", "1,1,nan"], "pitch_deg is not finite"),
        (["t_capture_ns,roll_deg,pitch_deg", "1,1,120"], r"within \+-90 degrees"),
    ],
)
def test_frames_csv_attitude_errors_name_the_row_and_the_fix(
    tmp_path: Path, rows: list[str], message: str
) -> None:
    with pytest.raises(SourceError, match=message):
        FolderSource(make_folder(tmp_path, 1, rows), None, paced=False, loop=False)


def test_frames_csv_heading_and_position_columns_are_optional_and_may_be_empty(
    tmp_path: Path,
) -> None:
    rows = [
        "t_capture_ns,left,right,roll_deg,pitch_deg,height_m,yaw_deg,north_m,east_m,down_m,"
        "attitude_source,height_source,seq",
        "1000,0000.png,0000.png,1.0,2.0,1.5,190.0,3.5,-2.25,-1.5,mavlink,rangefinder,7",
        "2000,0001.png,0001.png,1.0,2.0,1.5,,,,,config,config,8",
    ]
    source = FolderSource(make_folder(tmp_path, 2, rows), None, paced=False, loop=False)
    first, second = source.read(), source.read()
    assert first.pose == FramePose(1.0, 2.0, 1.5, "recording", "recording")
    assert first.vehicle is not None
    assert first.vehicle == pytest.approx((-170.0, 3.5, -2.25, -1.5))  # yaw wrapped
    assert second.vehicle is not None and all(np.isnan(v) for v in second.vehicle)
    # An older file without them still loads, without vehicle data.
    rows = ["t_capture_ns,roll_deg,pitch_deg", "1000,1.0,2.0"]
    frame = FolderSource(make_folder(tmp_path / "b", 1, rows), None, False, False).read()
    assert frame.vehicle is None


@pytest.mark.parametrize(
    ("cell", "message"),
    [("abc", r"frames.csv:2: north_m is not a number"), ("inf", "north_m is not finite")],
)
def test_frames_csv_position_errors_name_the_row(tmp_path: Path, cell: str, message: str) -> None:
    rows = ["t_capture_ns,north_m", f"1,{cell}"]
    with pytest.raises(SourceError, match=message):
        FolderSource(make_folder(tmp_path, 1, rows), None, paced=False, loop=False)


@pytest.mark.parametrize("suffix", [".png", ".jpg"])
def test_a_truncated_image_is_dropped_before_the_codec_prints_anything(
    tmp_path: Path, suffix: str, capfd: pytest.CaptureFixture[str]
) -> None:
    rng = np.random.default_rng(4)
    for side in ("left", "right"):
        (tmp_path / side).mkdir()
        for index in range(3):
            image = rng.integers(0, 255, (48, 64), dtype=np.uint8)
            cv2.imwrite(str(tmp_path / side / f"{index:03d}{suffix}"), image)
    cut = tmp_path / "left" / f"001{suffix}"
    whole = cut.read_bytes()
    cut.write_bytes(whole[: len(whole) // 2])
    source = open_files(tmp_path, None, paced=False, loop=False)
    assert source.read().seq == 0
    with pytest.raises(BrokenFrame, match=r"001.*truncated image"):
        source.read()
    assert source.read().seq == 2  # the next pair reads on
    # libpng and libjpeg write to the process's stderr themselves: nothing reached it.
    captured = capfd.readouterr()
    assert "libpng" not in captured.err and "JPEG" not in captured.err, captured.err
