"""A scenario file to a run: its world (file or generator, with a seed), its goal, its outputs."""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path
from typing import Any

from avoidd.config.sim import (
    CameraConfig,
    GeneratedWorldConfig,
    ScenarioConfig,
    WorldConfig,
    load_scenario,
    load_world,
)
from avoidd.planner.core import Goal
from avoidd.sim.generators import generate
from avoidd.sim.lockstep import LockstepRun
from avoidd.sim.summary import Summary
from avoidd.sim.world import World


def prepare(
    scenario: ScenarioConfig, seed: int | None = None, world: WorldConfig | None = None
) -> LockstepRun:
    """The run of a scenario; ``seed`` replaces a generator's seed (and seeds the noise).

    Args:
        scenario: The validated scenario.
        seed: Seed override (None: the scenario's own).
        world: The scenario's world file, already loaded (None: load it here). A run on another
            machine gets it this way and never opens the driver's paths.

    Returns:
        The run, ready to :meth:`~avoidd.sim.lockstep.LockstepRun.run`.
    """
    if isinstance(scenario.world, GeneratedWorldConfig):
        generator = scenario.world
        if seed is not None:
            generator = generator.model_copy(update={"seed": seed})
        clearance_m = scenario.avoidance.vehicle_radius_m + scenario.avoidance.margin_m
        world_config, goal = generate(generator, clearance_m)
        goal = scenario.goal or goal
        noise_seed = generator.seed
        kind: str = generator.kind
    else:
        world_config = world if world is not None else load_world(scenario.world)
        if seed is not None:
            world_config = world_config.model_copy(update={"seed": seed})
        assert scenario.goal is not None  # the model requires it with a world file
        goal = scenario.goal
        noise_seed = world_config.seed
        kind = "file"
    return LockstepRun(
        scenario,
        World.from_config(world_config),
        Goal(goal.north_m, goal.east_m, goal.altitude_m),
        seed=noise_seed,
        world_kind=kind,
    )


def lockstep_only(scenario: ScenarioConfig, run: str) -> list[str]:
    """What of a scenario only the lockstep simulator plays, one line each with the remedy.

    The real-time and SITL runs render one forward head from reported poses at no time of the
    scenario's, and play timed actions only.

    Args:
        scenario: The validated scenario.
        run: What was to run it, for the message.
    """
    lines = []
    subject = f"scenario {scenario.name}: {run}"
    if scenario.cameras != [CameraConfig()]:
        lines.append(f"{subject} has one forward head; remove 'cameras' or use 'avoidd sim run'")
    if any(action.t_s is None for action in scenario.timeline):
        lines.append(
            f"{subject} plays timed actions only; give t_s instead of flown_m or goal_within_m"
        )
    if any(action.camera is not None for action in scenario.timeline):
        lines.append(f"{subject} unplugs its one camera; remove 'camera' from the timeline")
    world = world_of(scenario)
    if world is None:
        assert isinstance(scenario.world, GeneratedWorldConfig)
        avoidance = scenario.avoidance
        world, _ = generate(scenario.world, avoidance.vehicle_radius_m + avoidance.margin_m)
    if any(obstacle.motion is not None for obstacle in world.obstacles):
        lines.append(f"{subject} draws obstacles where they stand; remove their 'motion'")
    return lines


def run_file(
    path: Path, seed: int | None = None, max_speed_m_s: float | None = None
) -> tuple[LockstepRun, Summary]:
    """Load, prepare and run one scenario file.

    Args:
        path: The scenario file.
        seed: Seed override (None: the scenario's own).
        max_speed_m_s: Top speed override (a speed sweep over the same batch).
    """
    return run_config(load_scenario(path), None, seed, max_speed_m_s)


def world_of(scenario: ScenarioConfig) -> WorldConfig | None:
    """The scenario's world file, loaded and validated (None for a generated world)."""
    if isinstance(scenario.world, GeneratedWorldConfig):
        return None
    return load_world(scenario.world)


def run_config(
    scenario: ScenarioConfig,
    world: WorldConfig | None = None,
    seed: int | None = None,
    max_speed_m_s: float | None = None,
) -> tuple[LockstepRun, Summary]:
    """Prepare and run one validated scenario; no file is read when ``world`` is given.

    The seam for workers on other machines (``sim batch --ray``): the driver loads and
    validates the files, the worker runs from the configs.

    Args:
        scenario: The validated scenario.
        world: Its world file's config (see :func:`world_of`; None: load it here).
        seed: Seed override (None: the scenario's own).
        max_speed_m_s: Top speed override (a speed sweep over the same batch).
    """
    if max_speed_m_s is not None:
        avoidance = scenario.avoidance.model_copy(update={"max_speed_m_s": max_speed_m_s})
        scenario = scenario.model_copy(update={"avoidance": avoidance})
    run = prepare(scenario, seed, world)
    return run, run.run()


def write_outputs(run: LockstepRun, summary: Summary, out: Path) -> list[Path]:
    """Write ``trace.jsonl``, ``summary.json`` and ``plot.png`` into ``out``.

    Returns:
        The files written.
    """
    from avoidd.sim.plot import plot_run

    out.mkdir(parents=True, exist_ok=True)
    trace = out / "trace.jsonl"
    with trace.open("w") as stream:
        for row in run.rows:
            stream.write(json.dumps(asdict(row)) + "\n")
    report: dict[str, Any] = summary.as_json() | {"wall_time_s": round(summary.wall_time_s, 2)}
    summary_path = out / "summary.json"
    summary_path.write_text(json.dumps(report, indent=2) + "\n")
    plot = out / "plot.png"
    plot_run(run, summary, plot)
    return [trace, summary_path, plot]
