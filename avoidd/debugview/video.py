"""The debug view's picture as H.264 over RTP/UDP: what a ground station's video widget shows.

One frame every ``1 / fps``: the polar plot of the scan as sent (with the planner's arrows and
state) on the left, the heads' pictures stacked on the right, letterboxed into the configured
size. PyAV (FFmpeg's libx264 and RTP muxer) encodes and sends it: low-latency settings, the
stream's parameter sets repeated before every key frame and a key frame every second, so a
ground station that opens it late shows a picture within a second. The state is taken on the
event loop and drawn and encoded in a thread of the stream's own.
"""

from __future__ import annotations

import asyncio
import functools
import logging
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from avoidd.config.debug_server import VideoConfig
from avoidd.types import Image

logger = logging.getLogger(__name__)

PAYLOAD_TYPE = 96
"""The RTP payload type of the H.264 stream (the dynamic type QGroundControl expects)."""


def compose(polar: Image | None, heads: Sequence[Image], width_px: int, height_px: int) -> Image:
    """The video frame: the polar plot left, the heads stacked right, on black.

    Each picture keeps its aspect ratio; the polar plot takes at most half the width.
    """
    frame = np.zeros((height_px, width_px, 3), dtype=np.uint8)
    left_px = 0
    if polar is not None:
        left_px = _paste(frame, _colour(polar), 0, 0, width_px // 2, height_px)
    if heads:
        slot_px = height_px // len(heads)
        for k, picture in enumerate(heads):
            _paste(frame, _colour(picture), left_px, k * slot_px, width_px - left_px, slot_px)
    return frame


def _colour(image: Image) -> Image:
    if image.ndim == 2:
        return np.asarray(cv2.cvtColor(image, cv2.COLOR_GRAY2BGR), dtype=np.uint8)
    return image


def _paste(frame: Image, image: Image, left: int, top: int, width: int, height: int) -> int:
    """Scale ``image`` into the box (aspect kept, centred vertically); the width it took."""
    scale = min(width / image.shape[1], height / image.shape[0])
    size = (max(int(image.shape[1] * scale), 1), max(int(image.shape[0] * scale), 1))
    scaled = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
    y = top + (height - size[1]) // 2
    frame[y : y + size[1], left : left + size[0]] = scaled
    return size[0]


def sdp_text(host: str, port: int) -> str:
    """The SDP description a player (VLC, ffplay, Mission Planner's GStreamer) opens."""
    family = "IP6" if ":" in host else "IP4"
    return (
        "v=0\r\n"
        f"o=- 0 0 IN {family} {host}\r\n"
        "s=avoidd debug view\r\n"
        f"c=IN {family} {host}\r\n"
        "t=0 0\r\n"
        f"m=video {port} RTP/AVP {PAYLOAD_TYPE}\r\n"
        f"a=rtpmap:{PAYLOAD_TYPE} H264/90000\r\n"
        f"a=fmtp:{PAYLOAD_TYPE} packetization-mode=1\r\n"
    )


class VideoEncoder:
    """H.264 frames to an RTP/UDP destination (PyAV).

    Args:
        config: The ``debug_server.video`` section.
    """

    def __init__(self, config: VideoConfig) -> None:
        import av

        self.config = config
        host = f"[{config.host}]" if ":" in config.host else config.host
        # Datagrams of at most 1200 bytes: one per packet on any link a ground station uses.
        self._container: Any = av.open(
            f"rtp://{host}:{config.port}?pkt_size=1200", mode="w", format="rtp"
        )
        rate = round(config.fps)
        stream: Any = self._container.add_stream(
            "libx264",
            rate=rate,
            options={
                "preset": "ultrafast",
                "tune": "zerolatency",
                "x264-params": f"keyint={rate}:min-keyint={rate}:repeat-headers=1",
            },
        )
        stream.width, stream.height = config.width_px, config.height_px
        stream.pix_fmt = "yuv420p"
        stream.bit_rate = config.bitrate_kbps * 1000
        self._stream = stream
        self._av = av
        self.frames = 0

    def send(self, frame_bgr: Image) -> None:
        """Encode one frame and send its packets."""
        frame = self._av.VideoFrame.from_ndarray(frame_bgr, format="bgr24")
        frame.pts = self.frames
        self.frames += 1
        for packet in self._stream.encode(frame):
            self._container.mux(packet)

    def close(self) -> None:
        """Flush and close the destination."""
        try:
            for packet in self._stream.encode(None):
                self._container.mux(packet)
        finally:
            self._container.close()


def _frame_out(encoder: VideoEncoder, drawing: Callable[[], Image | None], blank: Image) -> None:
    picture = drawing()
    encoder.send(blank if picture is None else picture)


async def run_video(config: VideoConfig, draw: Callable[[], Callable[[], Image | None]]) -> None:
    """Send the video until cancelled (a failure is logged once and ends the video only).

    Args:
        config: The ``debug_server.video`` section.
        draw: Takes the state to show now (on the event loop) and returns the drawing of it
            (run in the stream's thread; None: nothing to show yet, a black frame goes out).
    """
    pool = ThreadPoolExecutor(1, thread_name_prefix="debugview-video")
    loop = asyncio.get_running_loop()
    encoder: VideoEncoder | None = None
    try:
        encoder = await loop.run_in_executor(pool, VideoEncoder, config)
        if config.sdp_path is not None:
            Path(config.sdp_path).write_text(sdp_text(config.host, config.port))
        logger.info(
            "debug view video: H.264 over RTP to udp://%s:%d (%dx%d at %g fps)",
            config.host,
            config.port,
            config.width_px,
            config.height_px,
            config.fps,
        )
        period_s = 1.0 / config.fps
        blank = np.zeros((config.height_px, config.width_px, 3), dtype=np.uint8)
        while True:
            started_s = time.monotonic()
            frame = functools.partial(_frame_out, encoder, draw(), blank)
            await loop.run_in_executor(pool, frame)
            await asyncio.sleep(max(0.0, period_s - (time.monotonic() - started_s)))
    except (OSError, ValueError, RuntimeError) as exc:
        # PyAV's errors are OSError and ValueError subclasses (FFmpeg's codes).
        logger.error(
            "debug view video to udp://%s:%d stopped: %s (the daemon flies on without it)",
            config.host,
            config.port,
            exc,
        )
    finally:
        if encoder is not None:
            pool.submit(encoder.close)
        pool.shutdown(wait=True)
