"""The daemon against a MAVLink peer on real sockets (UDP both ways, TCP, a pty serial line)."""

from __future__ import annotations

import asyncio
import contextlib
import os
import pty
import time
import types
from pathlib import Path

import pytest

from avoidd.mavlink import codec as mav
from avoidd.mavlink.layout import read_bins
from avoidd.mavlink.mock_autopilot import MockAutopilot
from tests.helpers import (
    MavlinkPeer,
    free_udp_port,
    open_udp_peer,
    start_daemon,
    stop_daemon,
    synthetic_config,
    wait_for,
)


async def test_udpout_messages_decode_field_by_field(tmp_path: Path) -> None:
    peer = await open_udp_peer()
    daemon, task = await start_daemon(synthetic_config(tmp_path, f"udpout:127.0.0.1:{peer.port}"))
    try:
        ok = await wait_for(
            lambda: (
                any(min(m.distances) < 2000 for m in peer.of_type("OBSTACLE_DISTANCE"))
                and len(peer.of_type("HEARTBEAT")) >= 2
            ),
            timeout_s=20.0,
        )
        assert ok, f"received {[r.message.get_type() for r in peer.messages][:20]}"
    finally:
        await stop_daemon(daemon, task)
        peer.close()

    assert peer.parse_errors == 0
    assert set(peer.raw_first_bytes) == {0xFD}  # every packet is MAVLink 2
    od = [m for m in peer.of_type("OBSTACLE_DISTANCE") if min(m.distances) < 2000][-1]
    assert od.get_srcSystem() == 7 and od.get_srcComponent() == 196
    assert od.sensor_type == 4  # MAV_DISTANCE_SENSOR_UNKNOWN
    assert len(od.distances) == 72
    assert od.increment == 0
    # Not an autopilot: the layout that keeps ArduPilot's sectors whole (bin 0 at -20 deg),
    # which any reader that follows the message definition understands.
    assert od.increment_f == 5.0
    assert od.angle_offset == -20.0
    assert od.frame == 12  # MAV_FRAME_BODY_FRD
    assert (od.min_distance, od.max_distance) == (20, 2000)
    assert 0 not in od.distances
    assert all(v == 65535 or 20 <= v <= 2001 for v in od.distances)
    scan = read_bins(od.distances, od.increment_f, od.angle_offset)
    assert scan[36] == 65535  # behind the camera: nobody sees it
    assert od.distances[40] == 65535  # which is message bin 40 (180 deg = -20 + 40 * 5)
    assert abs(od.time_usec - time.monotonic_ns() // 1000) < 30_000_000

    heartbeat = peer.of_type("HEARTBEAT")[-1]
    assert heartbeat.get_srcSystem() == 7 and heartbeat.get_srcComponent() == 196
    assert heartbeat.type == 18  # MAV_TYPE_ONBOARD_CONTROLLER
    assert heartbeat.autopilot == 8  # MAV_AUTOPILOT_INVALID
    assert heartbeat.system_status == 4  # MAV_STATE_ACTIVE
    assert heartbeat.mavlink_version == 3
    texts = [m.text for m in peer.of_type("STATUSTEXT")]
    assert "avoidd started" in texts


def _heartbeat(system_id: int) -> bytes:
    """An ArduCopter heartbeat of ``system_id`` (component 1), as bytes on the wire."""
    codec = mav.Codec(system_id, mav.MAV_COMP_ID_AUTOPILOT1)
    return codec.pack(
        codec.build("HEARTBEAT", mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4)
    )


async def test_udpin_answers_only_the_autopilot_it_adopted(tmp_path: Path) -> None:
    port = free_udp_port()
    daemon, task = await start_daemon(synthetic_config(tmp_path, f"udpin:127.0.0.1:{port}"))
    first, second = await open_udp_peer(), await open_udp_peer()
    link = daemon.link
    try:
        try:
            # Before anybody spoke there is nowhere to send: the daemon tries, and counts drops.
            assert await wait_for(
                lambda: link.dropped["HEARTBEAT"] >= 1 and link.dropped["OBSTACLE_DISTANCE"] >= 3,
                20.0,
            ), f"dropped {dict(link.dropped)}"
            assert first.transport is not None and second.transport is not None
            # A valid heartbeat of another system (the config says 7) adopts nothing: nothing
            # is sent to its sender.
            first.transport.sendto(_heartbeat(1), ("127.0.0.1", port))
            assert await wait_for(lambda: daemon.received["HEARTBEAT"] == 1, 5.0)
            dropped = link.dropped["OBSTACLE_DISTANCE"]
            assert await wait_for(lambda: link.dropped["OBSTACLE_DISTANCE"] >= dropped + 3, 10.0)
            assert sum(link.sent.values()) == 0 and first.messages == []
            # The vehicle's heartbeat: its sender is the autopilot and gets everything.
            second.transport.sendto(_heartbeat(7), ("127.0.0.1", port))
            assert await wait_for(lambda: len(second.of_type("OBSTACLE_DISTANCE")) >= 3, 10.0)
            # Another sender of the vehicle's heartbeat while the autopilot is heard: a
            # stranger, answered nothing (it cannot take the link over).
            for _ in range(3):
                first.transport.sendto(_heartbeat(7), ("127.0.0.1", port))
                second.transport.sendto(_heartbeat(7), ("127.0.0.1", port))
                await asyncio.sleep(0.3)
            heard = len(second.of_type("OBSTACLE_DISTANCE"))
            assert await wait_for(lambda: len(second.of_type("OBSTACLE_DISTANCE")) >= heard + 5, 10)
            assert first.messages == []
            assert link.strangers[f"127.0.0.1:{first.port}"].datagrams == 3
        finally:
            await stop_daemon(daemon, task)
        # Every message the daemon counts as sent reached the autopilot, and no other.
        sent = sum(link.sent.values())
        heard_all = lambda: len(second.messages)  # noqa: E731
        assert await wait_for(lambda: heard_all() == sent, 5.0), f"sent {sent}, heard {heard_all()}"
        assert first.messages == [] and second.parse_errors == 0
    finally:
        first.close()
        second.close()


class TcpPeer(MavlinkPeer):
    def __init__(self) -> None:
        super().__init__()
        self.connections = 0
        self.writers: list[asyncio.StreamWriter] = []

    async def handle(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.connections += 1
        self.writers.append(writer)
        try:
            while data := await reader.read(4096):
                self.feed(data)
        except (ConnectionError, asyncio.CancelledError):
            pass
        finally:
            writer.close()


async def test_tcp_client_sends_and_reconnects(tmp_path: Path) -> None:
    peer = TcpPeer()
    server = await asyncio.start_server(peer.handle, "127.0.0.1", 0)
    port = server.sockets[0].getsockname()[1]
    daemon, task = await start_daemon(synthetic_config(tmp_path, f"tcp:127.0.0.1:{port}"))
    try:
        assert await wait_for(lambda: len(peer.of_type("OBSTACLE_DISTANCE")) >= 3, 10.0)
        # The autopilot side goes away and comes back on the same port.
        server.close()
        for writer in peer.writers:
            writer.close()
        await server.wait_closed()
        await asyncio.sleep(0.5)
        before = len(peer.of_type("OBSTACLE_DISTANCE"))
        server = await asyncio.start_server(peer.handle, "127.0.0.1", port)
        assert await wait_for(lambda: peer.connections >= 2, 5.0)
        assert await wait_for(lambda: len(peer.of_type("OBSTACLE_DISTANCE")) > before + 3, 5.0)
    finally:
        await stop_daemon(daemon, task)
        server.close()


async def test_serial_link_over_a_pty(tmp_path: Path) -> None:
    master, slave = pty.openpty()
    device = os.ttyname(slave)
    peer = MavlinkPeer()
    loop = asyncio.get_running_loop()
    os.set_blocking(master, False)

    def readable() -> None:
        with contextlib.suppress(BlockingIOError):
            peer.feed(os.read(master, 65536))

    loop.add_reader(master, readable)
    daemon, task = await start_daemon(synthetic_config(tmp_path, f"{device},57600"))
    try:
        assert await wait_for(lambda: len(peer.of_type("OBSTACLE_DISTANCE")) >= 5, 15.0)
        assert len(peer.of_type("HEARTBEAT")) >= 1
        assert peer.parse_errors == 0
    finally:
        await stop_daemon(daemon, task)
        loop.remove_reader(master)
        os.close(master)
        os.close(slave)


@pytest.mark.parametrize("flavour", ["ardupilot", "px4"])
async def test_stale_pipeline_says_unknown_as_each_autopilot_understands(
    tmp_path: Path, flavour: str
) -> None:
    # A recording of a few frames that ends: after it, avoidd has nothing it can vouch for.
    # PX4 reads 65535 as "no data" and gets every bin unknown at the full rate; ArduPilot
    # takes such a message for a healthy sensor with a clear view, so it gets nothing and
    # reports "PRX1: No Data" itself. Both get a CRITICAL heartbeat and one STATUSTEXT.
    folder = tmp_path / "rec"
    (folder / "left").mkdir(parents=True)
    (folder / "right").mkdir()
    import cv2
    import numpy as np

    rng = np.random.default_rng(0)
    for i in range(4):
        # Texture coarser than a pixel: iid pixel noise would read as sensor noise alone.
        noise = rng.normal(128.0, 60.0, (240, 320)).astype(np.float32)
        image = np.clip(cv2.GaussianBlur(noise, (0, 0), 1.5) * 3 - 256, 0, 255).astype(np.uint8)
        cv2.imwrite(str(folder / "left" / f"{i}.png"), image)
        cv2.imwrite(str(folder / "right" / f"{i}.png"), np.roll(image, -8, axis=1))
    port = free_udp_port()
    autopilot = MockAutopilot(flavour=flavour, system_id=7)
    await autopilot.start(f"udpin:127.0.0.1:{port}")
    config = synthetic_config(
        tmp_path,
        f"udpout:127.0.0.1:{port}",
        source={"kind": "files", "path": str(folder), "fps": 10},
        pipeline={"max_age_ms": 200, "log_interval_s": 1.0},
    )
    daemon, task = await start_daemon(config)
    try:
        assert await wait_for(
            lambda: any(min(m.distances) < 2001 for m in autopilot.of_type("OBSTACLE_DISTANCE")),
            10.0,
        ), "never received fresh data"
        assert await wait_for(
            lambda: any("stale" in m.text for m in autopilot.of_type("STATUSTEXT")), 10.0
        )
        t_stale_ns = time.monotonic_ns()
        assert daemon.outputs is not None
        withheld_when_stale = daemon.outputs.withheld
        assert await wait_for(
            lambda: any(
                r.received_ns > t_stale_ns + 1_200_000_000
                for r in autopilot.recorded
                if r.message.get_type() == "HEARTBEAT"
            ),
            5.0,
        )
    finally:
        await stop_daemon(daemon, task)
        # Let the mock read what is still on its socket before it closes.
        drained = await wait_for(
            lambda: autopilot.counts["OBSTACLE_DISTANCE"] == daemon.link.sent["OBSTACLE_DISTANCE"],
            5.0,
        )
        await autopilot.stop()
    assert drained, "an OBSTACLE_DISTANCE the daemon sent never arrived"
    texts = [m.text for m in autopilot.of_type("STATUSTEXT")]
    assert "avoidd: front source ended" in texts
    assert "avoidd: front stale, camera lost" in texts
    stale_severity = [m.severity for m in autopilot.of_type("STATUSTEXT") if "stale" in m.text]
    assert stale_severity == [2]  # MAV_SEVERITY_CRITICAL, once
    late = [r for r in autopilot.recorded if r.received_ns > t_stale_ns + 200_000_000]
    late_hb = [r.message for r in late if r.message.get_type() == "HEARTBEAT"]
    assert late_hb and all(m.system_status == 5 for m in late_hb)  # MAV_STATE_CRITICAL
    late_od = [r for r in late if r.message.get_type() == "OBSTACLE_DISTANCE"]
    if flavour == "ardupilot":
        assert late_od == []
        assert daemon.outputs.withheld > 10
    else:
        assert late_od and all(set(r.message.distances) == {65535} for r in late_od)
        assert all(r.message.increment_f == 10.0 for r in late_od)  # PX4's layout
        # The rate does not drop: every tick of the send loop (paced as
        # test_send_loop_keeps_its_schedule checks) still sends, and every message arrives.
        assert daemon.outputs.withheld == withheld_when_stale
        assert daemon.link.dropped["OBSTACLE_DISTANCE"] == 0


class _Done(Exception):
    """Ends a send loop under test."""


async def test_send_loop_keeps_its_schedule(monkeypatch: pytest.MonkeyPatch) -> None:
    # The send loop on a simulated clock: each send costs 30 ms, except one that overruns by
    # half a period (caught up at once, the grid kept) and one that stalls for 350 ms (no burst
    # of catch-up sends: the grid starts over from the stall).
    from avoidd.daemon import outputs

    clock = {"s": 100.0}
    cost_s = {2: 0.15, 6: 0.35}
    calls: list[float] = []

    async def sleep(delay_s: float) -> None:
        assert delay_s >= 0.0
        clock["s"] += delay_s

    def send() -> None:
        calls.append(round(clock["s"], 6))
        clock["s"] += cost_s.get(len(calls) - 1, 0.03)
        if len(calls) == 10:
            raise _Done

    monkeypatch.setattr(outputs, "time", types.SimpleNamespace(monotonic=lambda: clock["s"]))
    monkeypatch.setattr(outputs, "asyncio", types.SimpleNamespace(sleep=sleep))
    with pytest.raises(_Done):
        await outputs.every(10.0, send)
    assert calls == [100.0, 100.1, 100.2, 100.35, 100.4, 100.5, 100.6, 100.95, 101.05, 101.15]


@pytest.mark.parametrize("kind", ["udpout", "udpin"])
async def test_nobody_listening_does_not_stop_the_daemon(tmp_path: Path, kind: str) -> None:
    connection = f"{kind}:127.0.0.1:{free_udp_port()}"
    daemon, task = await start_daemon(synthetic_config(tmp_path, connection))
    await asyncio.sleep(1.0)
    assert not task.done()
    await stop_daemon(daemon, task)


def test_codec_survives_garbage_and_finds_messages_after_it() -> None:
    from hypothesis import given, settings
    from hypothesis import strategies as st

    from avoidd.mavlink.codec import Codec

    sender = Codec(1, 196)
    good = sender.pack(sender.heartbeat(4))

    # pymavlink resynchronises after a false start by dropping the whole (false) frame, at most
    # 280 bytes for MAVLink 2: 20 heartbeats (420 bytes) after any garbage must yield the rest.
    @settings(max_examples=300, deadline=None)
    @given(st.binary(max_size=600))
    def check(noise: bytes) -> None:
        receiver = Codec(1, 1)
        receiver.decode(noise)
        decoded = [m for chunk in range(20) for m in receiver.decode(good)]
        heartbeats = [m for m in decoded if m.get_type() == "HEARTBEAT"]
        assert len(heartbeats) >= (20 * len(good) - 280) // len(good)

    check()
