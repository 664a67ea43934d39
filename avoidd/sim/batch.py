"""A batch of lockstep runs: the jobs (validated configs, never paths) and the one job function.

Local processes and Ray tasks run :func:`run_job` on the same :class:`BatchJob`, so a batch
gives the same summaries either way.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from avoidd.config.sim import GeneratedWorldConfig, ScenarioConfig, WorldConfig


@dataclass(frozen=True)
class BatchJob:
    """One run of a batch: the validated configs travel to the worker, never the paths.

    A worker on another machine (``--ray``) has no copy of the driver's files.

    Attributes:
        file: The scenario file, as given (for the report and the sort order).
        scenario: Its validated config.
        world: Its world file's config (None: a generated world).
        seed: The seed of this run.
        max_speed_m_s: Top speed override (None: the scenario's).
    """

    file: str
    scenario: ScenarioConfig
    world: WorldConfig | None
    seed: int
    max_speed_m_s: float | None


def run_job(job: BatchJob) -> dict[str, Any]:
    """Run one batch job (in a local process or a Ray task: the same code); its summary row."""
    from avoidd.sim.scenario import run_config

    _, summary = run_config(job.scenario, job.world, job.seed, job.max_speed_m_s)
    return summary.as_json() | {"file": job.file, "wall_time_s": round(summary.wall_time_s, 1)}


def batch_jobs(
    loaded: list[tuple[Path, ScenarioConfig]], seeds: int, max_speed_m_s: float | None
) -> list[BatchJob]:
    """The jobs of a batch: each scenario with its own seed and the ``seeds - 1`` after it.

    Args:
        loaded: The scenario files as given, with their validated configs.
        seeds: Seeds per scenario.
        max_speed_m_s: Top speed override (None: each scenario's).
    """
    from avoidd.sim.scenario import world_of

    jobs = []
    for path, scenario in loaded:
        world = world_of(scenario)
        seed = _own_seed(scenario, world)
        jobs += [
            BatchJob(str(path), scenario, world, seed + offset, max_speed_m_s)
            for offset in range(seeds)
        ]
    return jobs


def _own_seed(scenario: ScenarioConfig, world: WorldConfig | None) -> int:
    """A scenario's own seed: its generator's, or its world file's."""
    if isinstance(scenario.world, GeneratedWorldConfig):
        return scenario.world.seed
    assert world is not None  # a scenario on a world file
    return world.seed
