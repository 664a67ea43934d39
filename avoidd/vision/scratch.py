"""Reusable arrays for the full-image temporaries of the vision functions.

A fresh full-image array is not free: the allocator hands large freed blocks back to the
system, and the next frame's array of the same size page-faults on every 4 KiB page it
touches (measured on the bench's 640x480 frames: about half of the post stage's time went to
page faults). The temporaries of a function are therefore taken from here and kept for the
next frame.

Each thread has its own arrays, so heads processed in parallel threads never share one. A
function must take a name of its own for each temporary, never return a scratch array, and
never hold one across a call that may use the same name.
"""

from __future__ import annotations

import threading
from typing import Any

import numpy as np
import numpy.typing as npt

_MAX_ARRAYS = 64
"""More distinct (name, shape, type) keys than this in one thread: start afresh (bounded memory
when image sizes keep changing)."""

_LOCAL = threading.local()


def scratch(name: str, shape: tuple[int, ...], dtype: npt.DTypeLike) -> npt.NDArray[Any]:
    """A C-contiguous array of this thread to write temporaries into; contents undefined.

    Args:
        name: The caller's name for the temporary (``module.function.what``).
        shape: Its shape.
        dtype: Its element type.

    Returns:
        The same array on every call with the same name, shape and type in this thread.
    """
    arrays: dict[tuple[str, tuple[int, ...], str], npt.NDArray[Any]] | None = getattr(
        _LOCAL, "arrays", None
    )
    if arrays is None:
        arrays = _LOCAL.arrays = {}
    key = (name, tuple(shape), np.dtype(dtype).str)
    array = arrays.get(key)
    if array is None:
        if len(arrays) >= _MAX_ARRAYS:
            arrays.clear()
        array = arrays[key] = np.empty(shape, dtype=dtype)
    return array
