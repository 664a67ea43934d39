"""Random and mutated bytes on a link never crash it; parse errors are counted."""

from __future__ import annotations

import asyncio
import itertools
import random
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from avoidd.config import MavlinkConfig
from avoidd.daemon import Daemon
from avoidd.loading import load_all
from avoidd.mavlink import codec as mav
from avoidd.mavlink.link import MavLink
from avoidd.mavlink.mock_autopilot import MockAutopilot
from avoidd.mavlink.vehicle import Vehicle
from tests.helpers import free_udp_port, synthetic_config, wait_for


def _valid_stream(seed: int) -> tuple[bytes, list[str]]:
    """A realistic stream from an autopilot: several message types, some long."""
    sender = mav.Codec(1, 1)
    rng = random.Random(seed)
    messages = []
    for i in range(12):
        kind = rng.choice(["HEARTBEAT", "ATTITUDE", "STATUSTEXT", "OBSTACLE_DISTANCE", "ACK"])
        if kind == "HEARTBEAT":
            messages.append(sender.build("HEARTBEAT", 2, 3, 81, rng.randrange(30), 4))
        elif kind == "ATTITUDE":
            messages.append(sender.build("ATTITUDE", i * 20, 0.1, -0.2, 3.0, 0.0, 0.0, 0.0))
        elif kind == "STATUSTEXT":
            messages.append(sender.statustext(6, "x" * rng.randrange(1, 50)))
        elif kind == "OBSTACLE_DISTANCE":
            messages.append(sender.obstacle_distance(i, [rng.randrange(65536)] * 72, 20, 2000))
        else:
            messages.append(sender.build("COMMAND_ACK", 511, 0, 0, 0, 1, 196))
    return b"".join(sender.pack(m) for m in messages), [m.get_type() for m in messages]


def _fresh_link() -> tuple[MavLink, Vehicle]:
    config = MavlinkConfig(connection="udpout:127.0.0.1:9", system_id="auto")
    link = MavLink(config.link, mav.Codec(1, 196))
    vehicle = Vehicle(link, config, lambda severity, text, key=None: None)
    return link, vehicle


def _feed(link: MavLink, data: bytes, cuts: list[int]) -> None:
    """Feed data in chunks cut at the given offsets, as a stream transport would."""
    edges = sorted({c % (len(data) + 1) for c in cuts} | {0, len(data)})
    for start, end in itertools.pairwise(edges):
        link._on_bytes(data[start:end])


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.binary(max_size=2000), st.lists(st.integers(0, 4000), max_size=8))
def test_random_bytes_never_crash_and_are_counted(noise: bytes, cuts: list[int]) -> None:
    link, _ = _fresh_link()
    _feed(link, noise, cuts)
    assert link.handler_errors == 0
    if len(noise) >= 300 and b"\xfd" not in noise and b"\xfe" not in noise:
        assert link.parse_errors > 0  # bytes with no frame start at all are garbage


@settings(max_examples=200, deadline=None)
@given(
    st.integers(0, 10_000),
    st.lists(
        st.tuples(
            st.sampled_from(["flip", "insert", "delete"]),
            st.integers(0, 10**6),
            st.binary(min_size=1, max_size=8),
        ),
        min_size=1,
        max_size=6,
    ),
    st.lists(st.integers(0, 4000), max_size=8),
)
def test_mutated_streams_never_crash_and_lose_only_what_was_hit(
    seed: int, mutations: list[tuple[str, int, bytes]], cuts: list[int]
) -> None:
    stream, kinds = _valid_stream(seed)
    data = bytearray(stream)
    for op, where, payload in mutations:
        at = where % max(len(data), 1)
        if op == "flip":
            data[at] ^= payload[0] or 1
        elif op == "insert":
            data[at:at] = payload
        else:
            del data[at : at + len(payload)]
    link, _ = _fresh_link()
    _feed(link, bytes(data), cuts)
    # The link survives, then decodes a clean stream that follows the damage (after at most
    # one frame's worth of resynchronisation).
    _feed(link, b"\x00" * 280 + stream, [])
    assert link.handler_errors == 0
    received = sum(link.received.values())
    assert received >= len(kinds) - 1
    if bytes(data) != stream:
        assert link.parse_errors > 0 or received < 2 * len(kinds)


def test_an_unmutated_stream_decodes_completely() -> None:
    stream, kinds = _valid_stream(1)
    link, _ = _fresh_link()
    _feed(link, stream, [5, 77, 300])
    assert sum(link.received.values()) == len(kinds)
    assert link.parse_errors == 0


@settings(max_examples=200, deadline=None)
@given(
    st.integers(0, 255),
    st.integers(0, 2**32 - 1),
    st.integers(0, 255),
    st.integers(0, 255),
    st.floats(allow_nan=True, allow_infinity=True, width=32),
    st.integers(0, 2**32 - 1),
)
def test_valid_frames_with_absurd_fields_do_not_break_the_vehicle(
    vehicle_type: int, custom_mode: int, autopilot: int, base_mode: int, angle: float, t_ms: int
) -> None:
    link, vehicle = _fresh_link()
    sender = mav.Codec(1, 1)
    frames = [
        sender.build("HEARTBEAT", vehicle_type, autopilot, base_mode, custom_mode, 4),
        sender.build("HEARTBEAT", 2, 3, base_mode, custom_mode, 4),
        sender.build("ATTITUDE", t_ms, angle, angle, angle, 0.0, 0.0, 0.0),
        sender.build("SYSTEM_TIME", t_ms * 1000, t_ms),
        sender.build("COMMAND_ACK", 511, base_mode, 0, 0, 1, 196),
        sender.distance_sensor(t_ms, 10, 4000, custom_mode % 65536, 25),
    ]
    link._on_bytes(b"".join(sender.pack(f) for f in frames))
    vehicle.tick(10**18)
    assert link.handler_errors == 0
    assert vehicle.attitude_at(10**18) is None  # nothing stale is vouched for


@pytest.mark.parametrize("kind", ["udp", "tcp", "serial"])
async def test_garbage_on_a_real_link_is_survived_and_counted(tmp_path: Path, kind: str) -> None:
    autopilot = MockAutopilot(system_id=7)
    if kind == "udp":
        port = free_udp_port()
        await autopilot.start(f"udpin:127.0.0.1:{port}")
        connection = f"udpout:127.0.0.1:{port}"
    elif kind == "tcp":
        port = free_udp_port()  # any free number; TCP and UDP ports are separate spaces
        await autopilot.start(f"tcpin:127.0.0.1:{port}")
        connection = f"tcp:127.0.0.1:{port}"
    else:
        await autopilot.start(f"pty:{tmp_path / 'ttyAP'}")
        connection = f"serial:{tmp_path / 'ttyAP'},115200"
    config, calibrations = load_all(synthetic_config(tmp_path, connection))
    daemon = Daemon(config, calibrations)
    task = asyncio.create_task(daemon.run())
    try:
        assert await wait_for(lambda: daemon.vehicle.link_up, 10.0)
        rng = random.Random(7)
        assert autopilot.transport is not None
        for _ in range(300):
            autopilot.transport.send(
                bytes(rng.randrange(256) for _ in range(rng.randrange(1, 300)))
            )
            await asyncio.sleep(0)
        heard = daemon.received["HEARTBEAT"]
        assert await wait_for(lambda: daemon.received["HEARTBEAT"] > heard + 1, 5.0)
        assert daemon.link.parse_errors > 0
        assert daemon.link.handler_errors == 0
        assert not task.done() and daemon.vehicle.link_up
    finally:
        daemon.stop()
        assert await asyncio.wait_for(task, timeout=10.0) == 0
        await autopilot.stop()
