"""Simulated heads and the timeline: several cameras, mounts, fields of view, one failing,
actions at a distance, and what only the lockstep simulator plays."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from avoidd.cli import main
from avoidd.config.sim import ScenarioConfig, load_scenario
from avoidd.errors import ConfigError
from avoidd.sim.heads import RIGS, rig_for
from avoidd.sim.lockstep import LockstepRun
from avoidd.sim.scenario import prepare

UNKNOWN_CM = 65535


def _run(seconds: float, **extra: Any) -> LockstepRun:
    scenario = ScenarioConfig.model_validate(
        {
            "version": 1,
            "name": "heads",
            "world": {"kind": "open", "length_m": 30},
            "perception": "oracle",
            "duration_s": seconds,
        }
        | extra
    )
    run = prepare(scenario)
    run.run()
    return run


def _known_bins(sectors_cm: list[int]) -> set[int]:
    return {i for i, value in enumerate(sectors_cm) if value != UNKNOWN_CM}


def test_a_field_of_view_sets_the_focal_length() -> None:
    assert rig_for("320x240", None) is RIGS["320x240"]
    narrow = rig_for("320x240", 50.0)
    assert narrow.hfov_deg == pytest.approx(50.0, abs=0.01)
    assert (narrow.width, narrow.height, narrow.baseline_m) == (320, 240, 0.12)
    assert rig_for("640x480", 100.0).hfov_deg == pytest.approx(100.0, abs=0.01)


def test_heads_to_the_front_and_back_see_both_ways_and_one_fails_alone() -> None:
    """A front head and one looking back (60 degrees wide each): the merged scan covers both
    arcs; the back one unplugged at 2 s leaves the front arc known and the back one unknown."""
    run = _run(
        4.0,
        cameras=[
            {"name": "front", "hfov_deg": 60},
            {"name": "back", "yaw_deg": 180, "hfov_deg": 60},
        ],
        timeline=[{"t_s": 2.0, "action": "camera_unplug", "camera": "back"}],
    )
    both = _known_bins(next(r.sectors_cm for r in run.rows if r.t_s == 1.0))
    front = {i % 72 for i in range(-6, 7)}
    back = {36 + i for i in range(-6, 7)}
    assert front <= both and back <= both
    assert not both - front - back  # nothing else is covered
    after = [r for r in run.rows if r.t_s >= 2.5]
    assert after and all(_known_bins(r.sectors_cm) == front for r in after)
    assert all(r.gate == "plan" for r in after)  # the front head keeps avoidd fresh


def test_every_head_unplugged_is_stale_perception() -> None:
    run = _run(
        3.0,
        cameras=[{"name": "left", "yaw_deg": -45}, {"name": "right", "yaw_deg": 45}],
        timeline=[{"t_s": 1.0, "action": "camera_unplug"}],
    )
    late = [r for r in run.rows if r.t_s >= 1.5]
    assert late and all(r.gate == "hold" and r.sectors_cm == [UNKNOWN_CM] * 72 for r in late)


def test_a_head_turned_to_the_side_covers_the_side() -> None:
    run = _run(1.0, cameras=[{"name": "right", "yaw_deg": 90, "pitch_deg": -10}])
    known = _known_bins(run.rows[-1].sectors_cm)
    assert 18 in known and 0 not in known and 36 not in known


def test_actions_at_a_distance_flown_and_from_the_goal() -> None:
    """A disarm after 6 m flown, a switch to LOITER 12 m from the goal: each silences avoidd
    where the trace puts the vehicle then."""
    run = _run(10.0, timeline=[{"flown_m": 6.0, "action": "disarm"}])
    silent = next(r for r in run.rows if r.gate == "silent" and r.t_s > 0.5)
    before = [r for r in run.rows if r.t_s < silent.t_s]
    flown = sum(r.speed_m_s * 0.1 for r in before)
    assert 5.0 <= flown <= 7.0
    assert 5.0 <= math.hypot(silent.north_m, silent.east_m) <= 6.8
    run = _run(10.0, timeline=[{"goal_within_m": 12.0, "action": "mode", "mode": "LOITER"}])
    silent = next(r for r in run.rows if r.gate == "silent" and r.t_s > 0.5)
    assert 11.0 <= 30.0 - silent.north_m <= 12.5
    assert all(r.gate == "silent" for r in run.rows if r.t_s >= silent.t_s)


def _scenario_file(tmp_path: Path, body: str) -> Path:
    path = tmp_path / "s.yaml"
    path.write_text("version: 1\nname: s\nworld: {kind: open}\n" + body)
    return path


@pytest.mark.parametrize(
    ("body", "line", "says"),
    [
        ("cameras:\n  - {name: a}\n  - {name: a}\n", 4, "cameras: cameras need different names"),
        ("cameras:\n  - {name: a, hfov_deg: 170}\n", 5, "cameras[0].hfov_deg"),
        ("cameras:\n  - {name: 'a b'}\n", 5, "cameras[0].name"),
        ("timeline:\n  - {t_s: 1, action: camera_unplug, camera: b}\n", 4, "no camera 'b'"),
        ("timeline:\n  - {t_s: 1, flown_m: 2, action: disarm}\n", 5, "at t_s, after flown_m"),
        ("timeline:\n  - {action: disarm}\n", 5, "at t_s, after flown_m"),
        ("timeline:\n  - {t_s: 1, action: disarm, camera: front}\n", 5, "only camera actions"),
        ("timeline:\n  - {goal_within_m: 0, action: disarm}\n", 5, "goal_within_m"),
    ],
)
def test_bad_cameras_and_triggers_name_the_line(
    tmp_path: Path, body: str, line: int, says: str
) -> None:
    path = _scenario_file(tmp_path, body)
    with pytest.raises(ConfigError) as caught:
        load_scenario(path)
    assert any(f"{path}:{line}:" in got and says in got for got in caught.value.lines), (
        caught.value.lines
    )


def test_sitl_and_real_time_runs_refuse_what_only_the_lockstep_simulator_plays(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    world = tmp_path / "w.yaml"
    world.write_text(
        "version: 1\nobstacles:\n  - {shape: pole, north_m: 8, east_m: 0,"
        " motion: {by_ne_m: [0, 4], speed_m_s: 1}}\n"
    )
    path = tmp_path / "s.yaml"
    path.write_text(
        f"version: 1\nname: lockstep\nworld: {world}\ngoal: {{north_m: 20}}\n"
        "cameras: [{name: front}, {name: back, yaw_deg: 180}]\n"
        "timeline: [{flown_m: 3, action: camera_unplug, camera: back}]\n"
    )
    for argv in (
        ["sim", "px4", str(path), "--binary-dir", str(tmp_path)],
        ["sim", "run", str(path), "--realtime"],
    ):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert "has one forward head" in err
        assert "plays timed actions only" in err
        assert "unplugs its one camera" in err
        assert "draws obstacles where they stand" in err
    plain = _scenario_file(tmp_path, "")
    assert np.isfinite(load_scenario(plain).duration_s)
    from avoidd.sim.scenario import lockstep_only

    assert lockstep_only(load_scenario(plain), "a SITL run") == []
