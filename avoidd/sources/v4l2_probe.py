"""What V4L2 cameras are attached: each capture node with its formats, sizes and frame rates.

Asked of the kernel directly (the ``VIDIOC_QUERYCAP``, ``VIDIOC_ENUM_FMT``,
``VIDIOC_ENUM_FRAMESIZES`` and ``VIDIOC_ENUM_FRAMEINTERVALS`` ioctls, the structures laid out as
in ``linux/videodev2.h``), so nothing beyond the standard library is needed. A node that is
no capture device (a UVC camera's metadata node) is left out; a node that cannot be opened
(busy, no permission) is listed with the reason.
"""

from __future__ import annotations

import errno
import fcntl
import glob
import os
import struct
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any


def _iowr(number: int, size: int, read_only: bool = False) -> int:
    """The ioctl request of ``_IOR``/``_IOWR('V', number, size)``."""
    direction = 2 if read_only else 3
    return (direction << 30) | (size << 16) | (ord("V") << 8) | number


_CAPABILITY = struct.Struct("16s32s32sIII12x")  # struct v4l2_capability, 104 bytes
_FMTDESC = struct.Struct("III32sII12x")  # struct v4l2_fmtdesc, 64 bytes
_FRMSIZE = struct.Struct("III6I8x")  # struct v4l2_frmsizeenum, 44 bytes
_FRMIVAL = struct.Struct("IIIII6I8x")  # struct v4l2_frmivalenum, 52 bytes
QUERYCAP = _iowr(0, _CAPABILITY.size, read_only=True)
ENUM_FMT = _iowr(2, _FMTDESC.size)
ENUM_FRAMESIZES = _iowr(74, _FRMSIZE.size)
ENUM_FRAMEINTERVALS = _iowr(75, _FRMIVAL.size)
_CAPTURE = 0x1  # V4L2_CAP_VIDEO_CAPTURE
_DEVICE_CAPS = 0x80000000  # V4L2_CAP_DEVICE_CAPS: device_caps is filled in
_BUF_CAPTURE = 1  # V4L2_BUF_TYPE_VIDEO_CAPTURE
_DISCRETE = 1
_MOST = 64
"""At most this many entries of any one enumeration (a driver that never says "no more")."""

Ioctl = Callable[[int, bytearray], None]
"""``fcntl.ioctl`` on an open descriptor, the buffer changed in place; OSError(EINVAL) ends an
enumeration."""


@dataclass(frozen=True)
class FrameSize:
    """One size a format offers, with its frame rates (frames per second, fastest first)."""

    width: int
    height: int
    fps: tuple[float, ...]


@dataclass(frozen=True)
class PixelFormat:
    """One pixel format (FOURCC) and its sizes."""

    fourcc: str
    description: str
    sizes: tuple[FrameSize, ...]


@dataclass(frozen=True)
class Camera:
    """One V4L2 capture node."""

    path: str
    card: str
    driver: str
    bus: str
    formats: tuple[PixelFormat, ...] = ()
    by_id: str | None = None
    error: str | None = None


def _text(raw: bytes) -> str:
    return raw.split(b"\0", 1)[0].decode("utf-8", "replace")


def _fourcc(code: int) -> str:
    return "".join(chr((code >> (8 * k)) & 0xFF) for k in range(4)).strip()


def _enumerate(
    ioctl: Ioctl, request: int, layout: struct.Struct, head: tuple[int, ...]
) -> Iterator[tuple[Any, ...]]:
    """Every entry of one enumeration, unpacked, until the driver says EINVAL."""
    for index in range(_MOST):
        buffer = bytearray(layout.size)
        struct.pack_into(f"{len(head) + 1}I", buffer, 0, index, *head)
        try:
            ioctl(request, buffer)
        except OSError as exc:
            if exc.errno == errno.EINVAL:
                return
            raise
        yield layout.unpack(bytes(buffer))


def describe(ioctl: Ioctl, path: str) -> Camera | None:
    """The node's formats, sizes and rates; None when it is no capture device."""
    buffer = bytearray(_CAPABILITY.size)
    ioctl(QUERYCAP, buffer)
    driver, card, bus, _version, capabilities, device_caps = _CAPABILITY.unpack(bytes(buffer))
    caps = device_caps if capabilities & _DEVICE_CAPS else capabilities
    if not caps & _CAPTURE:
        return None
    formats = []
    for _, _, _, description, pixel, _ in _enumerate(ioctl, ENUM_FMT, _FMTDESC, (_BUF_CAPTURE,)):
        sizes = []
        for entry in _enumerate(ioctl, ENUM_FRAMESIZES, _FRMSIZE, (pixel,)):
            kind, values = entry[2], entry[3:]
            if kind == _DISCRETE:
                dims = [(values[0], values[1])]
            else:  # stepwise or continuous: its smallest and largest
                dims = [(values[0], values[3]), (values[1], values[4])]
            for width, height in dims:
                sizes.append(FrameSize(width, height, _rates(ioctl, pixel, width, height)))
        formats.append(PixelFormat(_fourcc(pixel), _text(description), tuple(sizes)))
    return Camera(path, _text(card), _text(driver), _text(bus), tuple(formats))


def _rates(ioctl: Ioctl, pixel: int, width: int, height: int) -> tuple[float, ...]:
    rates: set[float] = set()
    for entry in _enumerate(ioctl, ENUM_FRAMEINTERVALS, _FRMIVAL, (pixel, width, height)):
        kind, values = entry[4], entry[5:]
        fractions = [values[0:2]] if kind == _DISCRETE else [values[0:2], values[2:4]]
        for numerator, denominator in fractions:
            if numerator > 0:
                rates.add(round(denominator / numerator, 2))
    return tuple(sorted(rates, reverse=True))


def stable_names(dev: str = "/dev") -> dict[str, str]:
    """``/dev/videoN`` -> its ``/dev/v4l/by-id`` name (stable across reboots), where one exists."""
    names = {}
    for link in sorted(glob.glob(os.path.join(dev, "v4l", "by-id", "*"))):
        names[os.path.realpath(link)] = link
    return names


def probe(dev: str = "/dev") -> list[Camera]:
    """Every V4L2 capture node under ``dev`` (empty: none attached)."""
    by_id = stable_names(dev)
    cameras = []
    for path in sorted(glob.glob(os.path.join(dev, "video*")), key=_node_number):
        try:
            fd = os.open(path, os.O_RDWR | os.O_NONBLOCK)
        except OSError as exc:
            cameras.append(Camera(path, "?", "?", "?", error=exc.strerror or str(exc)))
            continue
        try:

            def ioctl(request: int, buffer: bytearray, fd: int = fd) -> None:
                fcntl.ioctl(fd, request, buffer)

            camera = describe(ioctl, path)
        except OSError as exc:
            camera = Camera(path, "?", "?", "?", error=exc.strerror or str(exc))
        finally:
            os.close(fd)
        if camera is not None:
            cameras.append(_with_id(camera, by_id.get(os.path.realpath(path))))
    return cameras


def _with_id(camera: Camera, by_id: str | None) -> Camera:
    return Camera(
        camera.path, camera.card, camera.driver, camera.bus, camera.formats, by_id, camera.error
    )


def _node_number(path: str) -> int:
    digits = "".join(c for c in os.path.basename(path) if c.isdigit())
    return int(digits) if digits else 0
