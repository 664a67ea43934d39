"""An image's width and height from its header (PNG, JPEG, BMP, PNM, TIFF), before decoding it.

Decoding allocates the whole picture: a 20000x20000 PNG took 6.4 s and 856 MB just to be
refused for its size. Its header says the size in a few bytes.
"""

from __future__ import annotations

import re
from typing import Literal

MAX_IMAGE_PIXELS = 8192 * 4096
"""The largest image a recording may hold (33.5 megapixels): no stereo camera's view is
larger, and decoding one of these already takes about 100 MB."""

_PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
_JPEG_SOF = frozenset(
    {*range(0xC0, 0xC4), *range(0xC5, 0xC8), *range(0xC9, 0xCC), 0xCD, 0xCE, 0xCF}
)
_JPEG_NO_LENGTH = frozenset({0x01, *range(0xD0, 0xDA)})
_PNM_HEADER = re.compile(rb"P[1-6](?:\s+|#[^\n]*\n)+(\d+)(?:\s+|#[^\n]*\n)+(\d+)")


def _be(data: bytes, start: int, size: int) -> int:
    return int.from_bytes(data[start : start + size], "big")


def _png(data: bytes) -> tuple[int, int] | None:
    if len(data) < 24 or data[12:16] != b"IHDR":
        return None
    return _be(data, 16, 4), _be(data, 20, 4)


def _jpeg(data: bytes) -> tuple[int, int] | None:
    i = 2
    while i + 4 <= len(data):
        if data[i] != 0xFF:
            return None
        marker = data[i + 1]
        if marker == 0xFF:  # fill byte
            i += 1
            continue
        if marker in _JPEG_NO_LENGTH:
            i += 2
            continue
        if marker in _JPEG_SOF:
            if i + 9 > len(data):
                return None
            return _be(data, i + 7, 2), _be(data, i + 5, 2)
        i += 2 + _be(data, i + 2, 2)
    return None


def _bmp(data: bytes) -> tuple[int, int] | None:
    if len(data) < 26:
        return None
    header = int.from_bytes(data[14:18], "little")
    if header == 12:  # BITMAPCOREHEADER: 16-bit sizes
        return int.from_bytes(data[18:20], "little"), int.from_bytes(data[20:22], "little")
    width = int.from_bytes(data[18:22], "little", signed=True)
    height = int.from_bytes(data[22:26], "little", signed=True)
    return abs(width), abs(height)  # a negative height is a top-down bitmap


def _tiff(data: bytes) -> tuple[int, int] | None:
    order: Literal["little", "big"] = "little" if data[:2] == b"II" else "big"

    def number(start: int, size: int) -> int:
        return int.from_bytes(data[start : start + size], order)

    ifd = number(4, 4)
    if ifd + 2 > len(data):
        return None
    found: dict[int, int] = {}
    for entry in range(min(number(ifd, 2), 512)):
        at = ifd + 2 + 12 * entry
        if at + 12 > len(data):
            break
        tag, kind = number(at, 2), number(at + 2, 2)
        if tag in (256, 257) and kind in (3, 4):
            found[tag] = number(at + 8, 2 if kind == 3 else 4)
    if 256 in found and 257 in found:
        return found[256], found[257]
    return None


def image_size(data: bytes) -> tuple[int, int] | None:
    """Width and height of an encoded image from its header, or None if it does not say.

    Args:
        data: The file's bytes (the first few kilobytes are enough, except for a JPEG with
            large metadata before its frame header).

    Returns:
        ``(width, height)`` in pixels, or None for a format not known here or a header that
        does not parse (decoding then decides).
    """
    if data.startswith(_PNG_MAGIC):
        return _png(data)
    if data.startswith(b"\xff\xd8"):
        return _jpeg(data)
    if data.startswith(b"BM"):
        return _bmp(data)
    if data[:4] in (b"II*\x00", b"MM\x00*"):
        return _tiff(data)
    match = _PNM_HEADER.match(data[:1024])
    if match is not None:
        return int(match.group(1)), int(match.group(2))
    return None


def too_many_pixels(size: tuple[int, ...] | None, views: int = 1) -> str | None:
    """Why an image of ``size`` (width, height) is too large to read, or None if it is not.

    Args:
        size: Width and height (None: not known, not refused).
        views: Views side by side in one picture (a side-by-side video frame holds two).
    """
    if size is None or size[0] * size[1] <= views * MAX_IMAGE_PIXELS:
        return None
    limit = f"{MAX_IMAGE_PIXELS / 1e6:.1f} megapixels" + (
        f" per view ({views})" if views > 1 else ""
    )
    return f"{size[0]}x{size[1]} pixels, more than the {limit} avoidd reads"
