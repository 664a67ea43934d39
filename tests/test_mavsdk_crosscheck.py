"""An independent decoder: MAVSDK (the C++ library, in-process through the ``mavsdk`` package)
reads avoidd's bytes and must get the same fields as pymavlink."""

from __future__ import annotations

import asyncio
import json
import threading
import time
from pathlib import Path
from typing import Any

import pytest

from avoidd.daemon import Daemon
from avoidd.loading import load_all
from avoidd.mavlink import codec as mav
from tests.helpers import MavlinkPeer, open_udp_peer, synthetic_config, wait_for


class MavsdkDecoder:
    """MAVSDK on a raw:// connection: bytes in, decoded messages (as JSON fields) out."""

    def __init__(self) -> None:
        from mavsdk import ComponentType, Configuration, Mavsdk

        self._sdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
        assert int(self._sdk.add_any_connection("raw://")) == 0  # ConnectionResult.SUCCESS
        self.messages: list[Any] = []
        self._lock = threading.Lock()
        self._direct: Any = None

    def feed(self, data: bytes) -> None:
        self._sdk.pass_received_raw_bytes(data)

    def subscribe(self, timeout_s: float = 5.0) -> None:
        from mavsdk.plugins.mavlink_direct import MavlinkDirect

        deadline = time.monotonic() + timeout_s
        while not self._sdk.get_systems():
            assert time.monotonic() < deadline, "MAVSDK discovered no system"
            time.sleep(0.02)
        self._direct = MavlinkDirect(self._sdk.get_systems()[0])
        self._direct.subscribe_message("", self._on_message)

    def _on_message(self, message: Any, _user_data: Any) -> None:
        with self._lock:
            self.messages.append(message)

    def of_type(self, name: str) -> list[Any]:
        with self._lock:
            return [m for m in self.messages if m.message_name == name]

    def close(self) -> None:
        self._sdk.destroy()


def _same(pymav: Any, fields: dict[str, Any], names: list[str]) -> None:
    for name in names:
        ours = getattr(pymav, name)
        theirs = fields[name]
        if isinstance(ours, float):
            assert theirs == pytest.approx(ours, rel=1e-6, abs=1e-9), name
        elif isinstance(ours, list | tuple):
            assert list(theirs) == pytest.approx(list(ours)), name
        else:
            assert theirs == ours, name


async def test_obstacle_distance_from_the_daemon_decodes_identically(tmp_path: Path) -> None:
    peer = await open_udp_peer()
    config, calibrations = load_all(synthetic_config(tmp_path, f"udpout:127.0.0.1:{peer.port}"))
    daemon = Daemon(config, calibrations)
    task = asyncio.create_task(daemon.run())
    try:
        assert await wait_for(
            lambda: sum(min(m.distances) < 2000 for m in peer.of_type("OBSTACLE_DISTANCE")) >= 5,
            20.0,
        )
    finally:
        daemon.stop()
        assert await asyncio.wait_for(task, timeout=10.0) == 0
        peer.close()

    decoder = MavsdkDecoder()
    try:
        # A heartbeat first, so that MAVSDK discovers avoidd's system and we can subscribe.
        first_heartbeat = next(
            i for i, r in enumerate(peer.messages) if r.message.get_type() == "HEARTBEAT"
        )
        decoder.feed(peer.raw[first_heartbeat])
        decoder.subscribe()
        for datagram in peer.raw:
            decoder.feed(datagram)
        expected = peer.of_type("OBSTACLE_DISTANCE")
        assert await wait_for(
            lambda: len(decoder.of_type("OBSTACLE_DISTANCE")) >= len(expected) - 3, 5.0
        )
        decoded = decoder.of_type("OBSTACLE_DISTANCE")
    finally:
        decoder.close()
    # Match by time_usec, which is unique per message; MAVSDK may miss the first few while
    # it sets up, never a later one.
    by_time = {json.loads(m.fields_json)["time_usec"]: m for m in decoded}
    compared = 0
    for message in expected:
        if message.time_usec not in by_time:
            continue
        other = by_time[message.time_usec]
        assert (other.system_id, other.component_id) == (7, 196)
        _same(
            message,
            json.loads(other.fields_json),
            [
                "time_usec",
                "sensor_type",
                "distances",
                "increment",
                "min_distance",
                "max_distance",
                "increment_f",
                "angle_offset",
                "frame",
            ],
        )
        compared += 1
    assert compared >= len(expected) - 3
    assert any(min(m.distances) < 2000 for m in expected)


def test_distance_sensor_from_the_codec_decodes_identically() -> None:
    # The daemon sends DISTANCE_SENSOR once the perception work (issue 4) produces it; it will
    # be built by this codec method, checked here field by field, extensions included.
    codec = mav.Codec(7, 196)
    messages = [
        codec.distance_sensor(123_456, 20, 2000, 537, 0, 1.2, 0.9, (1.0, 0.0, 0.0, 0.0), 87, 0),
        codec.distance_sensor(123_500, 20, 2000, 2001, 2, 1.2, 0.9, (0.707, 0.0, 0.0, 0.707), 0, 1),
        codec.distance_sensor(123_600, 10, 4000, 150, mav.MAV_SENSOR_ROTATION_PITCH_270),
    ]
    decoder = MavsdkDecoder()
    peer = MavlinkPeer()
    try:
        decoder.feed(codec.pack(codec.heartbeat(mav.MAV_STATE_ACTIVE)))
        decoder.subscribe()
        for message in messages:
            data = codec.pack(message)
            peer.feed(data)
            decoder.feed(data)
        deadline = time.monotonic() + 5.0
        while len(decoder.of_type("DISTANCE_SENSOR")) < len(messages):
            assert time.monotonic() < deadline, "MAVSDK did not decode every DISTANCE_SENSOR"
            time.sleep(0.02)
        theirs = [json.loads(m.fields_json) for m in decoder.of_type("DISTANCE_SENSOR")]
    finally:
        decoder.close()
    ours = peer.of_type("DISTANCE_SENSOR")
    assert len(ours) == len(theirs) == len(messages)
    for mine, other in zip(ours, theirs, strict=True):
        _same(
            mine,
            other,
            [
                "time_boot_ms",
                "min_distance",
                "max_distance",
                "current_distance",
                "type",
                "id",
                "orientation",
                "covariance",
                "horizontal_fov",
                "vertical_fov",
                "quaternion",
                "signal_quality",
            ],
        )
    assert theirs[0]["signal_quality"] == 87 and theirs[1]["orientation"] == 2
