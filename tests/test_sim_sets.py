"""The project's scenario sets: all valid, and the randomized one a batch of 100 flights over
every generator with what the planner's targets are measured on."""

from __future__ import annotations

from pathlib import Path

from avoidd.config.sim import GeneratedWorldConfig, ScenarioConfig, load_scenario, load_world
from avoidd.sim.batch import batch_jobs
from tests.helpers import REPO

SCENARIOS = REPO / "sitl" / "scenarios"
CLEARANCE_M = 1.5  # radius 0.5 m + margin 1.0 m, the defaults every shipped scenario flies


def _load(folder: Path) -> list[tuple[Path, ScenarioConfig]]:
    return [(path, load_scenario(path)) for path in sorted(folder.glob("*.yaml"))]


def _low(value: float | tuple[float, float] | None) -> float | None:
    return value[0] if isinstance(value, tuple) else value


def test_every_world_file_is_valid() -> None:
    worlds = sorted((REPO / "sitl" / "worlds").glob("*.yaml"))
    assert len(worlds) >= 4
    for path in worlds:
        load_world(path)


def test_the_randomized_set_is_100_flights_over_every_generator_at_3_m_s() -> None:
    loaded = _load(SCENARIOS / "random")
    jobs = batch_jobs(loaded, 5, None)
    assert len(jobs) >= 100
    assert len({(job.file, job.seed) for job in jobs}) == len(jobs)
    generators = [s.world for _, s in loaded if isinstance(s.world, GeneratedWorldConfig)]
    assert len(generators) == len(loaded)
    kinds = {g.kind for g in generators}
    assert kinds >= {"pole_forest", "boxes", "wall_gap", "wall", "l_corridor", "dead_end", "open"}
    # No two files draw the same worlds.
    assert len({(g.kind, g.seed) for g in generators}) == len(generators)
    assert all(s.avoidance.max_speed_m_s == 3.0 and s.perception == "stereo" for _, s in loaded)


def test_the_randomized_set_has_what_the_targets_are_measured_on() -> None:
    loaded = [s for _, s in _load(SCENARIOS / "random")]
    worlds = [s.world for s in loaded if isinstance(s.world, GeneratedWorldConfig)]
    gaps = [_low(w.gap_m) for w in worlds if w.kind == "wall_gap"]
    assert min(g for g in gaps if g is not None) <= 2.2 * CLEARANCE_M + 1e-9
    assert any(w.kind == "l_corridor" and w.texture == "flat" for w in worlds)
    assert any(w.bars for w in worlds) and any(w.movers for w in worlds)
    offsets = [w.goal_east_m for w in worlds if isinstance(w.goal_east_m, tuple)]
    assert any(max(abs(low), abs(high)) >= 10.0 for low, high in offsets)
    assert any(abs(s.wind_m_s[0]) + abs(s.wind_m_s[1]) >= 3.0 for s in loaded)
    dead_ends = [s for s in loaded if s.passing.end_state == "no path"]
    assert len(dead_ends) >= 2
    assert all(isinstance(s.world, GeneratedWorldConfig) for s in dead_ends)
    assert any(len(s.cameras) > 1 and any(a.camera for a in s.timeline) for s in loaded)


def test_the_built_in_scenarios_use_every_feature_of_the_simulator() -> None:
    loaded = [s for _, s in _load(SCENARIOS)]
    assert len(loaded) >= 30
    worlds = [load_world(s.world) for s in loaded if isinstance(s.world, Path)]
    obstacles = [o for w in worlds for o in w.obstacles]
    generators = [s.world for s in loaded if isinstance(s.world, GeneratedWorldConfig)]
    assert any(o.bottom_m > 0 for o in obstacles)
    assert {o.textured for o in obstacles} >= {"full", "low", "flat"}
    assert any(g.texture == "flat" for g in generators) and any(g.movers for g in generators)
    assert any(abs((_low(g.gap_m) or 0.0) - 2.2 * CLEARANCE_M) < 1e-9 for g in generators)
    assert any(g.goal_east_m != 0.0 for g in generators)
    assert any(len(s.cameras) > 1 for s in loaded)
    assert any(c.hfov_deg is not None or c.pitch_deg for s in loaded for c in s.cameras)
    actions = [a for s in loaded for a in s.timeline]
    assert any(a.flown_m for a in actions) and any(a.goal_within_m for a in actions)
    assert any(a.camera for a in actions)
    passing = [s.passing for s in loaded]
    assert any(p.max_side_changes is not None for p in passing)
    assert any(p.start_delay_s is not None for p in passing)
    assert any(p.no_path_within_s is not None for p in passing)
