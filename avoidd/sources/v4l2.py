"""Live stereo cameras through V4L2: two devices, or one device delivering side-by-side frames."""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable
from typing import Protocol

import cv2
import numpy as np

from avoidd.config import V4l2SourceConfig
from avoidd.errors import BrokenFrame, SourceError
from avoidd.types import Image, StereoFrame

logger = logging.getLogger(__name__)


class Capture(Protocol):
    """The part of ``cv2.VideoCapture`` the source uses (so tests can stand in for hardware)."""

    def isOpened(self) -> bool:  # noqa: N802 - OpenCV's name
        """Whether the device opened."""
        ...

    def set(self, prop: int, value: float) -> bool:
        """Request a property."""
        ...

    def get(self, prop: int) -> float:
        """Read a property back."""
        ...

    def grab(self) -> bool:
        """Latch the next frame."""
        ...

    def retrieve(self) -> tuple[bool, np.ndarray | None]:
        """Decode the latched frame."""
        ...

    def release(self) -> None:
        """Close the device."""
        ...


CaptureFactory = Callable[[str], Capture]


def open_v4l2_capture(device: str) -> Capture:
    """Open a V4L2 device with OpenCV (``/dev/videoN`` or an index)."""
    target: int | str = int(device) if device.isdigit() else device
    capture: Capture = cv2.VideoCapture(target, cv2.CAP_V4L2)
    return capture


def _fourcc_text(value: float) -> str:
    code = int(value)
    return "".join(chr((code >> (8 * i)) & 0xFF) for i in range(4)).strip("\x00") or "?"


class V4l2Source:
    """Stereo frames from one side-by-side or two separate V4L2 devices.

    The requested size, rate and FOURCC are checked after opening: a different rate or FOURCC
    is logged, a different size is an error (the calibration would not fit).

    Args:
        config: The v4l2 source configuration (``width``/``height`` are per eye).
        name: The head's name, for messages.
        capture_factory: Opens one device; tests pass a fake camera here.

    Raises:
        SourceError: A device cannot be opened or delivers the wrong size.
    """

    def __init__(
        self,
        config: V4l2SourceConfig,
        name: str,
        capture_factory: CaptureFactory = open_v4l2_capture,
    ) -> None:
        self._config = config
        self._name = name
        self._side_by_side = len(config.devices) == 1
        self._captures: list[Capture] = []
        self._seq = 0
        try:
            for device in config.devices:
                self._captures.append(self._open(device, capture_factory))
        except SourceError:
            self.close()
            raise

    @property
    def description(self) -> str:
        """What the source reads, for logs and errors."""
        layout = "side-by-side" if self._side_by_side else "left/right"
        return f"camera '{self._name}' ({layout} {', '.join(self._config.devices)})"

    def _open(self, device: str, factory: CaptureFactory) -> Capture:
        if device.startswith("/dev/"):
            if not os.path.exists(device):
                raise SourceError(
                    f"camera '{self._name}': {device} does not exist; is it plugged in?"
                )
            if not os.access(device, os.R_OK | os.W_OK):
                raise SourceError(
                    f"camera '{self._name}': {device} not readable; is the user in group 'video'?"
                )
        capture = factory(device)
        if not capture.isOpened():
            capture.release()
            raise SourceError(f"camera '{self._name}': cannot open {device} with V4L2")
        cfg = self._config
        width = cfg.width * (2 if self._side_by_side else 1)
        if cfg.fourcc is not None:
            capture.set(cv2.CAP_PROP_FOURCC, float(cv2.VideoWriter.fourcc(*cfg.fourcc)))
        capture.set(cv2.CAP_PROP_FRAME_WIDTH, float(width))
        capture.set(cv2.CAP_PROP_FRAME_HEIGHT, float(cfg.height))
        capture.set(cv2.CAP_PROP_FPS, float(cfg.fps))
        got_w = int(capture.get(cv2.CAP_PROP_FRAME_WIDTH))
        got_h = int(capture.get(cv2.CAP_PROP_FRAME_HEIGHT))
        got_fps = float(capture.get(cv2.CAP_PROP_FPS))
        got_fourcc = _fourcc_text(capture.get(cv2.CAP_PROP_FOURCC))
        if (got_w, got_h) != (width, cfg.height):
            capture.release()
            raise SourceError(
                f"camera '{self._name}': {device} delivers {got_w}x{got_h}, asked {width}x"
                f"{cfg.height}; pick a mode the camera lists (v4l2-ctl --list-formats-ext)"
            )
        if abs(got_fps - cfg.fps) > 0.5 or (cfg.fourcc is not None and got_fourcc != cfg.fourcc):
            logger.warning(
                "camera '%s': %s runs at %.1f fps %s, asked %.1f fps %s",
                self._name,
                device,
                got_fps,
                got_fourcc,
                cfg.fps,
                cfg.fourcc or "(any)",
            )
        logger.info("camera '%s': opened %s at %dx%d", self._name, device, got_w, got_h)
        return capture

    def read(self) -> StereoFrame:
        """Grab both views as close together as the driver allows and decode them."""
        if not all(capture.grab() for capture in self._captures):
            raise SourceError(f"{self.description}: no frame (device lost?)")
        t_capture_ns = time.monotonic_ns()
        self._check_sync(self._seq)
        images: list[Image] = []
        for side, capture in zip(("left", "right"), self._captures, strict=False):
            ok, image = capture.retrieve()
            if not ok or image is None:
                what = "frame" if self._side_by_side else f"{side} view"
                raise BrokenFrame(f"{self.description}: {what} could not be decoded")
            # Never converted here: a 16-bit or odd format is refused by the head, not wrapped.
            images.append(np.asarray(image))
        seq = self._seq
        self._seq += 1
        if self._side_by_side:
            half = images[0].shape[1] // 2
            left = np.ascontiguousarray(images[0][:, :half])
            right = np.ascontiguousarray(images[0][:, half:])
            return StereoFrame(seq, t_capture_ns, left, right)
        return StereoFrame(seq, t_capture_ns, images[0], images[1])

    def _check_sync(self, seq: int) -> None:
        """Refuse two views the drivers stamped more than half a frame period apart.

        Two free-running cameras drift in phase; a pair taken at different instants on a
        moving vehicle gives wrong disparities, so it is dropped rather than measured.

        Raises:
            BrokenFrame: The views are out of sync.
        """
        if len(self._captures) != 2:
            return
        stamps_ms = [capture.get(cv2.CAP_PROP_POS_MSEC) for capture in self._captures]
        if min(stamps_ms) <= 0:
            return  # the driver gives no buffer timestamps
        apart_ms = abs(stamps_ms[0] - stamps_ms[1])
        limit_ms = 500.0 / self._config.fps
        if apart_ms > limit_ms:
            raise BrokenFrame(
                f"{self.description}: left and right taken {apart_ms:.0f} ms apart (more than "
                f"half a frame at {self._config.fps:g} fps); frame {seq} dropped; are the "
                "cameras synchronised?"
            )

    def close(self) -> None:
        """Release the devices."""
        for capture in self._captures:
            capture.release()
        self._captures = []
