"""``avoidd sim run|batch|ardupilot|px4``: closed-loop scenarios in the simulator or a real SITL."""

from __future__ import annotations

import argparse
import json
import os
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Any

from avoidd.commands import EXIT_FAILURE, EXIT_OK
from avoidd.errors import ConfigError


def configure(name: str, parser: argparse.ArgumentParser) -> None:
    """Add ``sim run`` and ``sim batch``."""
    actions = parser.add_subparsers(dest="sim_action", metavar="ACTION", required=True)
    run = actions.add_parser("run", help="run one scenario and write its trace, summary, plot")
    run.add_argument("scenario", type=Path, help="scenario file (sitl/scenarios/*.yaml)")
    run.add_argument("--seed", type=int, help="replace the generator's (or world's) seed")
    run.add_argument("--out", type=Path, help="folder for trace.jsonl, summary.json, plot.png")
    run.set_defaults(handler=run_one)
    batch = actions.add_parser("batch", help="run many scenarios and seeds; print a table")
    batch.add_argument("scenarios", type=Path, nargs="+", help="scenario files")
    batch.add_argument(
        "--seeds", type=int, default=1, help="seeds per scenario: its own, then the next ones"
    )
    batch.add_argument("--workers", type=int, default=os.cpu_count() or 1, help="local processes")
    batch.add_argument("--json", type=Path, help="also write every summary as JSON")
    batch.add_argument(
        "--max-speed",
        type=float,
        help="top speed for every scenario, m/s (a speed sweep over the same batch)",
    )
    batch.set_defaults(handler=run_batch)
    sitl = actions.add_parser(
        "ardupilot", help="fly one scenario with a real ArduCopter SITL and avoidd's daemon"
    )
    sitl.add_argument("scenario", type=Path, help="scenario file (sitl/scenarios/*.yaml)")
    sitl.add_argument(
        "--binary-dir",
        type=Path,
        default=Path(os.environ.get("AVOIDD_SITL_DIR", "../shared/sitl/ardupilot")),
        help="folder with arducopter and copter.parm (default: $AVOIDD_SITL_DIR)",
    )
    sitl.add_argument(
        "--push",
        type=float,
        metavar="M_S",
        help="planner off: push the vehicle at the goal at this speed; ArduPilot's own "
        "avoidance must stop it on avoidd's data",
    )
    sitl.add_argument("--avoid-margin", type=float, help="ArduPilot's AVOID_MARGIN, metres")
    sitl.add_argument("--json", type=Path, help="write the summary and every sample as JSON")
    sitl.set_defaults(handler=run_ardupilot)
    px4 = actions.add_parser(
        "px4", help="fly one scenario with a real PX4 SITL (SIH) and avoidd's daemon"
    )
    px4.add_argument("scenario", type=Path, help="scenario file (sitl/px4/*.yaml)")
    px4.add_argument(
        "--binary-dir",
        type=Path,
        default=Path(os.environ.get("AVOIDD_PX4_SITL_DIR", "../shared/sitl/px4")),
        help="folder with bin/px4 and etc/ (default: $AVOIDD_PX4_SITL_DIR)",
    )
    px4.add_argument(
        "--push",
        action="store_true",
        help="planner off: full forward stick in Position mode; PX4's collision prevention "
        "must stop the vehicle on avoidd's data",
    )
    px4.add_argument("--cp-dist", type=float, help="PX4's CP_DIST, metres")
    px4.add_argument("--json", type=Path, help="write the summary and every sample as JSON")
    px4.set_defaults(handler=run_px4)


def run_one(args: argparse.Namespace) -> int:
    """Run one scenario; exit 0 when it passes its criteria, 1 when not."""
    from avoidd.sim.scenario import run_file, write_outputs

    run, summary = run_file(args.scenario, args.seed)
    print(format_table([summary.as_json() | {"wall_time_s": round(summary.wall_time_s, 1)}]))
    if args.out is not None:
        for path in write_outputs(run, summary, args.out):
            print(f"wrote {path}")
    for failure in summary.failures:
        print(f"FAILED: {failure}")
    return EXIT_OK if summary.passed else EXIT_FAILURE


def run_ardupilot(args: argparse.Namespace) -> int:
    """Fly one scenario against ArduCopter SITL; exit 0 when it passes its criteria."""
    import asyncio
    import dataclasses
    import socket

    from avoidd.config.sim import load_scenario
    from avoidd.sim.external import ExternalRun

    scenario = load_scenario(args.scenario)
    if args.push is not None and not 0.1 <= args.push <= 10.0:
        raise ConfigError([f"--push {args.push}: give 0.1 to 10 m/s"])
    run = ExternalRun(
        scenario,
        args.binary_dir,
        mode="push" if args.push is not None else "planner",
        push_speed_m_s=args.push or 2.0,
        avoid_margin_m=args.avoid_margin,
    )
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port = int(probe.getsockname()[1])
    summary = asyncio.run(run.run(port))
    report = summary.as_json()
    print(json.dumps(report, indent=2))
    if args.json is not None:
        samples = [dataclasses.asdict(sample) for sample in summary.samples]
        args.json.write_text(json.dumps(report | {"trace": samples}, indent=2) + "\n")
    for failure in summary.failures:
        print(f"FAILED: {failure}")
    return EXIT_OK if summary.passed else EXIT_FAILURE


def run_px4(args: argparse.Namespace) -> int:
    """Fly one scenario against PX4 SITL; exit 0 when it passes its criteria."""
    import asyncio
    import dataclasses

    from avoidd.config.sim import load_scenario
    from avoidd.sim.px4_run import Px4Run

    scenario = load_scenario(args.scenario)
    run = Px4Run(
        scenario,
        args.binary_dir,
        mode="push" if args.push else "planner",
        cp_dist_m=args.cp_dist,
    )
    summary = asyncio.run(run.run())
    report = summary.as_json() | {
        "estimator_s": round(run.estimator_s, 1),
        "offboard_s": None if run.offboard_s is None else round(run.offboard_s, 2),
        "setpoints_after_release": run.setpoints_after_release,
    }
    print(json.dumps(report, indent=2))
    if args.json is not None:
        samples = [dataclasses.asdict(sample) for sample in summary.samples]
        args.json.write_text(json.dumps(report | {"trace": samples}, indent=2) + "\n")
    for failure in summary.failures:
        print(f"FAILED: {failure}")
    return EXIT_OK if summary.passed else EXIT_FAILURE


def _one(path: Path, seed: int, max_speed_m_s: float | None) -> dict[str, Any]:
    from avoidd.sim.scenario import run_file

    _, summary = run_file(path, seed, max_speed_m_s)
    return summary.as_json() | {"file": str(path), "wall_time_s": round(summary.wall_time_s, 1)}


def run_batch(args: argparse.Namespace) -> int:
    """Run every scenario with seeds 1..N in local processes; exit 0 when all pass."""
    from avoidd.config.sim import load_scenario
    from avoidd.progress import Progress

    for path in args.scenarios:
        load_scenario(path)  # every file valid before anything runs
    if args.max_speed is not None and not 0.1 <= args.max_speed <= 20.0:
        raise ConfigError([f"--max-speed {args.max_speed}: give 0.1 to 20 m/s"])
    jobs = [
        (path, own_seed(path) + offset) for path in args.scenarios for offset in range(args.seeds)
    ]
    progress = Progress(len(jobs))
    results: list[dict[str, Any]] = []
    with ProcessPoolExecutor(max_workers=max(1, args.workers)) as pool:
        futures = {
            pool.submit(_one, path, seed, args.max_speed): (path, seed) for path, seed in jobs
        }
        for future in as_completed(futures):
            result = future.result()
            results.append(result)
            progress.step(f"{result['name']} seed {result['seed']}")
    results.sort(key=lambda r: (r["file"], r["seed"]))
    print(format_table(results))
    print(format_totals(results))
    if args.json is not None:
        args.json.write_text(json.dumps(results, indent=2) + "\n")
    return EXIT_OK if all(r["passed"] for r in results) else EXIT_FAILURE


def _number(value: float | None, digits: int = 2) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def format_table(results: list[dict[str, Any]]) -> str:
    """One line per run: collision, clearance, goal, time, speed, side changes, verdict.

    ``sides`` is the most side changes within one detour (a detour lasts while the chosen way is
    more than 10 degrees off the goal's direction).
    """
    lines = [
        f"{'scenario':24} {'seed':>4} {'coll':>4} {'min m':>6} {'p01 m':>6} {'goal':>4} "
        f"{'t goal':>6} {'mean v':>6} {'sides':>5} {'end':9} {'wall s':>6} verdict"
    ]
    for r in results:
        lines.append(
            f"{r['name'][:24]:24} {r['seed']:>4} {'YES' if r['collided'] else 'no':>4} "
            f"{_number(r['min_clearance_m']):>6} {_number(r['clearance_p01_m']):>6} "
            f"{'yes' if r['reached'] else 'no':>4} {_number(r['time_to_goal_s'], 1):>6} "
            f"{_number(r['mean_speed_m_s']):>6} {r.get('detour_side_changes', 0):>5} "
            f"{r['end_state'][:9]:9} "
            f"{_number(r.get('wall_time_s'), 1):>6} "
            f"{'pass' if r['passed'] else 'FAIL: ' + '; '.join(r['failures'])}"
        )
    return "\n".join(lines)


def format_totals(results: list[dict[str, Any]]) -> str:
    """Collisions, goals reached, passes, mean time to goal over a batch."""
    count = len(results)
    collisions = sum(r["collided"] for r in results)
    reached = [r for r in results if r["reached"]]
    times = [r["time_to_goal_s"] for r in reached]
    mean_time = sum(times) / len(times) if times else None
    passed = sum(r["passed"] for r in results)
    reachable = [r for r in results if r.get("reachable", True)]
    reached_reachable = sum(r["reached"] for r in reachable)
    dead_ends = [r for r in results if not r.get("reachable", True)]
    no_path = sum(r["end_state"] == "no path" for r in dead_ends)
    clear = sum(
        r["clearance_p01_m"] is None or r["clearance_p01_m"] >= r.get("clearance_target_m", 0.0)
        for r in results
    )
    sides = max((r.get("detour_side_changes", 0) for r in results), default=0)
    holds = [r["stale_to_hold_ms"] for r in results if r.get("stale_to_hold_ms") is not None]
    hold = f"; stale to zero-velocity setpoint at most {max(holds):.0f} ms" if holds else ""
    share = 100.0 * reached_reachable / len(reachable) if reachable else 100.0
    return (
        f"{count} runs: {collisions} collisions, {len(reached)} goals reached, "
        f"{passed} passed; mean time to goal {_number(mean_time, 1)} s\n"
        f"reachable goals reached {reached_reachable}/{len(reachable)} ({share:.1f} %); "
        f"dead ends ending 'no path' {no_path}/{len(dead_ends)}; clearance >= margin - 0.1 m "
        f"in 99 % of steps: {clear}/{count} runs; most side changes in one detour: {sides}"
        f"{hold}"
    )


def own_seed(path: Path) -> int:
    """A scenario's own seed: its generator's, or its world file's."""
    from avoidd.config.sim import GeneratedWorldConfig, load_scenario, load_world

    scenario = load_scenario(path)
    if isinstance(scenario.world, GeneratedWorldConfig):
        return scenario.world.seed
    return load_world(scenario.world).seed
