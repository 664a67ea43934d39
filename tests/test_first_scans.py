"""The first scans after a start and after a recording starts over (issue 52, item 6).

ArduPilot reads an unknown bin (65535) as nothing: a message with an obstacle's bins unknown
between bins measured clear tells it the way is free. The temporal filter confirms a new
obstacle over ``confirm_frames`` frames; before it had that many since its start or reset,
the obstacle's bins were unknown while the rest of the view was already clear (1 message of
103, 4 of 141 on a looping recording). Asserted from the autopilot's side of a real socket:
the mock ArduPilot decodes every OBSTACLE_DISTANCE avoidd sends while a recording of a pole
1.9 m ahead loops every 0.4 s.
"""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

from avoidd.mavlink.layout import UNKNOWN_CM, read_bins
from avoidd.mavlink.mock_autopilot import MockAutopilot
from tests.helpers import RIG_320, free_udp_port, synthetic_config, wait_for, write_yaml
from tests.helpers import start_daemon as start
from tests.helpers import stop_daemon as stop
from tests.test_faults import POLE_CM, _write_pairs

PAIRS = 4
FPS = 10
RUN_S = 8.0


def _looping_config(tmp_path: Path, recording: Path, port: int) -> Path:
    calibration = write_yaml(tmp_path / "calib.yaml", {"version": 1, "rectified": RIG_320})
    head = {
        "name": "front",
        "calibration": str(calibration),
        "source": {"kind": "files", "path": str(recording), "fps": FPS, "loop": True},
    }
    return synthetic_config(
        tmp_path,
        f"udpout:127.0.0.1:{port}",
        heads=[head],
        pipeline={"max_age_ms": 400, "log_interval_s": 600.0},
    )


def _bins(message: Any) -> list[int]:
    """The message's values as avoidd's 72 bins (bin i centred on bearing 5 i)."""
    return list(read_bins(message.distances, message.increment_f, message.angle_offset))


async def test_no_message_has_the_obstacle_unknown_beside_clear_bins(tmp_path: Path) -> None:
    recording = _write_pairs(tmp_path / "rec", PAIRS)
    port = free_udp_port()
    autopilot = MockAutopilot(system_id=7, mode="GUIDED")  # ArduPilot
    await autopilot.start(f"udpin:127.0.0.1:{port}")
    daemon, task = await start(_looping_config(tmp_path, recording, port))
    try:
        assert await wait_for(lambda: daemon.vehicle.link_up, 20.0)
        await asyncio.sleep(RUN_S)
    finally:
        await stop(daemon, task)
        await autopilot.stop()
    (head,) = daemon.heads
    loops = RUN_S * FPS / PAIRS
    assert head.stats.processed >= 0.5 * RUN_S * FPS, head.stats
    messages = autopilot.of_type("OBSTACLE_DISTANCE")
    assert len(messages) >= 0.5 * RUN_S * 15, len(messages)
    # The pole straight ahead is bin 0: measured at its distance in nearly every message.
    ahead = [_bins(m)[0] for m in messages]
    measured = [v for v in ahead if v != UNKNOWN_CM]
    assert len(measured) >= 0.9 * len(messages), ahead
    assert all(abs(v - POLE_CM) <= 0.06 * POLE_CM for v in measured), measured
    blind = []
    for index, message in enumerate(messages):
        bins, clear = _bins(message), message.max_distance + 1
        if bins[0] == UNKNOWN_CM and clear in bins:
            blind.append(index)
    assert blind == [], (
        f"{len(blind)} of {len(messages)} messages ({loops:.0f} loops) had the pole unknown "
        f"beside clear bins: {blind}"
    )
