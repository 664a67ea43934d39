"""A simulated camera's renderer in a process of its own.

A real camera exposes and reads out its frames on its own hardware: none of that is the
companion computer's work. Rendered in the daemon's process, a simulated camera's frames cost
about as much CPU as the daemon's whole pipeline (320x240: some 20 ms a pair against 26), and on
a busy machine the two wait for each other: the frames' age reaches the daemon's limit, and the
data goes stale. :class:`RenderProcess` renders in a child process that starts a session of its
own, so the kernel's autogroup scheduling shares the CPU out to it as to another program, not
as one more thread of the daemon's.

The child ends when its pipe closes: at :meth:`RenderProcess.close`, or when the daemon's
process ends in any way (the operating system closes the pipe).
"""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
import threading
from multiprocessing.connection import Connection
from typing import Protocol

import numpy as np

from avoidd.errors import SourceError
from avoidd.sim.world import World
from avoidd.types import Image, Mount, RectifiedRig

_START_TIMEOUT_S = 60.0
"""How long the first pair may take (the child imports NumPy and OpenCV and builds the texture
first; seconds idle, more on a loaded machine)."""
_PAIR_TIMEOUT_S = 10.0
"""How long any later pair may take before the renderer is taken for hung."""

PoseArgs = tuple[float, float, float, float, float, float]
"""north_m, east_m, down_m, yaw_rad, roll_deg, pitch_deg: what the renderer draws from."""


class PairRenderer(Protocol):
    """Renders a head's two views from a vehicle pose."""

    def render_pair(self, pose: PoseArgs) -> tuple[Image, Image]:
        """The left and right grey views from the pose."""
        ...

    def close(self) -> None:
        """Release what the renderer holds."""
        ...


class LocalRenderer:
    """The renderer in the caller's own process and thread (tests, one-off renders).

    Args:
        world: The world.
        rig: The head's rectified rig.
        mount: The head's mount.
        noise_std: Sensor noise in grey levels.
        seed: Seed of the sensor noise.
    """

    def __init__(
        self, world: World, rig: RectifiedRig, mount: Mount, noise_std: float = 1.0, seed: int = 0
    ) -> None:
        from avoidd.sim.render import StereoRenderer  # NumPy work only when used

        self.renderer = StereoRenderer(world, rig, mount, noise_std)
        self._rng = np.random.default_rng(seed)

    def render_pair(self, pose: PoseArgs) -> tuple[Image, Image]:
        """The left and right grey views from the pose."""
        pair = self.renderer.render(*pose, rng=self._rng)
        return pair.left, pair.right

    def close(self) -> None:
        """Nothing to release."""


class RenderProcess:
    """The renderer in a child process with a session (and so a CPU share) of its own.

    The child is ``python -m avoidd.sim.render_process`` with a pipe each way (not
    :mod:`multiprocessing`'s spawn, which runs the caller's main script again in the child:
    a script without a ``__main__`` guard would start a second flight); its first message
    carries the world, rig, mount, noise and seed. It starts at once; the first
    :meth:`render_pair` waits for it to be ready. A renderer that failed once (no answer in
    time, the child gone) is :attr:`broken` for good: a late answer would pair a frame with
    the wrong pose, so the child is stopped and its owner starts another.

    Args:
        world: The world.
        rig: The head's rectified rig.
        mount: The head's mount.
        noise_std: Sensor noise in grey levels.
        seed: Seed of the sensor noise (the same frames as :class:`LocalRenderer` with it).

    Raises:
        SourceError: The child could not be started.
    """

    def __init__(
        self, world: World, rig: RectifiedRig, mount: Mount, noise_std: float = 1.0, seed: int = 0
    ) -> None:
        self._lock = threading.Lock()
        self._broken = False
        self._started = False
        fds: list[int] = []
        try:
            fds += os.pipe()  # to the child: read end, write end
            fds += os.pipe()  # from the child: read end, write end
            to_child_read, to_child_write, from_child_read, from_child_write = fds
            # The child imports avoidd as this process does, wherever it was found.
            env = os.environ | {"PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
            self._process = subprocess.Popen(
                [sys.executable, "-m", __name__, str(to_child_read), str(from_child_write)],
                pass_fds=(to_child_read, from_child_write),
                stdin=subprocess.DEVNULL,
                start_new_session=True,
                env=env,
            )
        except (OSError, ValueError) as exc:
            for fd in fds:
                os.close(fd)
            raise SourceError(f"the simulated camera's renderer did not start ({exc})") from exc
        os.close(to_child_read)
        os.close(from_child_write)
        self._send = Connection(to_child_write, readable=False)
        self._receive = Connection(from_child_read, writable=False)
        try:
            self._send.send((world, rig, mount, noise_std, seed))
        except (OSError, ValueError) as exc:
            self.close()
            raise SourceError(f"the simulated camera's renderer did not start ({exc})") from exc

    @property
    def pid(self) -> int:
        """The child's process id."""
        return self._process.pid

    @property
    def broken(self) -> bool:
        """Whether the renderer failed (or was closed) and must be replaced."""
        return self._broken or self._process.poll() is not None

    def render_pair(self, pose: PoseArgs) -> tuple[Image, Image]:
        """The left and right grey views from the pose, rendered by the child.

        Raises:
            SourceError: The child stopped, failed or did not answer in time (the head then
                treats the camera as lost and opens it again with backoff).
        """
        with self._lock:
            if self._broken:
                raise SourceError("the simulated camera's renderer stopped earlier")
            timeout_s = _PAIR_TIMEOUT_S if self._started else _START_TIMEOUT_S
            try:
                self._send.send(pose)
                if not self._receive.poll(timeout_s):
                    raise SourceError(
                        f"the simulated camera's renderer gave no frame in {timeout_s:.0f} s"
                    )
                reply = self._receive.recv()
            except (EOFError, OSError, SourceError) as exc:
                self._broken = True
                self._stop_child()
                if isinstance(exc, SourceError):
                    raise
                raise SourceError(f"the simulated camera's renderer stopped ({exc!r})") from exc
            if isinstance(reply, str):
                raise SourceError(f"the simulated camera's renderer failed: {reply}")
            self._started = True
        left, right = reply
        return left, right

    def close(self) -> None:
        """Stop the child and release the pipes; safe from another thread and twice.

        The child is stopped first: a thread waiting in :meth:`render_pair` then sees the pipe
        end and lets go, and the pipes are closed only after it has.
        """
        self._broken = True
        self._stop_child()
        with self._lock:
            for conn in (self._send, self._receive):
                with contextlib.suppress(OSError):
                    conn.close()

    def _stop_child(self) -> None:
        """Terminate the child (kill it if it lingers) and reap it."""
        if self._process.poll() is not None:
            return
        self._process.terminate()
        try:
            self._process.wait(2.0)
        except subprocess.TimeoutExpired:
            self._process.kill()
            with contextlib.suppress(subprocess.TimeoutExpired):
                self._process.wait(2.0)


class LentRenderer:
    """A renderer lent to a source that may be closed and opened again.

    A scenario unplugs its camera: closing the source leaves the renderer running; its owner
    closes it.

    Args:
        renderer: The renderer.
    """

    def __init__(self, renderer: PairRenderer) -> None:
        self._renderer = renderer

    def render_pair(self, pose: PoseArgs) -> tuple[Image, Image]:
        """The renderer's pair."""
        return self._renderer.render_pair(pose)

    def close(self) -> None:
        """Nothing: the renderer is its owner's."""


def serve(receive: Connection, send: Connection) -> None:
    """The child's loop: its settings first, then one pair per pose, until the pipe closes.

    Args:
        receive: The pipe from the daemon.
        send: The pipe to it.
    """
    try:
        world, rig, mount, noise_std, seed = receive.recv()
    except (EOFError, OSError):
        return
    renderer = LocalRenderer(world, rig, mount, noise_std, seed)
    while True:
        try:
            pose = receive.recv()
        except (EOFError, OSError):
            return
        try:
            reply: tuple[Image, Image] | str = renderer.render_pair(pose)
        except Exception as exc:  # a bug in the renderer: told to the daemon, which logs it
            reply = repr(exc)
        try:
            send.send(reply)
        except (EOFError, OSError):
            return


if __name__ == "__main__":
    serve(
        Connection(int(sys.argv[1]), writable=False), Connection(int(sys.argv[2]), readable=False)
    )
