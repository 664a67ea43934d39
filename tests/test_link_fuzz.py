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


def _valid_frames(seed: int) -> list[bytes]:
    """A realistic stream from an autopilot, frame by frame: several message types, some long."""
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
    return [sender.pack(m) for m in messages]


MAX_FRAME_BYTES = 280
"""The most a parser can take for one false start: a MAVLink 2 header that claims 255 bytes of
payload and a signature (10 + 255 + 2 + 13). Damage can cost at most this much after it."""

CLEAN_PER_GAP = 24
"""Clean frames after each damaged one (more than MAX_FRAME_BYTES of them)."""

Mutation = tuple[str, int, bytes]


def _mutate(frame: bytes, mutations: list[Mutation]) -> bytes:
    """Apply flips, insertions and deletions to one frame's bytes."""
    data = bytearray(frame)
    for op, where, payload in mutations:
        at = where % max(len(data), 1)
        if not data and op != "insert":
            continue  # deletions took the whole frame: nothing left to flip or delete
        if op == "flip":
            data[at] ^= payload[0] or 1
        elif op == "insert":
            data[at:at] = payload
        else:
            del data[at : at + len(payload)]
    return bytes(data)


def _clean_frames(sender: mav.Codec, first_id: int, count: int) -> list[tuple[int, bytes]]:
    """SYSTEM_TIME frames numbered by ``time_boot_ms``, none with a magic byte inside.

    A parser that lands in the middle of such a frame cannot take its bytes for the start of
    another one, so it skips to the next frame and loses nothing more.
    """
    frames = []
    for ident in range(first_id, first_id + count):
        for attempt in range(1, 64):
            data = sender.pack(sender.build("SYSTEM_TIME", 1_000_003 * attempt, ident))
            if 0xFD not in data[1:] and 0xFE not in data[1:]:
                frames.append((ident, data))
                break
        else:
            raise AssertionError(f"no encoding of clean frame {ident} without a magic byte")
    return frames


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


_MUTATION = st.tuples(
    st.sampled_from(["flip", "insert", "delete"]),
    st.integers(0, 10**6),
    st.binary(min_size=1, max_size=8),
)


@settings(max_examples=200, deadline=None)
@given(
    st.integers(0, 10_000),
    st.lists(st.lists(_MUTATION, max_size=3), min_size=1, max_size=6),
    st.lists(st.integers(0, 8000), max_size=8),
)
def test_damage_loses_only_the_frames_it_hit_and_what_it_swallowed(
    seed: int, damage: list[list[Mutation]], cuts: list[int]
) -> None:
    # Damaged frames (some left whole) each followed by a run of numbered clean frames. Every
    # clean frame that starts beyond one false start's reach of the damage must arrive, once
    # and in order; so must every undamaged frame; and nothing else may be made up.
    victims = _valid_frames(seed)[: len(damage)]
    clean_sender = mav.Codec(1, 1)
    stream = bytearray()
    clean_ids: list[int] = []
    must_arrive: list[int] = []
    damaged = 0
    started = 0
    survivors: set[bytes] = set()
    for index, (victim, mutations) in enumerate(zip(victims, damage, strict=True)):
        hit = _mutate(victim, mutations)
        damaged += hit != victim
        # A damaged frame that still begins with the MAVLink 2 magic is one the parser tries;
        # one whose start was cut away is bytes it skips while it looks for a frame.
        started += hit != victim and hit[:1] == victim[:1]
        if victim in hit:
            survivors.add(victim)
        stream += hit
        end = len(stream)
        for ident, frame in _clean_frames(clean_sender, index * CLEAN_PER_GAP, CLEAN_PER_GAP):
            if hit == victim or len(stream) - end >= MAX_FRAME_BYTES:
                must_arrive.append(ident)
            clean_ids.append(ident)
            stream += frame
        assert len(stream) - end > MAX_FRAME_BYTES + 40  # the next victim starts in sync
    link, _ = _fresh_link()
    decoded: list[mav.Message] = []
    link.subscribe(lambda message, _ns: decoded.append(message))
    _feed(link, bytes(stream), cuts)

    assert link.handler_errors == 0
    arrived = [m.time_boot_ms for m in decoded if m.get_type() == "SYSTEM_TIME"]
    assert arrived == sorted(set(arrived)), "a clean frame arrived twice or out of order"
    assert set(arrived) <= set(clean_ids)
    missing = sorted(set(must_arrive) - set(arrived))
    assert not missing, f"clean frames {missing} lost although no damage could reach them"
    if damaged == 0:
        assert arrived == clean_ids
    # pymavlink cannot check the CRC of a message id it does not know (it lacks its CRC
    # extra), so damage that makes up such an id passes as UNKNOWN_n: only known ids count.
    known = [m for m in decoded if not m.get_type().startswith("UNKNOWN_")]
    others = [bytes(m.get_msgbuf()) for m in known if m.get_type() != "SYSTEM_TIME"]
    assert len(others) == len(set(others)) and set(others) <= survivors
    whole = [v for v, m in zip(victims, damage, strict=True) if not m]
    assert set(whole) <= set(others), "an undamaged frame was lost"
    # Each damaged frame the parser tried leaves something counted: bad bytes, or an id made
    # up.
    made_up = len(decoded) - len(known)
    assert link.parse_errors + link.signature_rejects + made_up >= started


def test_an_unmutated_stream_decodes_completely() -> None:
    frames = _valid_frames(1)
    link, _ = _fresh_link()
    _feed(link, b"".join(frames), [5, 77, 300])
    assert sum(link.received.values()) == len(frames)
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
