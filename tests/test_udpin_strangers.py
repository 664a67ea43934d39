"""A ``udpin`` link belongs to its autopilot: strangers on the port get nothing and change nothing.

Real sockets on 127.0.0.1: the mock autopilot sends to avoidd's ``udpin`` port (``udpout``), as
ArduPilot SITL's SERIAL1 does, and a stray socket sends garbage and forged messages to the same
port.
"""

from __future__ import annotations

import asyncio
import logging
import random
from pathlib import Path

import pytest

from avoidd.config import MavlinkConfig
from avoidd.mavlink import codec as mav
from avoidd.mavlink import link as link_module
from avoidd.mavlink.link import MAX_STRANGERS, MavLink
from avoidd.mavlink.mock_autopilot import MockAutopilot
from avoidd.mavlink.vehicle import Vehicle
from tests.helpers import free_udp_port, open_udp_peer, synthetic_config, wait_for
from tests.helpers import start_daemon as start
from tests.helpers import stop_daemon as stop

GARBAGE_HZ = 100
GARBAGE_S = 5.0
LAND = 9  # ArduCopter's LAND custom mode


def _garbage(rng: random.Random) -> bytes:
    """Random bytes; most start like a MAVLink 2 frame announcing a long payload."""
    body = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 120)))
    if rng.random() < 0.7:
        return b"\xfd\xff" + body  # a shared parser would wait for 267 more bytes
    return body.replace(b"\x00", b"\xfd")


def _forged(t_ms: int) -> list[bytes]:
    """What a stranger forging the autopilot (system 7, component 1) would send."""
    forger = mav.Codec(7, mav.MAV_COMP_ID_AUTOPILOT1)
    base = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    heartbeat = forger.build(
        "HEARTBEAT", mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_ARDUPILOTMEGA, base, LAND, 4
    )
    attitude = forger.build("ATTITUDE", t_ms, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0)
    return [forger.pack(heartbeat), forger.pack(attitude)]


async def test_a_stranger_gets_nothing_and_its_garbage_cannot_take_the_link_down(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    port = free_udp_port()
    daemon, task = await start(synthetic_config(tmp_path, f"udpin:127.0.0.1:{port}"))
    stray = await open_udp_peer()
    autopilot = MockAutopilot(system_id=7, mode="GUIDED")
    rng = random.Random(21)
    assert stray.transport is not None
    try:
        # Once its link is open (it tries to send, and drops: nobody to send to yet).
        assert await wait_for(lambda: daemon.link.dropped["HEARTBEAT"] >= 1, 20.0)
        # Garbage before anyone else spoke: it does not make the stray the reply address.
        for _ in range(20):
            stray.transport.sendto(_garbage(rng), ("127.0.0.1", port))
        await autopilot.start(f"udpout:127.0.0.1:{port}")
        vehicle = daemon.vehicle
        assert await wait_for(lambda: vehicle.link_up and vehicle.streams_acknowledged, 10.0)
        assert await wait_for(lambda: len(autopilot.of_type("OBSTACLE_DISTANCE")) >= 3, 10.0)
        assert daemon.link.autopilot_sender is not None
        assert daemon.link.autopilot_sender[1] == autopilot.transport.local_port  # type: ignore[union-attr]

        caplog.set_level(logging.INFO, logger="avoidd.mavlink.link")
        before = {kind: autopilot.sent[kind] for kind in ("HEARTBEAT", "ATTITUDE")}
        outputs = len(autopilot.of_type("OBSTACLE_DISTANCE"))
        datagrams = forged = 0
        link_down = 0
        for tick in range(round(GARBAGE_S * GARBAGE_HZ)):
            stray.transport.sendto(_garbage(rng), ("127.0.0.1", port))
            datagrams += 1
            if tick % 10 == 0:
                for frame in _forged(tick):
                    stray.transport.sendto(frame, ("127.0.0.1", port))
                    datagrams += 1
                    forged += 1
            link_down += not vehicle.link_up
            await asyncio.sleep(1.0 / GARBAGE_HZ)
        assert link_down == 0 and vehicle.link_up
        assert autopilot.sent["HEARTBEAT"] - before["HEARTBEAT"] >= 3
        # The autopilot falls silent. Once what it sent has landed, avoidd has heard exactly
        # the heartbeats and attitudes it sent, no fewer (garbage on another address swallowed
        # none of them; a shared parser lost most) and no more (no forged one was taken for
        # the autopilot's). Whole counts at rest: a message still in flight at either end of
        # a window would make a count of the window one off.
        await autopilot.stop()
        kinds = tuple(before)
        assert await wait_for(
            lambda: all(daemon.received[k] >= autopilot.sent[k] for k in kinds), 5.0
        ), ({k: daemon.received[k] for k in kinds}, autopilot.sent)
        await asyncio.sleep(0.2)  # anything more would have landed by now
        assert all(daemon.received[k] == autopilot.sent[k] for k in kinds), (
            {k: daemon.received[k] for k in kinds},
            autopilot.sent,
        )
        assert vehicle.mode is not None and vehicle.mode.name == "GUIDED"
        assert all(abs(a.roll_rad) < 0.5 for a in vehicle.attitude._samples)
        assert vehicle.reboots == 0  # the forged boot clock never went back
        # Avoidd kept talking to the autopilot, and never to the stray.
        assert len(autopilot.of_type("OBSTACLE_DISTANCE")) > outputs
        assert stray.raw == []
        # What the stray sent is counted, and it was named once in the log.
        name = f"127.0.0.1:{stray.port}"
        assert await wait_for(lambda: daemon.link.strangers[name].datagrams == datagrams, 5.0)
        count = daemon.link.strangers[name]
        assert count.bytes > datagrams
        assert forged > 0 and not hasattr(count, "messages")  # nothing of it is decoded
        assert list(daemon.link.strangers) == [name]
        named = [r for r in caplog.records if name in r.getMessage()]
        assert len(named) == 1 and "not the autopilot" in named[0].getMessage()
    finally:
        await stop(daemon, task)
        await autopilot.stop()
        stray.close()


async def test_an_autopilot_back_on_a_new_port_is_accepted_after_the_link_timeout(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    port = free_udp_port()
    config = synthetic_config(tmp_path, f"udpin:127.0.0.1:{port}", mavlink={"link_timeout_s": 1.0})
    daemon, task = await start(config)
    first = MockAutopilot(system_id=7)
    second = MockAutopilot(system_id=7)
    caplog.set_level(logging.INFO, logger="avoidd.mavlink.link")
    try:
        await first.start(f"udpout:127.0.0.1:{port}")
        assert await wait_for(lambda: len(first.of_type("OBSTACLE_DISTANCE")) >= 3, 10.0)
        old = daemon.link.autopilot_sender
        # Both speak at once: the newcomer is a stranger while the autopilot is alive.
        await second.start(f"udpout:127.0.0.1:{port}")
        assert await wait_for(lambda: daemon.link.strangers, 5.0)
        assert second.recorded == [] and daemon.link.autopilot_sender == old
        # The autopilot restarts on the new port: after the link timeout it is accepted.
        await first.stop()
        assert await wait_for(lambda: len(second.of_type("OBSTACLE_DISTANCE")) >= 3, 10.0)
        assert daemon.link.autopilot_sender is not None
        assert daemon.link.autopilot_sender != old
        assert daemon.vehicle.link_up
        assert "the autopilot now speaks from" in caplog.text
    finally:
        await stop(daemon, task)
        await first.stop()
        await second.stop()


def test_strangers_are_counted_in_a_bounded_table_and_logged_sparingly(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    clock = {"ns": 10**12}
    monkeypatch.setattr(link_module.time, "monotonic_ns", lambda: clock["ns"])
    config = MavlinkConfig(connection="udpin:127.0.0.1:9", system_id=7)
    link = MavLink(config.link, mav.Codec(7, 196))
    vehicle = Vehicle(link, config, lambda severity, text, key=None: None)
    autopilot = mav.Codec(7, 1)
    heartbeat = autopilot.build(
        "HEARTBEAT", mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4
    )
    home = ("10.0.0.1", 5760)
    caplog.set_level(logging.INFO, logger="avoidd.mavlink.link")
    link._on_bytes(autopilot.pack(heartbeat), home)
    assert vehicle.link_up and link.autopilot_sender == home
    # 200 strangers, each sending 10 datagrams, over 160 s while the autopilot keeps talking.
    for second in range(160):
        clock["ns"] += 1_000_000_000
        link._on_bytes(autopilot.pack(heartbeat), home)
        for stranger in range(200):
            if stranger * 150 // 200 <= second < stranger * 150 // 200 + 10:
                link._on_bytes(b"\xfd\xff" + bytes(30), ("10.0.0.2", 1000 + stranger))
    assert len(link.strangers) == MAX_STRANGERS + 1
    assert sum(c.datagrams for c in link.strangers.values()) == 2000
    assert link.strangers["others"].datagrams == (200 - MAX_STRANGERS) * 10
    messages = [r.getMessage() for r in caplog.records]
    assert sum("is not the autopilot" in m for m in messages) == MAX_STRANGERS
    summaries = [m for m in messages if "ignored" in m and "strangers in the last" in m]
    assert len(summaries) == 2  # 160 s: at most one per 60 s
    assert link.received["HEARTBEAT"] == 161
    assert link.parse_errors == 0  # the strangers' garbage is theirs, not the link's
