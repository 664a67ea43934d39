"""avoidd against the mock autopilot over real sockets and a pty: discovery, modes, streams,
attitude, clocks, health, reconnects, loop lag and signing."""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import json
import logging
import math
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from avoidd.daemon import Daemon
from avoidd.looplag import LagMonitor
from avoidd.mavlink import codec as mav
from avoidd.mavlink.mock_autopilot import MockAutopilot
from tests.helpers import REPO, free_udp_port, synthetic_config, wait_for
from tests.helpers import start_daemon as start
from tests.helpers import stop_daemon as stop

KEY = bytes(range(1, 33))


async def udp_pair(
    tmp_path: Path, autopilot: MockAutopilot, **mavlink: Any
) -> tuple[Daemon, asyncio.Task[int]]:
    """The mock autopilot listening on UDP and the daemon sending to it."""
    port = free_udp_port()
    await autopilot.start(f"udpin:127.0.0.1:{port}")
    return await start(synthetic_config(tmp_path, f"udpout:127.0.0.1:{port}", mavlink=mavlink))


def free_tcp_port() -> int:
    import socket

    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


@pytest.mark.parametrize(
    ("flavour", "mode", "transport"),
    [("ardupilot", "GUIDED", "udp"), ("px4", "OFFBOARD", "tcp")],
)
async def test_discovery_modes_and_stream_requests(
    tmp_path: Path, flavour: str, mode: str, transport: str
) -> None:
    autopilot = MockAutopilot(flavour=flavour, system_id=42, mode=mode, armed=True)
    if transport == "udp":
        port = free_udp_port()
        await autopilot.start(f"udpin:127.0.0.1:{port}")
        connection = f"udpout:127.0.0.1:{port}"
    else:
        port = free_tcp_port()
        await autopilot.start(f"tcpin:127.0.0.1:{port}")
        connection = f"tcp:127.0.0.1:{port}"
    config = synthetic_config(tmp_path, connection, mavlink={"system_id": "auto"})
    daemon, task = await start(config)
    try:
        vehicle = daemon.vehicle
        assert vehicle is not None
        assert await wait_for(lambda: vehicle.link_up and vehicle.streams_acknowledged, 10.0)
        assert vehicle.system_id == 42
        assert vehicle.mode is not None
        assert (vehicle.mode.autopilot, vehicle.mode.name) == (
            "PX4" if flavour == "px4" else "ArduPilot",
            mode,
        )
        assert vehicle.mode.armed and vehicle.mode.guided
        # Mode changes and disarming are followed.
        autopilot.mode = "LAND" if flavour == "px4" else "LOITER"
        autopilot.armed = False
        assert await wait_for(
            lambda: vehicle.mode is not None and vehicle.mode.name == autopilot.mode, 3.0
        )
        assert not vehicle.mode.armed and not vehicle.mode.guided
        # avoidd speaks as the vehicle's system, and the autopilot hears a STATUSTEXT.
        assert await wait_for(lambda: len(autopilot.of_type("OBSTACLE_DISTANCE")) >= 3, 10.0)
        # (Before it heard the autopilot, avoidd spoke as system 1, the default.)
        assert {m.get_srcSystem() for m in autopilot.of_type("OBSTACLE_DISTANCE")[-3:]} == {42}
        texts = [m.text for m in autopilot.of_type("STATUSTEXT")]
        assert f"avoidd: link up, {vehicle.mode.autopilot} {mode}" in texts
        # Stream requests: SET_MESSAGE_INTERVAL to 42/1 for each stream at the configured rate.
        requests = {
            int(m.param1): m.param2
            for m in autopilot.of_type("COMMAND_LONG")
            if m.command == mav.MAV_CMD_SET_MESSAGE_INTERVAL
        }
        assert requests == {30: 20_000, 32: 100_000, 132: 100_000, 2: 1_000_000}
        assert all(
            (m.target_system, m.target_component) == (42, 1)
            for m in autopilot.of_type("COMMAND_LONG")
        )
        # The autopilot streams at the asked interval and every ATTITUDE it sent reaches
        # avoidd. (The rate they arrive at on a given machine is a benchmark's figure:
        # `avoidd bench-link --asked`.)
        assert autopilot.streams[30] == pytest.approx(0.02)
        assert await wait_for(lambda: autopilot.sent["ATTITUDE"] >= 100, 30.0)
        sent = autopilot.sent["ATTITUDE"]
        assert await wait_for(lambda: daemon.received["ATTITUDE"] >= sent, 10.0)
        assert daemon.received["ATTITUDE"] <= autopilot.sent["ATTITUDE"]
        assert vehicle.rangefinder is not None and vehicle.rangefinder.distance_m == 1.5
        assert vehicle.position is not None and vehicle.position.down_m == -1.5
        assert daemon.link.parse_errors == 0
    finally:
        await stop(daemon, task)
        await autopilot.stop()


async def test_attitude_history_and_clocks_match_the_autopilot(tmp_path: Path) -> None:
    autopilot = MockAutopilot(system_id=7)
    daemon, task = await udp_pair(tmp_path, autopilot)
    try:
        vehicle = daemon.vehicle
        assert vehicle is not None
        assert await wait_for(lambda: len(vehicle.attitude) > 60, 10.0)
        # Same machine, same monotonic clock: the autopilot's boot clock is ours minus boot_ns.
        assert vehicle.clock.offset_ns is not None
        error_ms = (vehicle.clock.offset_ns + autopilot.boot_ns) / 1e6
        assert -2.0 <= error_ms <= 0.1, error_ms
        now_ns = time.monotonic_ns()
        errors = []
        for back_ms in range(30, 600, 7):
            t_ns = now_ns - back_ms * 1_000_000
            attitude = vehicle.attitude_at(t_ns)
            assert attitude is not None
            roll, pitch, yaw = autopilot.attitude((t_ns - autopilot.boot_ns) / 1e9)
            errors += [
                abs(attitude.roll_rad - roll),
                abs(attitude.pitch_rad - pitch),
                abs(math.remainder(attitude.yaw_rad - yaw, math.tau)),
            ]
        # Rates up to 0.5 rad/s and 1 ms stamps: a few milliradians at most.
        assert max(errors) < 0.003, max(errors)
    finally:
        await stop(daemon, task)
        await autopilot.stop()


async def test_time_usec_is_the_capture_time_and_never_goes_back(tmp_path: Path) -> None:
    # Neither ArduPilot nor PX4 reads time_usec (both time the data from its arrival); avoidd
    # stamps the scan's capture time on its own monotonic clock (time since the companion
    # booted), whatever the autopilot's clocks do: it used to switch from avoidd's clock to
    # the autopilot's boot clock and then to UTC in the first second, once going back.
    autopilot = MockAutopilot(system_id=7)
    autopilot.boot_ns -= 3_600_000_000_000  # booted an hour before us, and it has UTC
    started_us = time.monotonic_ns() // 1000
    daemon, task = await udp_pair(tmp_path, autopilot)
    try:
        assert await wait_for(lambda: daemon.received["SYSTEM_TIME"] >= 1, 10.0)
        assert await wait_for(lambda: len(autopilot.of_type("OBSTACLE_DISTANCE")) >= 20, 10.0)
        stamps = [m.time_usec for m in autopilot.of_type("OBSTACLE_DISTANCE")]
        now_us = time.monotonic_ns() // 1000
        assert all(b >= a for a, b in itertools.pairwise(stamps))
        assert started_us <= stamps[0] and stamps[-1] <= now_us
        assert now_us - stamps[-1] < daemon.config.pipeline.max_age_ms * 1000 + 200_000
    finally:
        await stop(daemon, task)
        await autopilot.stop()


async def test_refused_and_unanswered_stream_requests(tmp_path: Path) -> None:
    autopilot = MockAutopilot(system_id=7, refuse={"DISTANCE_SENSOR"})
    daemon, task = await udp_pair(tmp_path, autopilot)
    try:
        vehicle = daemon.vehicle
        assert vehicle is not None
        assert await wait_for(lambda: vehicle.streams_acknowledged, 10.0)
        state = {r.name: (r.acked, r.refused) for r in vehicle.requests}
        assert state["DISTANCE_SENSOR"] == (False, True)
        assert state["ATTITUDE"] == (True, False)
        # The autopilot goes deaf to commands: after a reboot-like link loss, avoidd retries.
        autopilot.acknowledge = False
        for request in vehicle.requests:
            request.acked = False
        vehicle.requests[0].attempts = 0
        await asyncio.sleep(3.5)
        assert vehicle.requests[0].attempts >= 1
        assert sum(r.attempts for r in vehicle.requests) >= 3
        assert not vehicle.streams_acknowledged
    finally:
        await stop(daemon, task)
        await autopilot.stop()


async def test_a_quick_reboot_within_the_link_timeout_gets_the_streams_back(
    tmp_path: Path,
) -> None:
    # The heartbeat never stops long enough for the link to go down, so only the requested
    # streams falling silent (and the boot clock going back) show the reboot.
    autopilot = MockAutopilot(system_id=7)
    daemon, task = await udp_pair(tmp_path, autopilot, link_timeout_s=3.0)
    try:
        vehicle = daemon.vehicle
        assert await wait_for(lambda: vehicle.link_up and vehicle.streams_acknowledged, 10.0)
        assert await wait_for(lambda: len(vehicle.attitude) > 20, 5.0)
        requests_before = sum(int(m.param1) == 30 for m in autopilot.of_type("COMMAND_LONG"))
        rebooted_ns = time.monotonic_ns()
        autopilot.reboot()
        assert await wait_for(lambda: vehicle.reboots == 1, 3.0)
        assert vehicle.link_up  # it never went down
        # ATTITUDE flows again, and what avoidd knows is from after the reboot.
        assert await wait_for(
            lambda: (
                vehicle.streams_acknowledged
                and vehicle.attitude_at(time.monotonic_ns() - 20_000_000) is not None
            ),
            3.0,
        )
        back_s = (time.monotonic_ns() - rebooted_ns) / 1e9
        requests_after = sum(int(m.param1) == 30 for m in autopilot.of_type("COMMAND_LONG"))
        assert requests_after > requests_before
        texts = [m.text for m in autopilot.of_type("STATUSTEXT")]
        assert "avoidd: autopilot rebooted" in texts
        print(f"streams back {back_s:.2f} s after the reboot")
        assert back_s < 3.0
    finally:
        await stop(daemon, task)
        await autopilot.stop()


async def test_a_stream_accepted_and_then_forgotten_is_asked_for_again(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    # An autopilot that reboots between acknowledging ATTITUDE and sending it has forgotten
    # the request; the other streams deliver, so nothing looks like a reboot.
    caplog.set_level(logging.INFO, logger="avoidd.mavlink.vehicle")
    autopilot = MockAutopilot(system_id=7, forget_once={"ATTITUDE"})
    daemon, task = await udp_pair(tmp_path, autopilot, link_timeout_s=3.0)
    try:
        vehicle = daemon.vehicle
        assert await wait_for(lambda: vehicle.link_up and vehicle.streams_acknowledged, 10.0)
        assert not autopilot.forget_once  # the first ATTITUDE request was accepted, then lost
        assert await wait_for(lambda: len(vehicle.attitude) > 5, 10.0)
        requests = [m for m in autopilot.of_type("COMMAND_LONG") if int(m.param1) == 30]
        assert len(requests) >= 2
        assert vehicle.quiet_streams >= 1 and vehicle.reboots == 0
        said = [r.getMessage() for r in caplog.records if "never sent" in r.getMessage()]
        assert said and "ATTITUDE" in said[0]
    finally:
        await stop(daemon, task)
        await autopilot.stop()


async def test_link_down_and_up_are_reported(tmp_path: Path) -> None:
    autopilot = MockAutopilot(system_id=7)
    daemon, task = await udp_pair(tmp_path, autopilot, link_timeout_s=1.0)
    try:
        vehicle = daemon.vehicle
        assert vehicle is not None
        assert await wait_for(lambda: vehicle.link_up, 10.0)
        assert autopilot._task is not None
        autopilot._task.cancel()  # the autopilot stops talking (still listening)
        assert await wait_for(lambda: not vehicle.link_up, 3.0)
        assert await wait_for(
            lambda: "avoidd: link down" in [m.text for m in autopilot.of_type("STATUSTEXT")], 3.0
        )
        autopilot._task = asyncio.create_task(autopilot._run())
        assert await wait_for(lambda: vehicle.link_up, 3.0)
        ups = [m.text for m in autopilot.of_type("STATUSTEXT") if "link up" in m.text]
        assert await wait_for(
            lambda: len([m for m in autopilot.of_type("STATUSTEXT") if "link up" in m.text]) == 2,
            3.0,
        ), ups
        # Streams are asked for again: a rebooted autopilot has forgotten them.
        assert await wait_for(lambda: vehicle.streams_acknowledged, 5.0)
        commands = autopilot.of_type("COMMAND_LONG")
        assert sum(int(m.param1) == 30 for m in commands) >= 2
    finally:
        await stop(daemon, task)
        await autopilot.stop()


async def _mock_process(connection: str, *extra: str) -> asyncio.subprocess.Process:
    return await asyncio.create_subprocess_exec(
        sys.executable,
        "-m",
        "avoidd",
        "--log-level=WARNING",
        "mock-autopilot",
        connection,
        "--duration=60",
        "--system-id=7",
        *extra,
        cwd=REPO,
    )


async def _kill(process: asyncio.subprocess.Process) -> None:
    with contextlib.suppress(ProcessLookupError):
        process.kill()
    await process.wait()


@pytest.mark.parametrize("kind", ["tcp", "serial"])
async def test_reconnect_within_two_seconds_and_the_loop_never_blocks(
    tmp_path: Path, kind: str
) -> None:
    if kind == "tcp":
        port = free_tcp_port()
        mock_connection = f"tcpin:127.0.0.1:{port}"
        connection = f"tcp:127.0.0.1:{port}"
    else:
        link_path = tmp_path / "ttyAP"
        mock_connection = f"pty:{link_path}"
        connection = f"serial:{link_path},115200"
    daemon, task = await start(
        synthetic_config(tmp_path, connection, mavlink={"link_timeout_s": 1.0})
    )
    process = await _mock_process(mock_connection)
    lag = LagMonitor()
    lag_task = asyncio.create_task(lag.run())
    back_s: list[float] = []
    try:
        vehicle = daemon.vehicle
        assert await wait_for(lambda: vehicle.link_up, 15.0)
        lag.reset()  # from here on: links dropping, reconnecting and coming back up
        for _ in range(3):
            await _kill(process)  # the autopilot goes away...
            assert await wait_for(lambda: not daemon.link.connected, 5.0)
            assert await wait_for(lambda: not vehicle.link_up, 5.0)
            await asyncio.sleep(0.7)
            assert not task.done()  # ...and avoidd keeps running
            heard = daemon.received["HEARTBEAT"]
            returned_s = time.monotonic()
            process = await _mock_process(mock_connection)  # ...and comes back
            assert await wait_for(lambda: daemon.link.connected, 10.0)
            back_s.append(time.monotonic() - returned_s)
            # Bytes flow again (the mock heartbeats once a second, so this takes up to 1 s).
            assert await wait_for(lambda h=heard: daemon.received["HEARTBEAT"] > h, 5.0)
        assert await wait_for(lambda: vehicle.link_up and vehicle.streams_acknowledged, 5.0)
    finally:
        lag_task.cancel()
        await _kill(process)
        await stop(daemon, task)
    startup_s = await _mock_startup_s()
    print(
        f"{kind}: link back {[round(s, 2) for s in back_s]} s after the peer was started, "
        f"whose own start-up takes {startup_s:.2f} s; max loop lag {lag.max_lag_ms:.1f} ms, "
        f"{lag.max_own_lag_ms:.1f} ms of it not waiting for a CPU, over {lag.samples} wake-ups; "
        f"the worst: {lag.worst.describe() if lag.worst else 'none'}"
    )
    assert max(back_s) - startup_s < 2.0, (back_s, startup_s)
    assert lag.samples > 100
    # The loop never blocks: of each wake-up's lateness, what is left after the time our
    # threads waited for a CPU (another process's load, not ours) and the garbage collector's
    # pauses (whose length follows this test process's heap, the whole suite's) stays small.
    # A blocking connect or read in the loop would show here in full (tests/test_looplag.py).
    assert lag.accounted
    assert lag.max_own_lag_ms <= 20.0


async def _mock_startup_s() -> float:
    """How long the mock autopilot process takes to start and speak (subtracted above)."""
    port = free_udp_port()
    received = asyncio.Event()

    class Listener(asyncio.DatagramProtocol):
        def datagram_received(self, data: bytes, addr: Any) -> None:
            received.set()

    loop = asyncio.get_running_loop()
    transport, _ = await loop.create_datagram_endpoint(Listener, local_addr=("127.0.0.1", port))
    started = time.monotonic()
    process = await _mock_process(f"udpout:127.0.0.1:{port}")
    try:
        await asyncio.wait_for(received.wait(), 10.0)
        return time.monotonic() - started
    finally:
        transport.close()
        await _kill(process)


@pytest.mark.parametrize("peer_key", ["same", "wrong", "none"])
async def test_signing(tmp_path: Path, peer_key: str) -> None:
    key_file = tmp_path / "signing.key"
    key_file.write_text(KEY.hex())
    stamp = tmp_path / "signing-timestamp"
    autopilot_key = {"same": KEY, "wrong": bytes(32), "none": None}[peer_key]
    autopilot = MockAutopilot(system_id=5, mode="GUIDED", key=autopilot_key)
    signing = {"key_file": str(key_file), "timestamp_file": str(stamp)}
    daemon, task = await udp_pair(tmp_path, autopilot, system_id="auto", signing=signing)
    try:
        vehicle = daemon.vehicle
        assert vehicle is not None
        if peer_key == "same":
            assert await wait_for(lambda: vehicle.link_up and vehicle.streams_acknowledged, 10.0)
            assert vehicle.system_id == 5
            assert daemon.link.signature_rejects == 0
        else:
            await asyncio.sleep(3.0)
            # Nothing it said was acted on: no discovery, no mode, no streams, no clock.
            assert vehicle.system_id is None and vehicle.mode is None
            assert not vehicle.link_up and len(vehicle.attitude) == 0
            assert daemon.link.signature_rejects >= 2
            assert daemon.link.received["HEARTBEAT"] == 0
        # An unsigned RADIO_STATUS is on the default allow-list and still gets through.
        radio = mav.Codec(5, 68)
        assert autopilot.transport is not None
        autopilot.transport.send(radio.pack(radio.build("RADIO_STATUS", 200, 180, 90, 10, 5, 0, 0)))
        assert await wait_for(lambda: daemon.received["RADIO_STATUS"] == 1, 3.0)
        # avoidd signs everything it sends: the keyed mock decodes it, an unkeyed one rejects.
        if peer_key == "same":
            assert len(autopilot.of_type("OBSTACLE_DISTANCE")) > 0
            assert autopilot.codec.signature_rejects == 0
        elif peer_key == "wrong":
            assert autopilot.of_type("OBSTACLE_DISTANCE") == []
            assert autopilot.codec.signature_rejects > 0
    finally:
        await stop(daemon, task)
        await autopilot.stop()
    stored = json.loads(stamp.read_text())["timestamp"]
    assert stored == daemon.codec.signing_timestamp  # the one in use, written at stop
