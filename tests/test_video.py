"""The debug view's video: the frame's layout, its settings, and the stream a ground station
opens, received and decoded by FFmpeg (PyAV) from the daemon over real loopback UDP."""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from avoidd.config import DebugServerConfig
from avoidd.debugview import render
from avoidd.debugview.video import VideoEncoder, compose, sdp_text
from tests.helpers import free_udp_port
from tests.test_debug_view import running

av = pytest.importorskip("av", reason="PyAV is in the test extra: pip install -e '.[test]'")


def test_the_frame_puts_the_polar_plot_left_and_the_heads_stacked_right() -> None:
    polar = np.full((480, 480, 3), 200, dtype=np.uint8)
    heads = [np.full((240, 640, 3), 60 * (k + 1), dtype=np.uint8) for k in range(2)]
    frame = compose(polar, heads, 1280, 720)
    assert frame.shape == (720, 1280, 3)
    assert (frame[40:680, :640] == 200).all()  # 480 px scaled to 640 x 640, centred in 720
    assert (frame[:40, :640] == 0).all() and (frame[680:, :640] == 0).all()
    top, bottom = frame[60:300, 640:], frame[420:660, 640:]
    assert (top == 60).all() and (bottom == 120).all()  # each head in its half, centred
    assert (frame[:60, 640:] == 0).all() and (frame[300:420, 640:] == 0).all()
    grey = np.full((100, 100), 90, dtype=np.uint8)
    assert compose(None, [grey], 320, 240)[120, 160].tolist() == [90, 90, 90]


@pytest.mark.parametrize(
    ("video", "says"),
    [
        ({"enabled": True, "host": "192.168.1.5"}, "not a loopback address"),
        ({"host": "10.0.0.2"}, "allow_remote: true"),
        ({"width_px": 641}, "multiple of 2"),
    ],
)
def test_bad_video_settings_name_the_remedy(video: dict[str, Any], says: str) -> None:
    with pytest.raises(ValueError, match=says):
        DebugServerConfig.model_validate({"enabled": True, "video": video})


def test_the_video_needs_the_debug_view() -> None:
    with pytest.raises(ValueError, match=r"debug_server\.enabled: true"):
        DebugServerConfig.model_validate({"video": {"enabled": True}})
    remote = DebugServerConfig.model_validate(
        {"enabled": True, "video": {"enabled": True, "host": "10.0.0.2", "allow_remote": True}}
    )
    assert remote.video.host == "10.0.0.2" and remote.video.port == 5600


class Receiver:
    """FFmpeg reading the stream from its SDP description, as VLC or a GStreamer player would."""

    def __init__(self, sdp: Path, want: int) -> None:
        self.frames: list[np.ndarray] = []
        self.error: BaseException | None = None
        self._want = want
        self._sdp = sdp
        self.thread = threading.Thread(target=self._read, daemon=True)
        self.thread.start()

    def _read(self) -> None:
        try:
            container = av.open(
                str(self._sdp),
                format="sdp",
                options={"protocol_whitelist": "file,udp,rtp", "reorder_queue_size": "0"},
                timeout=(20.0, 10.0),
            )
            try:
                for frame in container.decode(video=0):
                    self.frames.append(frame.to_ndarray(format="bgr24"))
                    if len(self.frames) >= self._want:
                        break
            finally:
                container.close()
        except BaseException as exc:  # reported by the test
            self.error = exc


def test_an_encoded_picture_arrives_decodable_and_alike(tmp_path: Path) -> None:
    from avoidd.config.debug_server import VideoConfig

    port = free_udp_port()
    sdp = tmp_path / "stream.sdp"
    sdp.write_text(sdp_text("127.0.0.1", port))
    receiver = Receiver(sdp, want=5)
    time.sleep(0.5)  # FFmpeg has bound the port
    encoder = VideoEncoder(VideoConfig(port=port, width_px=640, height_px=360, fps=10))
    picture = np.zeros((360, 640, 3), dtype=np.uint8)
    picture[:, :320] = (40, 160, 220)  # left half one colour, a white box on the right
    picture[100:260, 400:560] = 255
    deadline = time.monotonic() + 30.0
    while receiver.thread.is_alive() and time.monotonic() < deadline:
        encoder.send(picture)
        time.sleep(0.1)
    encoder.close()
    receiver.thread.join(5.0)
    assert receiver.error is None, receiver.error
    assert len(receiver.frames) >= 5
    got = receiver.frames[-1]
    assert got.shape == (360, 640, 3)
    assert np.abs(got.astype(int) - picture.astype(int)).mean() < 8.0


def test_the_daemon_sends_its_debug_picture_to_a_ground_station_port(tmp_path: Path) -> None:
    port = free_udp_port()
    sdp = tmp_path / "avoidd.sdp"
    sdp.write_text(sdp_text("127.0.0.1", port))
    receiver = Receiver(sdp, want=10)
    time.sleep(0.5)
    video = {"enabled": True, "port": port, "fps": 10, "sdp_path": str(tmp_path / "written.sdp")}
    with running(tmp_path, video=video):
        receiver.thread.join(40.0)
    assert receiver.error is None, receiver.error
    assert len(receiver.frames) >= 10
    frame = receiver.frames[-1]
    assert frame.shape == (720, 1280, 3)
    # The polar plot on the left: its grey of unknown bins (no head looks back).
    assert _share(frame[:, :640], render.UNKNOWN_BGR) > 0.05
    # The head's left view and depth on the right: not black.
    assert frame[:, 640:].std() > 20.0
    assert (tmp_path / "written.sdp").read_text() == sdp.read_text()


def _share(image: np.ndarray, bgr: tuple[int, int, int], tolerance: int = 30) -> float:
    close = np.all(np.abs(image.astype(np.int16) - np.array(bgr)) <= tolerance, axis=2)
    return float(close.mean())
