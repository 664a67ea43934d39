"""Closed loop with a real ArduCopter SITL: avoidd's camera rendered from the pose ArduPilot
reports, ArduPilot flying the vehicle (``avoidd sim ardupilot``, :mod:`avoidd.sim.external`).

(b) Pushed at a wall in GUIDED by a ground station, with avoidd's planner off, the vehicle is
stopped by ArduPilot's own simple avoidance on avoidd's OBSTACLE_DISTANCE, its centre within
0.5 m of ``AVOID_MARGIN`` from the wall. (c) With the planner on, avoidd flies the vehicle in
GUIDED round the wall to a goal behind it without collision.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from avoidd.config.sim import load_scenario
from avoidd.sim.external import ExternalRun
from tests.helpers import free_udp_port

pytestmark = [pytest.mark.sitl, pytest.mark.timeout(420)]

SCENARIOS = Path(__file__).resolve().parents[1] / "sitl" / "ardupilot"
AVOID_MARGIN_M = 2.0  # sitl/ardupilot/avoidd.parm


async def test_arducopter_stops_short_of_a_wall_on_avoidds_data(sitl_dir: Path) -> None:
    run = ExternalRun(
        load_scenario(SCENARIOS / "wall-stop.yaml"), sitl_dir, mode="push", push_speed_m_s=1.5
    )
    summary = await run.run(free_udp_port())
    assert summary.samples, summary.as_json()
    assert not summary.collided, summary.as_json()
    # The wall's face to the vehicle's centre at the closest approach, and where it ended.
    centre_m = summary.min_clearance_m + run.radius_m
    print(f"closest approach: centre {centre_m:.2f} m from the wall (AVOID_MARGIN 2 m)")
    assert abs(centre_m - AVOID_MARGIN_M) <= 0.5, summary.as_json()
    assert summary.reached_s is None  # it never got through
    # ArduPilot backs away inside its margin (AVOID_BACKUP_SPD) and the push brings it back:
    # it holds near the wall for the rest of the run, never farther than the push's restart.
    stopped = [s for s in summary.samples if s.t_s > summary.samples[-1].t_s - 5.0]
    assert all(s.clearance_m + run.radius_m < AVOID_MARGIN_M + 2.0 for s in stopped)


async def test_avoidd_flies_guided_round_a_wall_to_its_goal(sitl_dir: Path) -> None:
    # ArduPilot's own margin below the planner's (radius 0.5 + margin 1.0 from the centre), so
    # that it stays the second line and does not stop the vehicle first.
    run = ExternalRun(
        load_scenario(SCENARIOS / "wall-around.yaml"), sitl_dir, mode="planner", avoid_margin_m=1.0
    )
    summary = await run.run(free_udp_port())
    print(summary.as_json())
    assert not summary.collided, summary.as_json()
    assert summary.reached_s is not None, summary.as_json()
    assert summary.passed, summary.as_json()
    # It went round an end of the wall (12 m wide, from east -6 to 6), not through it.
    assert max(abs(sample.east_m) for sample in summary.samples) > 6.0
    # The samples carry the planner's view: the positions' velocity and the wall's side.
    tracked = [s for s in summary.samples if s.track_ne_m_s is not None]
    assert len(tracked) >= 0.8 * len(summary.samples), summary.as_json()
    assert any(s.near_side_deg is not None for s in summary.samples), summary.as_json()
