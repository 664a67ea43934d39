"""Starts a real ArduCopter SITL binary for a test or a simulation, and stops all of it after.

The binary (``$AVOIDD_SITL_DIR/arducopter``) simulates its own vehicle. It waits for a ground
station on TCP ``5760 + 10 * instance`` before it simulates anything, so a
:class:`~avoidd.sim.gcs.GroundStation` keeps that port served for the whole run; its SERIAL1
is a UDP client that sends to avoidd (``udpin`` on ``companion_port``). It exits when the
process that started it dies, and the runner kills its process group when it stops, so no
process is left behind even when a test fails.
"""

from __future__ import annotations

import asyncio
import logging
import os
import socket
import tempfile
from pathlib import Path
from types import TracebackType

from avoidd.errors import LinkError
from avoidd.sim.gcs import GroundStation
from avoidd.sim.process import end_and_remove

logger = logging.getLogger(__name__)

PARAMS = Path(__file__).resolve().parents[2] / "sitl" / "ardupilot" / "avoidd.parm"
"""avoidd's ArduCopter parameters (proximity over MAVLink, simple avoidance, SERIAL1)."""


def _port_free(port: int) -> bool:
    with socket.socket() as probe:
        try:
            probe.bind(("127.0.0.1", port))
        except OSError:
            return False
        return True


def free_instance() -> int:
    """An SITL instance number whose ports (5760 + 10 n and the two after) are free."""
    for instance in range(20):
        base = 5760 + 10 * instance
        if all(_port_free(base + k) for k in range(3)):
            return instance
    raise LinkError("no free SITL instance: ports 5760 to 5952 are all taken")


class ArduPilotSitl:
    """One ArduCopter SITL process, its ground station, and the companion port it sends to.

    Args:
        binary_dir: Folder with ``arducopter`` and ``copter.parm``.
        companion_port: UDP port on 127.0.0.1 that SERIAL1 sends to (avoidd's ``udpin``).
        extra_params: Parameter files loaded after ``copter.parm`` (default: avoidd's).
        speedup: Simulation speed (1: real time).
        home: ``lat,lon,alt,heading`` of the home position.
    """

    def __init__(
        self,
        binary_dir: Path,
        companion_port: int,
        extra_params: list[Path] | None = None,
        speedup: float = 1.0,
        home: str = "-35.363261,149.165230,584,0",
    ) -> None:
        binary_dir = binary_dir.resolve()
        self.binary = binary_dir / "arducopter"
        self.defaults = [
            binary_dir / "copter.parm",
            *(p.resolve() for p in extra_params or [PARAMS]),
        ]
        self.companion_port = companion_port
        self.speedup = speedup
        self.home = home
        self.instance = 0
        self.process: asyncio.subprocess.Process | None = None
        self.gcs: GroundStation | None = None
        self._workdir: Path | None = None

    @property
    def gcs_port(self) -> int:
        """The ground-station TCP port of this instance."""
        return 5760 + 10 * self.instance

    async def start(self, timeout_s: float = 30.0) -> GroundStation:
        """Start the binary, connect the ground station and wait for the first heartbeat.

        A start that fails leaves nothing behind (process, socket, work folder).

        Raises:
            LinkError: The binary is missing, or it never served its ground-station port.
        """
        if not os.access(self.binary, os.X_OK):
            raise LinkError(f"{self.binary}: not an executable ArduCopter SITL binary")
        try:
            return await self._start(timeout_s)
        except BaseException:
            await self.stop()
            raise

    async def _start(self, timeout_s: float) -> GroundStation:
        self.instance = free_instance()
        self._workdir = Path(tempfile.mkdtemp(prefix="avoidd-sitl-"))
        self.process = await asyncio.create_subprocess_exec(
            str(self.binary),
            "-w",
            "--model",
            "+",
            "--speedup",
            str(self.speedup),
            f"-I{self.instance}",
            "--sim-address=127.0.0.1",
            "--home",
            self.home,
            "--defaults",
            ",".join(str(p) for p in self.defaults),
            "--serial1",
            f"udpclient:127.0.0.1:{self.companion_port}",
            cwd=self._workdir,
            stdout=asyncio.subprocess.DEVNULL,
            stderr=asyncio.subprocess.DEVNULL,
            start_new_session=True,
        )
        gcs = GroundStation(f"tcp:127.0.0.1:{self.gcs_port}")
        self.gcs = gcs
        await gcs.open()
        await gcs.wait_heartbeat(timeout_s)
        logger.info(
            "ArduCopter SITL instance %d up (GCS tcp:%d, SERIAL1 to udp:%d)",
            self.instance,
            self.gcs_port,
            self.companion_port,
        )
        return gcs

    async def stop(self) -> None:
        """Close the ground station, end the process group and delete the work folder."""
        if self.gcs is not None:
            await self.gcs.close()
            self.gcs = None
        process, folder = self.process, self._workdir
        self.process = self._workdir = None
        await end_and_remove(process, folder)

    async def __aenter__(self) -> ArduPilotSitl:
        await self.start()
        return self

    async def __aexit__(
        self,
        kind: type[BaseException] | None,
        error: BaseException | None,
        trace: TracebackType | None,
    ) -> None:
        await self.stop()
