"""Simulator figures: stereo pairs rendered per second, planner cost, lockstep wall time."""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from avoidd.config import AvoidanceConfig
from avoidd.config.sim import GeneratedWorldConfig, ScenarioConfig
from avoidd.planner.core import Goal, Planner, Pose
from avoidd.sim.generators import generate
from avoidd.sim.lockstep import RIGS, LockstepRun
from avoidd.sim.render import StereoRenderer
from avoidd.sim.world import SimBox, SimCylinder, World
from avoidd.sources.scene import Box, Pole, Scene, render_pair
from avoidd.types import Mount

OBJECTS = 20


def bench_world(seed: int = 1) -> World:
    """Twenty obstacles (boxes and poles) spread 3 to 25 m ahead of the origin."""
    rng = np.random.default_rng(seed)
    obstacles: list[SimBox | SimCylinder] = []
    for i in range(OBJECTS):
        north, east = float(rng.uniform(3.0, 25.0)), float(rng.uniform(-10.0, 10.0))
        if i % 2:
            obstacles.append(SimCylinder(north, east, float(rng.uniform(0.1, 0.4)), 5.0))
        else:
            size = float(rng.uniform(0.5, 2.0))
            obstacles.append(SimBox(north, east, size, size / 2, 3.0, float(rng.uniform(0, 3))))
    return World(tuple(obstacles), seed)


def _old_scene(world: World) -> Scene:
    """The same obstacles for the ray-cast scene renderer of ``sources`` (unyawed)."""
    items: list[Box | Pole] = []
    for o in world.obstacles:
        if isinstance(o, SimCylinder):
            items.append(Pole(o.north_m, o.east_m, 2 * o.radius_m, o.height_m))
        else:
            items.append(Box(o.north_m, o.east_m, 2 * o.half_length_m, 2 * o.half_width_m, 3.0))
    return Scene(2.0, 0.0, tuple(items), 60.0, world.seed)


def render_rates(frames: int) -> list[dict[str, Any]]:
    """Pairs per second of the simulator's renderer and of the scene renderer, per size."""
    world = bench_world()
    rows = []
    for size, rig in RIGS.items():
        renderer = StereoRenderer(world, rig, Mount())
        rng = np.random.default_rng(0)
        renderer.render(0.0, 0.0, -2.0, 0.0, rng=rng)
        started = time.perf_counter()
        for i in range(frames):
            renderer.render(0.2 * i, 0.05 * i, -2.0, 0.03 * i, 1.0, -2.0, rng)
        fast_s = (time.perf_counter() - started) / frames
        scene = _old_scene(world)
        started = time.perf_counter()
        for _ in range(max(1, frames // 5)):
            render_pair(scene, rig)
        old_s = (time.perf_counter() - started) / max(1, frames // 5)
        rows.append(
            {
                "size": size,
                "pairs_per_s": round(1.0 / fast_s, 1),
                "ms_per_pair": round(fast_s * 1000, 1),
                "raycast_scene_ms_per_pair": round(old_s * 1000, 1),
                "speedup": round(old_s / fast_s, 1),
            }
        )
    return rows


def planner_cost(cycles: int) -> dict[str, float]:
    """Milliseconds per planner cycle (decide) and per scan taken in (observe).

    The vehicle flies a circle among remembered obstacles. Wall time, and the CPU time of
    the planner's own thread (what it takes from the vision; steady when the machine is busy).
    """
    planner = Planner(AvoidanceConfig(enabled=True), 20.0)
    rng = np.random.default_rng(2)
    decide_s: list[float] = []
    decide_cpu_s: list[float] = []
    observe_s: list[float] = []
    for i in range(cycles):
        t_ns = (i + 1) * 50_000_000
        angle = 0.02 * i
        pose = Pose(t_ns, 10 * math.sin(angle), 10 * (1 - math.cos(angle)), -2.0, angle, 2.0, 0.0)
        if i % 3 == 0:
            scan = np.full(72, np.nan, dtype=np.float32)
            scan[list(range(-7, 8))] = rng.uniform(2.0, 25.0, 15)
            scan[scan > 20] = np.inf
            started = time.perf_counter()
            planner.observe_scan(scan, t_ns, pose)
            observe_s.append(time.perf_counter() - started)
        started, started_cpu = time.perf_counter(), time.thread_time()
        planner.decide(t_ns, pose, Goal(40.0, 5.0, 2.0), fresh=True)
        decide_s.append(time.perf_counter() - started)
        decide_cpu_s.append(time.thread_time() - started_cpu)
    return {
        "decide_ms_mean": round(1000 * float(np.mean(decide_s)), 3),
        "decide_ms_p95": round(1000 * float(np.percentile(decide_s, 95)), 3),
        "decide_cpu_ms_mean": round(1000 * float(np.mean(decide_cpu_s)), 3),
        "observe_ms_mean": round(1000 * float(np.mean(observe_s)), 3),
        "remembered_points": int(planner.memory.north_east.shape[0]),
    }


def lockstep_time(duration_s: float = 30.0) -> dict[str, float]:
    """Wall time of a pole-forest scenario with one 320x240 stereo head at 15 Hz."""
    generator = GeneratedWorldConfig(kind="pole_forest", seed=1)
    scenario = ScenarioConfig.model_validate(
        {
            "version": 1,
            "name": "bench",
            "world": generator.model_dump(),
            "goal": {"north_m": 30.0, "east_m": 0.0},
            "duration_s": duration_s,
            "avoidance": {"enabled": True},
        }
    )
    world, goal = generate(generator, 1.5)
    run = LockstepRun(scenario, World.from_config(world), Goal(goal.north_m, goal.east_m, 2.0), 1)
    summary = run.run()
    return {"sim_s": summary.sim_time_s, "wall_s": round(summary.wall_time_s, 2)}
