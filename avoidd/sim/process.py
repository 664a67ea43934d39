"""Ending a SITL autopilot that runs in its own process group."""

from __future__ import annotations

import asyncio
import contextlib
import os
import shutil
import signal
from pathlib import Path


async def end_process_group(
    process: asyncio.subprocess.Process | None, grace_s: float = 3.0
) -> None:
    """SIGTERM a process's group, then SIGKILL it if it has not ended within ``grace_s``.

    The process must have been started with ``start_new_session=True`` (its pid is its
    group's id), so that helpers it started end with it.

    A wait that is cancelled (a test torn down, Ctrl-C) still sends the forced signal before
    the cancellation goes on: nothing is left running.

    Args:
        process: The process, or None (nothing to do).
        grace_s: Seconds between the polite and the forced signal.
    """
    if process is None or process.returncode is not None:
        return
    with contextlib.suppress(ProcessLookupError):
        os.killpg(process.pid, signal.SIGTERM)
    ended = False
    try:
        await asyncio.wait_for(process.wait(), grace_s)
        ended = True
    except TimeoutError:
        pass
    finally:
        if not ended:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(process.pid, signal.SIGKILL)
    if not ended:
        await process.wait()


async def end_and_remove(process: asyncio.subprocess.Process | None, folder: Path | None) -> None:
    """:func:`end_process_group`, then delete the run's work folder (also when cancelled).

    Args:
        process: The process, or None.
        folder: Its work folder, or None.
    """
    try:
        await end_process_group(process)
    finally:
        if folder is not None:
            shutil.rmtree(folder, ignore_errors=True)
