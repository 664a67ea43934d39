"""A signed avoidd against a real, signed ArduCopter SITL, restarted three times in a minute.

Issue 52 item 2: each start used to store a signing timestamp a minute past its own, so a few
quick restarts put avoidd so far ahead that a correctly keyed autopilot was refused. Here the
autopilot is ArduPilot itself: its key and starting timestamp are set with ``SETUP_SIGNING``
over its ground-station port (channel 0, which ArduPilot trusts unsigned), after which it
signs what it sends on every port and refuses unsigned frames on SERIAL1, where avoidd is.
Whether ArduPilot took avoidd's OBSTACLE_DISTANCE is read from its own SYS_STATUS: the
proximity sensor is healthy only while MAVLink proximity data keeps arriving.
"""

from __future__ import annotations

import signal
import time
from pathlib import Path

import pytest

from avoidd.mavlink.signing import wall_timestamp
from avoidd.sim.ardupilot import ArduPilotSitl
from avoidd.sim.gcs import GroundStation
from tests.helpers import free_udp_port, synthetic_config, wait_for
from tests.test_trust_link import KEY, DaemonProcess

pytestmark = pytest.mark.sitl

PROXIMITY = 1 << 26  # MAV_SYS_STATUS_SENSOR_PROXIMITY


def _config(tmp_path: Path, port: int, signed: bool) -> Path:
    folder = tmp_path / ("signed" if signed else "unsigned")
    folder.mkdir()
    mavlink: dict[str, object] = {"system_id": "auto"}
    if signed:
        key_file = folder / "signing.key"
        key_file.write_text(KEY.hex())
        mavlink["signing"] = {
            "key_file": str(key_file),
            "timestamp_file": str(folder / "signing-timestamp"),
        }
    return synthetic_config(folder, f"udpin:127.0.0.1:{port}", mavlink=mavlink)


def _proximity_healthy(gcs: GroundStation, since_ns: int) -> bool | None:
    """ArduPilot's latest word on its proximity sensor after ``since_ns`` (None: no word)."""
    statuses = gcs.of_type("SYS_STATUS", since_ns)
    if not statuses:
        return None
    return bool(statuses[-1].onboard_control_sensors_health & PROXIMITY)


@pytest.mark.timeout(300)
async def test_a_signed_daemon_restarted_three_times_feeds_a_signed_ardupilot_each_time(
    sitl_dir: Path, tmp_path: Path
) -> None:
    port = free_udp_port()
    async with ArduPilotSitl(sitl_dir, port) as sitl:
        gcs = sitl.gcs
        assert gcs is not None
        gcs.send(gcs.codec.build("SETUP_SIGNING", 1, 1, list(KEY), wall_timestamp()))
        assert await gcs.request_message_interval("SYS_STATUS", 5) == 0

        # The control: an unsigned avoidd hears the signed autopilot (it checks nothing), but
        # ArduPilot refuses its every frame, so its proximity sensor never turns healthy.
        daemon = DaemonProcess(_config(tmp_path, port, signed=False))
        try:
            await daemon.wait_line("MAVLink link up", 60)
            since_ns = time.monotonic_ns()
            assert await wait_for(lambda: len(gcs.of_type("SYS_STATUS", since_ns)) >= 20, 10)
            refused = [
                s.onboard_control_sensors_health & PROXIMITY
                for s in gcs.of_type("SYS_STATUS", since_ns)
            ]
        finally:
            assert daemon.end(signal.SIGTERM) == 0, daemon.log
        assert not any(refused), "ArduPilot took unsigned proximity data: signing is not on"

        config = _config(tmp_path, port, signed=True)
        waits_s: list[float] = []
        for signum in (signal.SIGKILL, signal.SIGTERM, signal.SIGKILL):
            daemon = DaemonProcess(config)
            try:
                started = await daemon.wait_line("avoidd started", 60)
                waits_s.append(await daemon.wait_line("MAVLink link up", 20) - started)
                since_ns = time.monotonic_ns()
                assert await wait_for(lambda t=since_ns: _proximity_healthy(gcs, t), 5.0), (
                    f"ArduPilot refused avoidd's data after start {len(waits_s)}",
                    daemon.log,
                )
            finally:
                code = daemon.end(signum)
            assert code == (-9 if signum == signal.SIGKILL else 0), daemon.log
            # Its data stops with it (ArduPilot drops proximity data older than 0.5 s), so
            # the next start must earn the healthy sensor again.
            ended_ns = time.monotonic_ns()
            assert await wait_for(lambda t=ended_ns: _proximity_healthy(gcs, t) is False, 5.0)
    print(f"signed ArduPilot: link up {', '.join(f'{w:.2f}' for w in waits_s)} s after each start")
    assert len(waits_s) == 3 and max(waits_s) <= 2.0, waits_s
