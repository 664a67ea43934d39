"""What a simulated run reports: speed while moving, start delay, time to "no path", bounds."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest

from avoidd.config.sim import PassConfig, ScenarioConfig, load_scenario
from avoidd.errors import ConfigError
from avoidd.sim.lockstep import LockstepRun
from avoidd.sim.report import format_table, format_totals
from avoidd.sim.scenario import prepare
from avoidd.sim.summary import Summary, judge


def _run(world: dict[str, Any], seconds: float, **extra: Any) -> LockstepRun:
    scenario = ScenarioConfig.model_validate(
        {"version": 1, "name": "m", "world": world, "perception": "oracle"}
        | {"duration_s": seconds}
        | extra
    )
    return prepare(scenario)


def test_the_speed_while_moving_leaves_out_the_hover_after_arrival() -> None:
    """20 m in the open at 3 m/s, then hovering: the mean over the run is half the speed the
    vehicle flew; the speed while moving is what the trace shows while it moved."""
    run = _run({"kind": "open", "length_m": 20}, 15.0)
    summary = run.run()
    assert summary.reached
    moving = [r.speed_m_s for r in run.rows if r.speed_m_s > 0.3]
    assert summary.moving_speed_m_s is not None
    assert summary.moving_speed_m_s == pytest.approx(sum(moving) / len(moving), abs=0.05)
    assert summary.moving_speed_m_s >= 2.4
    assert summary.mean_speed_m_s < 0.6 * summary.moving_speed_m_s
    assert summary.moving_s == pytest.approx(len(moving) / 10, abs=0.2)
    assert summary.world_kind == "open" and summary.speed_limit_m_s == 3.0


def _first_moving_s(run: LockstepRun) -> float:
    return next(r.t_s for r in run.rows if r.speed_m_s > 0.3)


def test_the_start_delay_counts_from_the_goal_to_moving() -> None:
    """ArduPilot in GUIDED may move at once; PX4 waits for the pilot's OFFBOARD at 2 s. The
    delay is when the trace first shows more than 0.3 m/s (rows every 0.1 s)."""
    guided = _run({"kind": "open", "length_m": 12}, 4.0)
    summary = guided.run()
    assert summary.start_delay_s is not None
    assert 0.0 <= _first_moving_s(guided) - summary.start_delay_s < 0.1
    px4 = _run(
        {"kind": "open", "length_m": 12},
        5.0,
        autopilot="px4",
        timeline=[{"t_s": 2.0, "action": "mode", "mode": "OFFBOARD"}],
    )
    late = px4.run()
    assert late.start_delay_s is not None and late.start_delay_s > 2.0
    assert 0.0 <= _first_moving_s(px4) - late.start_delay_s < 0.1


def test_the_time_to_no_path_and_to_it_from_the_search() -> None:
    """A room closed round the goal: "no path" at the first cycle that says it; the search
    (going round the room) counts from the last cycle that flew straight for the goal."""
    run = _run({"kind": "dead_end", "length_m": 12}, 30.0)
    summary = run.run()
    assert run.goal is not None
    first = next(r.t_s for r in run.rows if r.state == "no path")
    assert summary.no_path_s is not None and abs(summary.no_path_s - first) <= 0.1

    def straight(row: Any) -> bool:
        goal_deg = math.degrees(
            math.atan2(run.goal.east_m - row.east_m, run.goal.north_m - row.north_m)
        )
        off = math.remainder(row.direction_deg - goal_deg, 360.0)
        return bool(row.state == "moving" and abs(off) < 9.0)

    last = max(r.t_s for r in run.rows if r.direction_deg is not None and straight(r))
    assert summary.search_s is not None and 0.0 < summary.search_s < summary.no_path_s
    assert summary.search_s <= first - last + 0.1


def test_bounds_on_side_changes_start_delay_and_no_path_fail_the_run() -> None:
    summary = Summary("b", 1, "oracle", detour_side_changes=3, start_delay_s=None)
    summary.no_path_s = 31.0
    passing = PassConfig(
        no_collision=False, max_side_changes=2, start_delay_s=1.5, no_path_within_s=30.0
    )
    judge(summary, passing)
    assert not summary.passed
    assert summary.failures == [
        "3 side changes in one detour, over 2",
        "start delay never, over 1.5 s",
        "no path after 31.0 s, not within 30.0 s",
    ]
    within = Summary("b", 1, "oracle", detour_side_changes=2, start_delay_s=0.4, no_path_s=29.0)
    judge(within, passing)
    assert within.passed, within.failures


def _row(kind: str, moving: float | None, **extra: Any) -> dict[str, Any]:
    summary = Summary("r", 1, "stereo", world_kind=kind, speed_limit_m_s=3.0)
    summary.moving_speed_m_s = moving
    summary.start_delay_s = 0.5
    summary.passed = True
    return summary.as_json() | extra


def test_the_totals_give_the_speed_in_forests_and_boxes_as_a_share_of_max_speed() -> None:
    results = [
        _row("pole_forest", 2.4),
        _row("boxes", 1.8),
        _row("wall", 0.9),  # not a speed course
        _row("dead_end", 1.0, no_path_s=24.0, start_delay_s=1.1),
    ]
    totals = format_totals(results)
    assert (
        "flight speed while moving in pole forests/boxes: 70 % of max speed on average, "
        "lowest 60 % (2 runs)" in totals
    )
    assert "start delay 0.7 s on average, at most 1.1 s" in totals
    assert "'no path' after at most 24.0 s" in totals
    table = format_table(results)
    assert "v move" in table.splitlines()[0]
    assert " 2.40 " in table.splitlines()[1]


def test_bad_bounds_in_a_scenario_name_the_line_and_key(tmp_path: Path) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text(
        "version: 1\nname: x\nworld: {kind: open}\npass:\n  max_side_changes: -1\n"
        "  start_delay_s: 0\n  no_path_within_s: forever\n"
    )
    with pytest.raises(ConfigError) as caught:
        load_scenario(path)
    lines = caught.value.lines
    assert any(f"{path}:5: pass.max_side_changes" in line for line in lines), lines
    assert any(f"{path}:6: pass.start_delay_s" in line for line in lines), lines
    assert any(f"{path}:7: pass.no_path_within_s" in line for line in lines), lines


def test_a_run_can_end_soon_after_arrival_or_no_path() -> None:
    """``end_after_s``: the hover after the goal (or the hold after "no path") is cut short;
    what was measured until then is the same."""
    whole = _run({"kind": "open", "length_m": 12}, 15.0).run()
    short = _run({"kind": "open", "length_m": 12}, 15.0, end_after_s=1.0).run()
    assert short.time_to_goal_s == whole.time_to_goal_s is not None
    assert short.sim_time_s == pytest.approx(whole.time_to_goal_s + 1.0, abs=0.02)
    assert short.moving_speed_m_s == pytest.approx(whole.moving_speed_m_s, abs=0.05)
    dead = _run({"kind": "dead_end", "length_m": 12}, 40.0, end_after_s=2.0).run()
    assert dead.no_path_s is not None and dead.end_state == "no path"
    assert dead.sim_time_s == pytest.approx(dead.no_path_s + 2.0, abs=0.02)
