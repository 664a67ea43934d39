"""The link's send queue: bounded, one sender, HEARTBEAT and STATUSTEXT first; STATUSTEXT
coalescing by subject."""

from __future__ import annotations

import asyncio

from avoidd.config.connection import parse_connection
from avoidd.daemon import Announcer
from avoidd.mavlink import codec as mav
from avoidd.mavlink.link import MavLink
from tests.helpers import open_udp_peer, wait_for


async def test_health_jumps_the_queue_and_the_queue_is_bounded() -> None:
    peer = await open_udp_peer()
    codec = mav.Codec(1, 196)
    link = MavLink(parse_connection(f"udpout:127.0.0.1:{peer.port}"), codec, queue_size=16)
    await link.open()
    try:
        # Queue more than fits before the sender gets a turn (no await in between).
        for i in range(40):
            link.send(codec.obstacle_distance(i, [100] * 72, 20, 2000))
        link.send(codec.statustext(mav.MAV_SEVERITY_CRITICAL, "avoidd: front stale"))
        link.send(codec.heartbeat(mav.MAV_STATE_CRITICAL))
        assert await wait_for(lambda: len(peer.messages) >= 18, 5.0)
    finally:
        await link.close()
        peer.close()
    kinds = [r.message.get_type() for r in peer.messages]
    assert kinds[:2] == ["STATUSTEXT", "HEARTBEAT"]
    assert kinds[2:] == ["OBSTACLE_DISTANCE"] * 16
    # The oldest ordinary messages were dropped and counted; the newest 16 went out in order.
    assert link.dropped["OBSTACLE_DISTANCE"] == 24
    assert [m.time_usec for m in peer.of_type("OBSTACLE_DISTANCE")] == list(range(24, 40))
    # One sender: sequence numbers are consecutive.
    seqs = [r.message.get_seq() for r in peer.messages]
    assert seqs == [(seqs[0] + i) % 256 for i in range(len(seqs))]
    assert link.sent == {"STATUSTEXT": 1, "HEARTBEAT": 1, "OBSTACLE_DISTANCE": 16}


async def test_sending_while_the_link_is_down_drops_and_counts() -> None:
    codec = mav.Codec(1, 196)
    link = MavLink(parse_connection("tcp:127.0.0.1:9"), codec)  # nobody listens on port 9
    await link.open()
    try:
        link.send(codec.heartbeat(mav.MAV_STATE_ACTIVE))
        assert await wait_for(lambda: link.dropped["HEARTBEAT"] == 1, 2.0)
        assert link.sent["HEARTBEAT"] == 0
    finally:
        await link.close()


async def test_statustext_about_one_subject_keeps_only_the_latest_waiting() -> None:
    announcer = Announcer(asyncio.get_running_loop())
    announcer(2, "avoidd: front camera lost", "camera front")
    announcer(5, "avoidd: front camera back", "camera front")
    announcer(2, "avoidd: rear camera lost", "camera rear")
    announcer(2, "avoidd: front camera lost", "camera front")
    announcer(6, "avoidd started")
    announcer(6, "avoidd started")
    await asyncio.sleep(0.05)  # the calls are thread-safe: they land through the loop
    assert [text for _, text, _ in announcer.pending] == [
        "avoidd: front camera lost",
        "avoidd: rear camera lost",
        "avoidd started",
        "avoidd started",
    ]
    assert announcer.coalesced == 2
