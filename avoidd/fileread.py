"""Reading a file that may be anything: only a regular file, and never more than a bound.

A path in a configuration may name a folder, a FIFO (whose ``open`` waits for a writer), a
device (``/dev/zero`` never ends) or a file far larger than any avoidd reads. Each is refused
here with its kind named, before a byte is read: the type is checked before the file is
opened (opening some devices has effects), opened without blocking, checked again on the
open descriptor, and read up to the bound only.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path


class UnreadableFile(Exception):
    """A file that is not read; the text says why, without the path (callers add it).

    Attributes:
        reason: Why, e.g. ``a FIFO (named pipe), not a regular file``.
    """

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


_KINDS = (
    (stat.S_ISDIR, "a folder"),
    (stat.S_ISFIFO, "a FIFO (named pipe)"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
)


def kind_of(mode: int) -> str:
    """What a file of this ``st_mode`` is, in a few words (``a regular file``, ``a folder``)."""
    if stat.S_ISREG(mode):
        return "a regular file"
    return next((name for test, name in _KINDS if test(mode)), "not a regular file")


def not_regular(path: Path) -> str | None:
    """Why ``path`` is no regular file (``a folder, not a regular file``), or None if it is one.

    A path that does not exist is None too: the caller decides whether that is fine.
    """
    try:
        mode = path.stat().st_mode
    except FileNotFoundError:
        return None
    except OSError as exc:
        return f"cannot be examined ({exc.strerror or exc})"
    if stat.S_ISREG(mode):
        return None
    return f"{kind_of(mode)}, not a regular file"


def _size_text(size_bytes: int) -> str:
    if size_bytes >= 1_000_000:
        return f"{size_bytes / 1_000_000:g} MB"
    if size_bytes >= 1_000:
        return f"{size_bytes / 1_000:g} kB"
    return f"{size_bytes} bytes"


def read_bounded(path: Path, max_bytes: int) -> bytes:
    """The content of a regular file of at most ``max_bytes``.

    Args:
        path: The file.
        max_bytes: The most it may hold.

    Returns:
        Its bytes.

    Raises:
        FileNotFoundError: It does not exist.
        UnreadableFile: It is not a regular file, is larger than ``max_bytes`` or cannot be
            read; the reason names which.
    """
    reason = not_regular(path)
    if reason is not None:
        raise UnreadableFile(reason)
    flags = os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY | os.O_CLOEXEC
    try:
        fd = os.open(path, flags)
    except FileNotFoundError:
        raise
    except OSError as exc:
        raise UnreadableFile(f"cannot be read ({exc.strerror or exc})") from exc
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):  # replaced between the two looks
            raise UnreadableFile(f"{kind_of(mode)}, not a regular file")
        chunks: list[bytes] = []
        total = 0
        while total <= max_bytes:
            chunk = os.read(fd, min(1 << 20, max_bytes + 1 - total))
            if not chunk:
                break
            chunks.append(chunk)
            total += len(chunk)
    except OSError as exc:
        raise UnreadableFile(f"cannot be read ({exc.strerror or exc})") from exc
    finally:
        os.close(fd)
    if total > max_bytes:
        raise UnreadableFile(f"larger than {_size_text(max_bytes)}")
    return b"".join(chunks)
