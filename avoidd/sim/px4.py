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
import math
import os
import re
import shutil
import socket
import tempfile
import time
from pathlib import Path
from types import TracebackType

from pymavlink import mavutil

from avoidd.errors import LinkError
from avoidd.mavlink import codec as mav
from avoidd.sim.gcs import GroundStation
from avoidd.sim.process import end_and_remove

logger = logging.getLogger(__name__)

PARAMS = Path(__file__).resolve().parents[2] / "sitl" / "px4" / "avoidd.params"
"""avoidd's PX4 parameters (PX4 shell ``param set`` lines, sourced at boot)."""

GCS_PORT = 14550
"""Where PX4's ground-station link sends (from UDP 18570)."""
ONBOARD_PORT = 14540
"""Where PX4's onboard link sends (from UDP 14580): avoidd's ``udpin`` port."""
CONSOLE = "console.log"
"""PX4's console output, in the run's folder (deleted with it)."""
PX4_PORTS = (18570, 14580, 14280, 13030, 19450)
"""UDP ports PX4 instance 0 binds for its MAVLink instances."""

ESTIMATOR_READY = 0x01 | 0x02 | 0x04 | 0x08 | 0x10 | 0x20
"""ESTIMATOR_STATUS flags that must all be set: attitude, horizontal and vertical velocity,
relative and absolute horizontal position, absolute vertical position."""
ESTIMATOR_BAD = 0x0400 | 0x0800  # GPS glitch, accelerometer error
SETTLE_S = 20.0
"""Seconds to wait after the estimator first reports ready. With ``EKF2_ANGERR_INIT`` 0.02
(avoidd.params) it reports ready about 1.5 s after boot, but a vehicle armed then drifted
toward the wall against its own velocity report (planner flights 0.82 and 0.89 m from it,
against 1.06-1.32 m armed about 35 s after boot); armed 20 s after ready, 1.06-1.34 m."""
NAV_TAKEOFF = 22
_LANDED = {0: "undefined", 1: "on ground", 2: "in air", 3: "taking off", 4: "landing"}
"""MAV_LANDED_STATE names."""


def _udp_free(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        try:
            probe.bind(("127.0.0.1", port))
        except OSError:
            return False
        return True


def climb_story(positions: list[mav.Message], window_s: float = 5.0) -> str:
    """How the height moved over the last ``window_s`` against the climb rate PX4 reported.

    Below ``MPC_LAND_ALT1`` PX4's take-off climbs on its velocity estimate alone, so a height
    that stays while the reported climb rate does not tells an estimate that disagrees with
    the position (as PX4 SITL's horizontal velocity does under load).

    Args:
        positions: GLOBAL_POSITION_INT messages in time order.
        window_s: The span looked at, back from the last message (its ``time_boot_ms``).

    Returns:
        ``"; last 5 s: height +0.02 m/s, reported climb +0.41 m/s"``, or "" with fewer than
        two messages over at least a second.
    """
    if len(positions) < 2:
        return ""
    end_ms = int(positions[-1].time_boot_ms)
    recent = [m for m in positions if end_ms - int(m.time_boot_ms) <= window_s * 1000.0]
    span_s = (end_ms - int(recent[0].time_boot_ms)) / 1000.0
    if len(recent) < 2 or span_s < 1.0:
        return ""
    rate_m_s = (recent[-1].relative_alt - recent[0].relative_alt) / 1000.0 / span_s
    # GLOBAL_POSITION_INT's vz is down, in cm/s.
    said_m_s = -sum(float(m.vz) for m in recent) / len(recent) / 100.0
    return f"; last {span_s:.0f} s: height {rate_m_s:+.2f} m/s, reported climb {said_m_s:+.2f} m/s"


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
        # PX4's console (its INFO/WARN/ERROR lines) goes to a file in the work folder: a
        # failure can quote it (see console_tail) before the folder is deleted.
        with open(self._root / CONSOLE, "wb") as console:
            self.process = await asyncio.create_subprocess_exec(
                str(bin_dir / "px4"),
                "-d",
                str(self.romfs),
                "-w",
                str(self._root / "work"),
                cwd=self._root,
                env=environment,
                stdin=asyncio.subprocess.DEVNULL,
                stdout=console,
                stderr=asyncio.subprocess.STDOUT,
                start_new_session=True,
            )
        self.boots += 1

    def console_tail(self, lines: int = 12) -> list[str]:
        """The last ``lines`` lines PX4 printed (its console), for a failure's message.

        Returns:
            Those lines, oldest first (empty when PX4 is not running or printed nothing).
        """
        if self._root is None:
            return []
        try:
            text = (self._root / CONSOLE).read_text(errors="replace")
        except OSError:
            return []
        # Its lines carry colour codes for a terminal; drop them.
        clean = re.sub(r"\x1b\[[0-9;]*m", "", text)
        return [line.strip() for line in clean.splitlines() if line.strip()][-lines:]

    async def restart(self, timeout_s: float = 30.0) -> None:
        """Kill the process and start a fresh one (new work folder); the GCS stays open."""
        await self._kill()
        await self._spawn()
        assert self.gcs is not None
        await self.gcs.wait_heartbeat(timeout_s)

    async def wait_estimator(self, timeout_s: float = 90.0, settle_s: float = SETTLE_S) -> float:
        """Wait until the estimator reports attitude, velocity and position valid, then settle.

        Args:
            timeout_s: Seconds the estimator has to report ready.
            settle_s: Seconds to wait after that (see ``SETTLE_S``).

        Returns:
            Seconds until the estimator reported ready (the settling not counted).

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
        ready_s = time.monotonic() - start
        await asyncio.sleep(settle_s)
        return ready_s

    async def take_off(self, height_m: float, tries: int = 3, climb_s: float = 20.0) -> int:
        """Arm and take off (NAV_TAKEOFF, to ``MIS_TAKEOFF_ALT``) until ``height_m`` above home.

        NAV_TAKEOFF goes with every position parameter NaN: PX4 reads params 5-7 as latitude,
        longitude and altitude above sea level and takes zeros literally (a take-off to
        0 N 0 E stays on the ground). A take-off that does not reach the height (seen now and
        then, idle and under load: accepted, TAKEOFF mode, stuck a few decimetres up where
        PX4 denies a disarm as "not landed") is tried again: disarmed by force (the vehicle is
        simulated), armed and commanded again; the last try runs in a fresh PX4 process (a
        CI run once saw three stalls in a row in one process). Each failed try is logged with
        what PX4 did.

        Args:
            height_m: Height above home (GLOBAL_POSITION_INT's ``relative_alt``) that counts
                as taken off; below ``MIS_TAKEOFF_ALT``.
            tries: Take-offs to try.
            climb_s: Seconds a take-off has to reach the height.

        Returns:
            The tries it took.

        Raises:
            LinkError: PX4 would not arm within 60 s, refused the take-off for 20 s, did not
                come back after the restart, or did not climb in ``tries`` tries (the message
                tells each try).
        """
        gcs = self.gcs
        assert gcs is not None
        await gcs.request_message_interval("EXTENDED_SYS_STATE", 5.0)
        stories: list[str] = []
        for attempt in range(1, tries + 1):
            if attempt == tries and attempt > 1:
                logger.warning("PX4 SITL: restarting it for a last take-off")
                await self.restart()
                await self.wait_estimator(120.0)
                await gcs.request_message_interval("EXTENDED_SYS_STATE", 5.0)
            since_ns = time.monotonic_ns()
            if not await gcs.arm(retry_s=60.0):
                raise LinkError(f"PX4 would not arm within 60 s; it said {self._said(since_ns)}")
            await self._command_take_off(since_ns)
            climbed = await gcs.next_message(
                lambda m: (
                    m.get_type() == "GLOBAL_POSITION_INT"
                    and gcs.from_autopilot(m)
                    and m.relative_alt >= height_m * 1000.0
                ),
                climb_s,
            )
            if climbed is not None:
                return attempt
            story = f"try {attempt}: {self._take_off_story(since_ns)}"
            stories.append(story)
            logger.warning("PX4 did not climb to %.1f m: %s", height_m, story)
            if attempt < tries - 1:
                disarmed = await gcs.disarm_to_retry()
                if disarmed != mav.MAV_RESULT_ACCEPTED:
                    logger.warning("PX4 SITL: forced disarm answered %s; arming again", disarmed)
                await asyncio.sleep(2.0)  # down and still before arming again
        raise LinkError(
            f"PX4 did not climb to {height_m:.1f} m in {tries} tries: " + "; ".join(stories)
        )

    async def _command_take_off(self, since_ns: int) -> None:
        """NAV_TAKEOFF until accepted (a command just after arming may be denied)."""
        gcs = self.gcs
        assert gcs is not None
        nan = math.nan
        deadline = time.monotonic() + 20.0
        result: int | None = None
        while time.monotonic() < deadline:
            result = await gcs.command(NAV_TAKEOFF, -1, 0, 0, nan, nan, nan, nan)
            if result == mav.MAV_RESULT_ACCEPTED:
                return
            await asyncio.sleep(1.0)
        raise LinkError(
            f"PX4 refused to take off (MAV_RESULT {result}; it said {self._said(since_ns)})"
        )

    def _said(self, since_ns: int) -> list[str]:
        gcs = self.gcs
        assert gcs is not None
        return [str(m.text).strip() for m in gcs.of_type("STATUSTEXT", since_ns)][-6:]

    def _take_off_story(self, since_ns: int) -> str:
        """What PX4 did since ``since_ns``: modes, landed states, height, words, console."""
        gcs = self.gcs
        assert gcs is not None
        modes: list[str] = []
        for beat in gcs.of_type("HEARTBEAT", since_ns):
            if not gcs.from_autopilot(beat):
                continue
            name = str(mavutil.interpret_px4_mode(beat.base_mode, beat.custom_mode))
            name += " armed" if beat.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED else " disarmed"
            if not modes or modes[-1] != name:
                modes.append(name)
        landed: list[str] = []
        for state in gcs.of_type("EXTENDED_SYS_STATE", since_ns):
            name = _LANDED.get(int(state.landed_state), str(state.landed_state))
            if not landed or landed[-1] != name:
                landed.append(name)
        positions = [
            m for m in gcs.of_type("GLOBAL_POSITION_INT", since_ns) if gcs.from_autopilot(m)
        ]
        heights_m = [m.relative_alt / 1000.0 for m in positions]
        height = (
            f"height above home at most {max(heights_m):.2f} m, last {heights_m[-1]:.2f} m"
            f"{climb_story(positions)}"
            if heights_m
            else "no GLOBAL_POSITION_INT"
        )
        return (
            f"modes {' > '.join(modes)}; landed states {' > '.join(landed) or 'none'}; "
            f"{height}; it said {self._said(since_ns)}; console {self.console_tail(8)}"
        )

    async def _kill(self) -> None:
        process, folder = self.process, self._root
        self.process = self._root = None
        await end_and_remove(process, folder)

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
