"""``avoidd cameras``: the V4L2 enumeration decoded from a kernel's answers, and the command on a
machine with no camera (this one) and with a node that is no camera."""

from __future__ import annotations

import errno
import struct
from pathlib import Path
from typing import ClassVar

import pytest

from avoidd.cli import main
from avoidd.commands.cameras import format_camera, snippet
from avoidd.sources import v4l2_probe as v4l2


def _code(fourcc: str) -> int:
    return int.from_bytes(fourcc.encode(), "little")


class FakeKernel:
    """The answers a UVC stereo camera's driver gives, laid out as linux/videodev2.h has them
    (the camera hardware is the edge of the world here: there is none on this machine)."""

    FORMATS: ClassVar = [("MJPG", "Motion-JPEG"), ("YUYV", "YUYV 4:2:2")]
    SIZES: ClassVar = {"MJPG": [(2560, 720), (1280, 480)], "YUYV": [(640, 480)]}
    RATES: ClassVar = {
        (2560, 720): [(1, 30)],
        (1280, 480): [(1, 60), (1, 30)],
        (640, 480): [(1, 15)],
    }

    def __init__(self, capture: bool = True) -> None:
        self.capture = capture

    def __call__(self, request: int, buffer: bytearray) -> None:
        if request == v4l2.QUERYCAP:
            caps = 0x1 if self.capture else 0x00800000  # capture, or a metadata node
            struct.pack_into(
                "16s32s32sIII",
                buffer,
                0,
                b"uvcvideo",
                b"USB Stereo",
                b"usb-0000:00:14.0-1",
                0x60000,
                caps | 0x80000000,
                caps,
            )
            return
        index = struct.unpack_from("I", buffer, 0)[0]
        if request == v4l2.ENUM_FMT:
            if index >= len(self.FORMATS):
                raise OSError(errno.EINVAL, "no more")
            fourcc, description = self.FORMATS[index]
            struct.pack_into("I", buffer, 8, 0)
            struct.pack_into("32sI", buffer, 12, description.encode(), _code(fourcc))
        elif request == v4l2.ENUM_FRAMESIZES:
            pixel = struct.unpack_from("I", buffer, 4)[0]
            sizes = self.SIZES[pixel.to_bytes(4, "little").decode()]
            if index >= len(sizes):
                raise OSError(errno.EINVAL, "no more")
            struct.pack_into("III", buffer, 8, 1, *sizes[index])  # discrete
        elif request == v4l2.ENUM_FRAMEINTERVALS:
            width, height = struct.unpack_from("II", buffer, 8)
            rates = self.RATES[(width, height)]
            if index >= len(rates):
                raise OSError(errno.EINVAL, "no more")
            struct.pack_into("III", buffer, 16, 1, *rates[index])
        else:
            raise OSError(errno.ENOTTY, "not a V4L2 request")


def test_the_requests_are_the_kernels_numbers() -> None:
    # linux/videodev2.h: _IOR('V', 0, 104), _IOWR('V', 2, 64), _IOWR('V', 74, 44), (75, 52).
    assert (v4l2.QUERYCAP, v4l2.ENUM_FMT) == (0x80685600, 0xC0405602)
    assert (v4l2.ENUM_FRAMESIZES, v4l2.ENUM_FRAMEINTERVALS) == (0xC02C564A, 0xC034564B)


def test_a_stereo_cameras_formats_sizes_and_rates_are_decoded() -> None:
    camera = v4l2.describe(FakeKernel(), "/dev/video0")
    assert camera is not None
    assert (camera.card, camera.driver, camera.bus) == (
        "USB Stereo",
        "uvcvideo",
        "usb-0000:00:14.0-1",
    )
    assert [(f.fourcc, f.description) for f in camera.formats] == FakeKernel.FORMATS
    mjpg = camera.formats[0]
    assert [(s.width, s.height, s.fps) for s in mjpg.sizes] == [
        (2560, 720, (30.0,)),
        (1280, 480, (60.0, 30.0)),
    ]
    assert v4l2.describe(FakeKernel(capture=False), "/dev/video1") is None  # metadata node


def test_the_snippet_asks_for_the_side_by_side_frame_nearest_640_per_eye() -> None:
    camera = v4l2.describe(FakeKernel(), "/dev/video0")
    assert camera is not None
    text = snippet(camera)
    assert "kind: v4l2" in text and "devices: [/dev/video0]" in text
    assert "width: 640" in text and "height: 480" in text  # one eye of 1280x480
    assert "fps: 30" in text and "fourcc: MJPG" in text
    assert "side-by-side" in text
    listed = format_camera(camera)
    assert "MJPG (Motion-JPEG): 2560x720@30, 1280x480@60/30" in listed
    assert "YUYV (YUYV 4:2:2): 640x480@15" in listed


def test_nothing_found_on_a_machine_without_cameras(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["cameras", "--dev", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f"nothing found: no V4L2 camera under {tmp_path}")


def test_a_node_that_is_no_camera_is_listed_with_the_reason(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "video0").write_bytes(b"")  # opens, but answers no V4L2 request
    assert main(["cameras", "--dev", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert f"{tmp_path / 'video0'}: ?" in out
    assert "cannot be read: Inappropriate ioctl for device" in out
