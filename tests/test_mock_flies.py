"""``avoidd mock-autopilot --fly``: the bench's autopilot flies avoidd's setpoints (issue 50).

The mock as a user starts it (a process, real UDP), the daemon with avoidance on and a goal:
the vehicle moves toward the goal on the planner's GUIDED velocity setpoints, avoidd learns
the mock's origin and home, and the mock reports where it is in GLOBAL_POSITION_INT too.
"""

from __future__ import annotations

import asyncio
import math
import signal
import sys
from pathlib import Path

import pytest

from avoidd.commands.mock_autopilot import DEFAULT_ORIGIN
from avoidd.mavlink import codec as mav
from avoidd.mavlink.geo import GlobalPoint, offset_lat_lon
from avoidd.sim.mav_autopilot import SimulatedAutopilot
from avoidd.sim.vehicle import Multirotor, VehicleState
from tests.helpers import REPO, free_udp_port, synthetic_config, wait_for
from tests.helpers import start_daemon as start
from tests.helpers import stop_daemon as stop


async def test_the_flying_mock_flies_the_planners_setpoints(tmp_path: Path) -> None:
    port = free_udp_port()
    mock = await asyncio.create_subprocess_exec(
        sys.executable,
        "-m",
        "avoidd",
        "--log-level",
        "WARNING",
        "mock-autopilot",
        f"udpin:127.0.0.1:{port}",
        "--fly",
        "--system-id",
        "7",
        "--mode",
        "GUIDED",
        "--armed",
        "--duration",
        "60",
        cwd=REPO,
        stdout=asyncio.subprocess.PIPE,
    )
    goal = {"north_m": 10.0, "east_m": 0.0, "altitude_m": 2.0}
    sections = {"avoidance": {"enabled": True, "goal": goal}}
    config = synthetic_config(tmp_path, f"udpout:127.0.0.1:{port}", sections=sections)
    daemon, task = await start(config)
    try:
        assert await wait_for(lambda: daemon.vehicle.origin is not None, 20)
        origin = daemon.vehicle.origin
        assert (origin.lat_deg, origin.lon_deg) == pytest.approx(DEFAULT_ORIGIN[:2], abs=1e-6)

        def north_m() -> float:
            position = daemon.vehicle.position
            return -math.inf if position is None else float(position.north_m)

        # The synthetic scene has nothing in the way within 10 m north at 2 m: it flies there.
        assert await wait_for(lambda: north_m() > 3.0, 30), north_m()
        assert daemon.link.sent["SET_POSITION_TARGET_LOCAL_NED"] > 0
        assert daemon.link.received["GLOBAL_POSITION_INT"] > 0
    finally:
        await stop(daemon, task)
        mock.send_signal(signal.SIGINT)
        out, _ = await asyncio.wait_for(mock.communicate(), 20)
    assert "the vehicle ended" in out.decode()
    assert mock.returncode == 0


def test_global_position_follows_the_simulated_state() -> None:
    autopilot = SimulatedAutopilot(
        origin=(47.0, 8.0, 500.0),
        home_up_m=0.5,
        vehicle=Multirotor(state=VehicleState(position_m=[30.0, -20.0, -4.0])),  # type: ignore[arg-type]
    )
    message = autopilot.stream_message(mav.message_id("GLOBAL_POSITION_INT"))
    assert message is not None
    lat_deg, lon_deg = offset_lat_lon(GlobalPoint(47.0, 8.0, 500.0), 30.0, -20.0)
    assert (message.lat, message.lon) == (round(lat_deg * 1e7), round(lon_deg * 1e7))
    assert message.alt == 504_000 and message.relative_alt == 3_500
    assert message.lat > 47.0 * 1e7 and message.lon < 8.0 * 1e7  # north, west
