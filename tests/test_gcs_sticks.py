"""The ground station's stick stream keeps its pace while the event loop is busy."""

from __future__ import annotations

import asyncio
import socket
import time

import pytest

from avoidd.errors import LinkError
from avoidd.mavlink import codec as mav
from avoidd.sim.gcs import GroundStation
from tests.helpers import free_udp_port


async def test_sticks_go_on_from_the_ground_stations_port_while_the_loop_is_blocked() -> None:
    # An autopilot's GCS link (a real UDP socket) says hello; the ground station (udpin)
    # learns where it is. The sticks then come from the ground station's own port (PX4 answers
    # the last sender: a second port would take its telemetry away), carry the forward stick
    # set from the test, and keep coming while the event loop is blocked for a second (a task
    # on the loop sent nothing then, and PX4 failed safe into Hold after 0.5 s).
    port = free_udp_port()
    gcs = GroundStation(f"udpin:127.0.0.1:{port}")
    await gcs.open()
    autopilot = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    autopilot.bind(("127.0.0.1", 0))
    autopilot.settimeout(5.0)
    codec = mav.Codec(1, 1)
    try:
        autopilot.sendto(codec.pack(codec.build("HEARTBEAT", 2, 12, 0, 0, 4)), ("127.0.0.1", port))
        await asyncio.sleep(0.2)  # the ground station hears it
        sticks = gcs.sticks(20.0, forward=700)
        try:
            blocked_from = time.monotonic()
            time.sleep(1.0)  # the loop does nothing for a second
            blocked_to = time.monotonic()
            sent_while_blocked = sticks.sent
            heard: list[tuple[float, mav.Message, tuple[str, int]]] = []
            while len(heard) < 200:
                data, sender = autopilot.recvfrom(4096)
                now = time.monotonic()
                heard.extend((now, m, sender) for m in codec.decode(data))
                if now > blocked_to + 0.5:
                    break
        finally:
            sticks.stop()
    finally:
        autopilot.close()
        await gcs.close()
    manual = [(m, s) for _, m, s in heard if m.get_type() == "MANUAL_CONTROL"]
    assert {s for _, s in manual} == {("127.0.0.1", port)}
    assert all(m.x == 700 and m.z == 500 and m.target == 1 for m, _ in manual)
    # 20 at 20 Hz in the blocked second; a loaded machine may delay a few.
    assert blocked_to - blocked_from >= 1.0
    assert sent_while_blocked >= 5
    assert len(manual) >= sent_while_blocked  # all of them arrived


async def test_sticks_need_an_open_udp_link() -> None:
    with pytest.raises(LinkError, match="sticks need an open UDP link"):
        GroundStation("udpin:127.0.0.1:14999").sticks()
