"""The trust rule on real sockets: who may command avoidd, and a signed daemon that restarts.

The autopilot is the mock on a loopback UDP socket; a ground station's frames reach avoidd
through the mock's socket, as through a router. Restarts are real processes, killed with
SIGKILL or stopped with SIGTERM.
"""

from __future__ import annotations

import asyncio
import json
import os
import queue
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import pytest

from avoidd.mavlink import codec as mav
from avoidd.mavlink.mock_autopilot import MockAutopilot
from avoidd.mavlink.signing import wall_timestamp
from tests.helpers import REPO, free_udp_port, synthetic_config, wait_for
from tests.helpers import start_daemon as start
from tests.helpers import stop_daemon as stop

ME = mav.MAV_COMP_ID_OBSTACLE_AVOIDANCE
KEY = bytes(range(1, 33))
GOAL = {"north_m": 30.0, "east_m": 0.0, "altitude_m": 2.0}


def _param_values(autopilot: MockAutopilot, name: str) -> list[float]:
    return [
        m.param_value for m in autopilot.of_type("PARAM_VALUE") if m.param_id.rstrip("\x00") == name
    ]


def _texts(autopilot: MockAutopilot) -> list[str]:
    return [m.text.rstrip("\x00") for m in autopilot.of_type("STATUSTEXT")]


async def test_an_unsigned_ground_station_cannot_switch_avoidance_on_nor_thin_its_margin(
    tmp_path: Path,
) -> None:
    params_file = tmp_path / "params.json"
    autopilot = MockAutopilot(system_id=7, mode="GUIDED", armed=True)
    port = free_udp_port()
    await autopilot.start(f"udpin:127.0.0.1:{port}")
    avoidance = {"enabled": False, "goal": GOAL, "params_file": str(params_file)}
    config = synthetic_config(
        tmp_path, f"udpout:127.0.0.1:{port}", sections={"avoidance": avoidance}
    )
    daemon, task = await start(config)
    ground, stranger = mav.Codec(255, 190), mav.Codec(99, 1)
    try:
        assert await wait_for(lambda: daemon.vehicle.link_up, 10)
        assert autopilot.transport is not None

        def param_set(codec: mav.Codec, name: str, value: float) -> None:
            message = codec.build("PARAM_SET", 7, ME, name.encode(), value, 9)
            assert autopilot.transport is not None
            autopilot.transport.send(codec.pack(message))

        # A stranger's sets get no answer at all.
        param_set(stranger, "AVD_MARGIN", 3.0)
        param_set(ground, "AVD_ENABLE", 1.0)
        param_set(ground, "AVD_MARGIN", 0.0)
        param_set(ground, "AVD_RADIUS", 0.05)
        param_set(ground, "AVD_MAX_SPEED", 8.0)
        param_set(ground, "AVD_MARGIN", 2.0)  # more cautious: taken
        assert await wait_for(lambda: len(_param_values(autopilot, "AVD_MARGIN")) == 2, 5)
        assert await wait_for(lambda: len(_param_values(autopilot, "AVD_MAX_SPEED")) == 1, 5)
        assert _param_values(autopilot, "AVD_ENABLE") == [0.0]
        assert _param_values(autopilot, "AVD_MARGIN") == [1.0, 2.0]
        assert _param_values(autopilot, "AVD_RADIUS") == [0.5]
        assert _param_values(autopilot, "AVD_MAX_SPEED") == [3.0]
        assert daemon.vehicle.refused_commands["sender"] == 1
        assert await wait_for(
            lambda: "avoidd: AVD_MAX_SPEED refused: unsigned" in _texts(autopilot), 5
        ), _texts(autopilot)
        # The vehicle is armed in GUIDED with a goal, yet avoidd stays silent.
        await asyncio.sleep(1.0)
        assert autopilot.of_type("SET_POSITION_TARGET_LOCAL_NED") == []
        assert not daemon.avoidance.config.enabled
    finally:
        await stop(daemon, task)
        await autopilot.stop()
    saved = json.loads(params_file.read_text())
    assert saved["AVD_ENABLE"] == 0.0 and saved["AVD_MARGIN"] == 2.0
    assert saved["AVD_RADIUS"] == 0.5 and saved["AVD_MAX_SPEED"] == 3.0


async def test_with_the_opt_in_an_unsigned_ground_station_switches_avoidance_on(
    tmp_path: Path,
) -> None:
    autopilot = MockAutopilot(system_id=7, mode="GUIDED", armed=True)
    port = free_udp_port()
    await autopilot.start(f"udpin:127.0.0.1:{port}")
    config = synthetic_config(
        tmp_path,
        f"udpout:127.0.0.1:{port}",
        mavlink={"control": {"unsigned_may_weaken": True}},
        sections={"avoidance": {"enabled": False, "goal": GOAL}},
    )
    daemon, task = await start(config)
    ground = mav.Codec(255, 190)
    try:
        assert await wait_for(lambda: daemon.vehicle.link_up, 10)
        assert autopilot.transport is not None
        message = ground.build("PARAM_SET", 7, ME, b"AVD_ENABLE", 1.0, 9)
        autopilot.transport.send(ground.pack(message))
        assert await wait_for(lambda: _param_values(autopilot, "AVD_ENABLE") == [1.0], 5)
        assert await wait_for(
            lambda: len(autopilot.of_type("SET_POSITION_TARGET_LOCAL_NED")) >= 5, 10
        )
    finally:
        await stop(daemon, task)
        await autopilot.stop()


# --- a signed daemon in a process of its own ---------------------------------------------------


class DaemonProcess:
    """``avoidd run`` in a child process, its log lines read as they come, with their time."""

    def __init__(self, config: Path) -> None:
        self.lines: queue.Queue[tuple[float, str]] = queue.Queue()
        self.log: list[str] = []
        self.process = subprocess.Popen(
            [sys.executable, "-m", "avoidd", "run", "--config", str(config)],
            stderr=subprocess.PIPE,
            stdout=subprocess.DEVNULL,
            text=True,
            cwd=REPO,
            env={**os.environ, "PYTHONPATH": str(REPO)},
        )
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.process.stderr is not None
        for line in self.process.stderr:
            self.lines.put((time.monotonic(), line.rstrip("\n")))

    async def wait_line(self, text: str, timeout_s: float) -> float:
        """When a line holding ``text`` came (monotonic s); fails after ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            try:
                t_s, line = self.lines.get_nowait()
            except queue.Empty:
                await asyncio.sleep(0.02)
                continue
            self.log.append(line)
            if text in line:
                return t_s
        raise AssertionError(f"no line with {text!r} in {timeout_s} s:\n" + "\n".join(self.log))

    def end(self, signum: int) -> int:
        self.process.send_signal(signum)
        try:
            return self.process.wait(timeout=30)
        finally:
            if self.process.poll() is None:
                self.process.kill()
                self.process.wait()


def _signed_config(tmp_path: Path, connection: str) -> Path:
    key_file = tmp_path / "signing.key"
    key_file.write_text(KEY.hex())
    signing = {"key_file": str(key_file), "timestamp_file": str(tmp_path / "signing-timestamp")}
    avoidance = {"enabled": False, "params_file": str(tmp_path / "params.json")}
    return synthetic_config(
        tmp_path,
        connection,
        mavlink={"system_id": "auto", "signing": signing},
        sections={"avoidance": avoidance},
    )


async def _restarts(tmp_path: Path, daemon_side: str, autopilot_side: str) -> list[float]:
    """Start, end and start a signed daemon three times; seconds from start to link up each time.

    The autopilot started just before, signs from the wall clock (as one with GPS time does).
    """
    port = free_udp_port()
    autopilot = MockAutopilot(system_id=5, mode="LOITER", key=KEY)
    await autopilot.start(f"{autopilot_side}:127.0.0.1:{port}")
    config = _signed_config(tmp_path, f"{daemon_side}:127.0.0.1:{port}")
    waits: list[float] = []
    try:
        for signum in (signal.SIGKILL, signal.SIGTERM, signal.SIGKILL):
            daemon = DaemonProcess(config)
            try:
                started = await daemon.wait_line("avoidd started", 60)
                up = await daemon.wait_line("MAVLink link up", 20)
                waits.append(up - started)
            finally:
                code = daemon.end(signum)
            assert code == (-9 if signum == signal.SIGKILL else 0), daemon.log
    finally:
        await autopilot.stop()
    return waits


@pytest.mark.timeout(240)
@pytest.mark.parametrize(
    ("daemon_side", "autopilot_side"), [("udpin", "udpout"), ("udpout", "udpin")]
)
async def test_a_signed_daemon_restarted_three_times_hears_its_autopilot_at_once(
    tmp_path: Path, daemon_side: str, autopilot_side: str
) -> None:
    # Each start used to store a mark a minute past its own timestamp and begin from the
    # last mark: after a few quick restarts avoidd was more than a minute ahead of the
    # autopilot and refused its every frame as a replay (on udpin it then never heard it).
    waits = await _restarts(tmp_path, daemon_side, autopilot_side)
    assert len(waits) == 3 and max(waits) <= 2.0, waits
    stored = json.loads((tmp_path / "signing-timestamp").read_text())
    assert stored["timestamp"] - wall_timestamp() < 30 * 100_000  # never far ahead


@pytest.mark.timeout(180)
async def test_a_signed_command_captured_before_a_crash_is_refused_after_it(
    tmp_path: Path,
) -> None:
    port = free_udp_port()
    autopilot = MockAutopilot(system_id=5, mode="LOITER", key=KEY)
    await autopilot.start(f"udpin:127.0.0.1:{port}")
    config = _signed_config(tmp_path, f"udpout:127.0.0.1:{port}")
    ground = mav.Codec(255, 190)
    ground.enable_signing(KEY, wall_timestamp(), lambda _msg_id: False, link_id=1)

    def send(message: Any) -> bytes:
        frame = ground.pack(message)
        assert autopilot.transport is not None
        autopilot.transport.send(frame)
        return frame

    try:
        daemon = DaemonProcess(config)
        try:
            await daemon.wait_line("MAVLink link up", 60)
            heartbeat = ground.build("HEARTBEAT", mav.MAV_TYPE_GCS, 8, 0, 0, 4)
            captured = [send(heartbeat)]
            captured.append(send(ground.build("PARAM_SET", 5, ME, b"AVD_MAX_SPEED", 2.0, 9)))
            assert await wait_for(lambda: _param_values(autopilot, "AVD_MAX_SPEED") == [2.0], 5)
            # Signed, so also the less cautious way.
            send(ground.build("PARAM_SET", 5, ME, b"AVD_MAX_SPEED", 2.5, 9))
            assert await wait_for(
                lambda: _param_values(autopilot, "AVD_MAX_SPEED") == [2.0, 2.5], 5
            )
        finally:
            assert daemon.end(signal.SIGKILL) == -9
        daemon = DaemonProcess(config)
        try:
            await daemon.wait_line("MAVLink link up", 60)
            assert autopilot.transport is not None
            for frame in captured:  # the frames again: the ground station's, then 2.0
                autopilot.transport.send(frame)
            await asyncio.sleep(1.5)
            assert _param_values(autopilot, "AVD_MAX_SPEED") == [2.0, 2.5]
            # The ground station's next frames are taken.
            send(heartbeat)
            send(ground.build("PARAM_SET", 5, ME, b"AVD_MAX_SPEED", 1.5, 9))
            assert await wait_for(
                lambda: _param_values(autopilot, "AVD_MAX_SPEED") == [2.0, 2.5, 1.5], 5
            )
        finally:
            assert daemon.end(signal.SIGTERM) == 0
    finally:
        await autopilot.stop()
    assert json.loads((tmp_path / "params.json").read_text())["AVD_MAX_SPEED"] == 1.5
