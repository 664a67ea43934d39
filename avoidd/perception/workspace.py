"""Reusable arrays for the whole-image and per-point temporaries of one head's frame.

A fresh array of a whole image is memory the kernel must map and zero page by page; on the
companion computers (and in the VMs the bench runs in) that costs several times the arithmetic
done in it. The obstacle stage therefore keeps its temporaries between frames: a workspace
hands out arrays by name, the same one every frame, grown when a frame needs more.

Arrays from a workspace are overwritten by the next frame that asks for the same name: they
must not leave the function that asked for them (or :func:`avoidd.perception.perceive.perceive`,
which owns the thread's workspace).
"""

from __future__ import annotations

import threading
from typing import Any

import numpy as np
import numpy.typing as npt

_local = threading.local()


class Workspace:
    """Named scratch arrays (see the module docstring)."""

    def __init__(self) -> None:
        self._arrays: dict[tuple[str, np.dtype[Any]], npt.NDArray[Any]] = {}

    @staticmethod
    def for_thread() -> Workspace:
        """The calling thread's workspace (heads processed in parallel never share one)."""
        workspace = getattr(_local, "workspace", None)
        if workspace is None:
            workspace = Workspace()
            _local.workspace = workspace
        return workspace

    def array(self, name: str, shape: int | tuple[int, ...], dtype: npt.DTypeLike) -> Any:
        """An uninitialised array of ``shape``, reused from earlier frames when large enough.

        Args:
            name: What it holds (one array per name and dtype).
            shape: Its shape.
            dtype: Its element type.

        Returns:
            A C-contiguous array (a view of the kept one).
        """
        shape = (shape,) if isinstance(shape, int) else tuple(shape)
        size = int(np.prod(shape, dtype=np.int64))
        key = (name, np.dtype(dtype))
        kept = self._arrays.get(key)
        if kept is None or kept.size < size:
            # A little headroom: the number of points changes from frame to frame.
            kept = np.empty(max(size + size // 8, 1024), dtype=key[1])
            self._arrays[key] = kept
        return kept[:size].reshape(shape)
