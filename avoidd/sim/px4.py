"""Starts a real PX4 SITL (SIH physics) for a test or a simulation, and stops all of it after.

The binary (``$AVOIDD_PX4_SITL_DIR/bin/px4``) simulates its own quadrotor (``sihsim_quadx``, no
Gazebo). Each run gets a fresh work folder and a private ``bin`` folder of links: PX4's start-up
script runs its modules as ``px4-<module>`` commands found on ``PATH``, and the same folder
carries avoidd's ``px4-rc.params`` (the start-up script sources the first one on ``PATH``), so
parameters such as ``SDLOG_MODE -1`` hold from boot without a reboot.

PX4's ports are fixed by its start-up script (instance 0; one instance per machine):

- ground-station link: PX4 sends from UDP 18570 to 127.0.0.1:14550, where the
  :class:`~avoidd.sim.gcs.GroundStation` listens (``udpin:127.0.0.1:14550``);
- onboard link (companion, offboard): PX4 sends from UDP 14580 to 127.0.0.1:14540, avoidd's
  ``udpin:127.0.0.1:14540``.

The process runs in its own process group; :meth:`Px4Sitl.stop` kills the group and deletes the
work folder, so nothing is left behind even when a test fails.
"""

from __future__ import annotations

import asyncio
import logging
import os
import shutil
import socket
import tempfile
import time
from pathlib import Path
from types import TracebackType

from avoidd.errors import LinkError
from avoidd.sim.gcs import GroundStation
from avoidd.sim.process import end_process_group

logger = logging.getLogger(__name__)

PARAMS = Path(__file__).resolve().parents[2] / "sitl" / "px4" / "avoidd.params"
"""avoidd's PX4 parameters (PX4 shell ``param set`` lines, sourced at boot)."""

GCS_PORT = 14550
"""Where PX4's ground-station link sends (from UDP 18570)."""
ONBOARD_PORT = 14540
"""Where PX4's onboard link sends (from UDP 14580): avoidd's ``udpin`` port."""
PX4_PORTS = (18570, 14580, 14280, 13030, 19450)
"""UDP ports PX4 instance 0 binds for its MAVLink instances."""

ESTIMATOR_READY = 0x01 | 0x02 | 0x04 | 0x08 | 0x10 | 0x20
"""ESTIMATOR_STATUS flags that must all be set: attitude, horizontal and vertical velocity,
relative and absolute horizontal position, absolute vertical position."""
ESTIMATOR_BAD = 0x0400 | 0x0800  # GPS glitch, accelerometer error


def _udp_free(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        try:
            probe.bind(("127.0.0.1", port))
        except OSError:
            return False
        return True


class Px4Sitl:
    """One PX4 SITL process with SIH physics and the ground station on its GCS link.

    Args:
        binary_dir: Folder with ``bin/px4`` and ``etc/`` (PX4's ROMFS).
        params: Parameter files (PX4 shell lines such as ``param set CP_DIST 2``) sourced at
            boot, in order (default: avoidd's).
        extra_params: More ``name: value`` pairs set at boot after the files.
        model: ``PX4_SIM_MODEL``.
    """

    def __init__(
        self,
        binary_dir: Path,
        params: list[Path] | None = None,
        extra_params: dict[str, float] | None = None,
        model: str = "sihsim_quadx",
    ) -> None:
        binary_dir = binary_dir.resolve()
        self.binary = binary_dir / "bin" / "px4"
        self.romfs = binary_dir / "etc"
        self.params = [p.resolve() for p in (params if params is not None else [PARAMS])]
        self.extra_params = dict(extra_params or {})
        self.model = model
        self.process: asyncio.subprocess.Process | None = None
        self.gcs: GroundStation | None = None
        self.boots = 0
        """Processes started (a restart counts again)."""
        self._root: Path | None = None

    @property
    def onboard_connection(self) -> str:
        """Avoidd's connection for PX4's onboard link."""
        return f"udpin:127.0.0.1:{ONBOARD_PORT}"

    def _prepare(self) -> Path:
        """A fresh folder with ``bin`` (links to px4, avoidd's px4-rc.params) and ``work``."""
        root = Path(tempfile.mkdtemp(prefix="avoidd-px4-"))
        try:
            self._fill(root)
        except BaseException:
            shutil.rmtree(root, ignore_errors=True)
            raise
        return root

    def _fill(self, root: Path) -> None:
        bin_dir = root / "bin"
        bin_dir.mkdir()
        # PX4's build makes px4-<module> links to px4; the start-up script calls them through
        # PATH. Copies that lost their link nature (3-byte text files) cannot run, so link anew.
        for entry in sorted((self.binary.parent).iterdir()):
            name = entry.name
            if name == "px4-alias.sh":
                (bin_dir / name).symlink_to(entry)
            elif name == "px4" or name.startswith("px4-"):
                (bin_dir / name).symlink_to(self.binary)
        lines = ["#!/bin/sh", "# avoidd's parameters for this run (sourced by rcS)"]
        for path in self.params:
            lines.append(f"# from {path}")
            lines.extend(
                line.strip()
                for line in path.read_text().splitlines()
                if line.strip() and not line.lstrip().startswith("#")
            )
        lines.extend(f"param set {name} {value:g}" for name, value in self.extra_params.items())
        (bin_dir / "px4-rc.params").write_text("\n".join(lines) + "\n")
        (root / "work").mkdir()

    async def start(self, timeout_s: float = 30.0) -> GroundStation:
        """Start the binary, listen on the GCS link and wait for the first heartbeat.

        A start that fails leaves nothing behind (process, socket, work folder).

        Raises:
            LinkError: The binary is missing, a port PX4 needs is taken, or no heartbeat came.
        """
        if not os.access(self.binary, os.X_OK):
            raise LinkError(f"{self.binary}: not an executable PX4 SITL binary")
        taken = [p for p in (*PX4_PORTS, GCS_PORT) if not _udp_free(p)]
        if taken:
            raise LinkError(
                f"PX4 SITL: UDP ports {taken} on 127.0.0.1 are taken (another PX4 or a ground "
                "station?); PX4's ports are fixed, run one instance at a time"
            )
        try:
            if self.gcs is None:
                gcs = GroundStation(f"udpin:127.0.0.1:{GCS_PORT}")
                self.gcs = gcs
                await gcs.open()
            await self._spawn()
            await self.gcs.wait_heartbeat(timeout_s)
        except BaseException:
            await self.stop()
            raise
        logger.info("PX4 SITL up (GCS udp:%d, onboard udp:%d)", GCS_PORT, ONBOARD_PORT)
        return self.gcs

    async def _spawn(self) -> None:
        self._root = self._prepare()
        bin_dir = self._root / "bin"
        environment = dict(os.environ)
        environment["PATH"] = f"{bin_dir}:{environment.get('PATH', '/usr/bin:/bin')}"
        environment["PX4_SIM_MODEL"] = self.model
        self.process = await asyncio.create_subprocess_exec(
            str(bin_dir / "px4"),
            "-d",
            str(self.romfs),
            "-w",
            str(self._root / "work"),
            cwd=self._root,
            env=environment,
            stdin=asyncio.subprocess.DEVNULL,
            stdout=asyncio.subprocess.DEVNULL,
            stderr=asyncio.subprocess.DEVNULL,
            start_new_session=True,
        )
        self.boots += 1

    async def restart(self, timeout_s: float = 30.0) -> None:
        """Kill the process and start a fresh one (new work folder); the GCS stays open."""
        await self._kill()
        await self._spawn()
        assert self.gcs is not None
        await self.gcs.wait_heartbeat(timeout_s)

    async def wait_estimator(self, timeout_s: float = 90.0) -> float:
        """Wait until the estimator reports attitude, velocity and position valid.

        Returns:
            Seconds waited.

        Raises:
            LinkError: Not within the timeout.
        """
        gcs = self.gcs
        assert gcs is not None
        start = time.monotonic()
        await gcs.request_message_interval("ESTIMATOR_STATUS", 2.0)
        ok = await gcs.next_message(
            lambda m: (
                m.get_type() == "ESTIMATOR_STATUS"
                and gcs.from_autopilot(m)
                and m.flags & ESTIMATOR_READY == ESTIMATOR_READY
                and not m.flags & ESTIMATOR_BAD
            ),
            timeout_s,
        )
        if ok is None:
            raise LinkError(f"PX4 SITL: estimator not ready within {timeout_s:.0f} s")
        return time.monotonic() - start

    async def _kill(self) -> None:
        process = self.process
        self.process = None
        await end_process_group(process)
        if self._root is not None:
            shutil.rmtree(self._root, ignore_errors=True)
            self._root = None

    async def stop(self) -> None:
        """Close the ground station, end the process group and delete the work folder."""
        if self.gcs is not None:
            await self.gcs.close()
            self.gcs = None
        await self._kill()

    async def __aenter__(self) -> Px4Sitl:
        await self.start()
        return self

    async def __aexit__(
        self,
        kind: type[BaseException] | None,
        error: BaseException | None,
        trace: TracebackType | None,
    ) -> None:
        await self.stop()
