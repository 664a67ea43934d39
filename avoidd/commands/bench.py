"""The bench commands: ``bench``, ``bench-link``, ``bench-sim`` and ``bench-debugview``."""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
from pathlib import Path

from avoidd.commands import EXIT_CONFIG, EXIT_OK


def configure(name: str, parser: argparse.ArgumentParser) -> None:
    """Add the options of ``bench`` or ``bench-link``."""
    if name == "bench":
        parser.add_argument(
            "--matcher",
            action="append",
            choices=["sgbm", "sad", "census", "segment"],
            help="time only this matcher (repeat for several; default: all four)",
        )
        parser.add_argument("--frames", type=int, default=5, help="frames per configuration")
        parser.add_argument(
            "--quick",
            action="store_true",
            help="320x240 and 640x480, 64 disparities (the worst-case frames at 640x480 always)",
        )
        parser.add_argument("--json", type=Path, help="also write the figures as JSON")
        parser.add_argument(
            "--euroc",
            type=Path,
            metavar="MAV0",
            help="also time a recorded EuRoC sequence (its mav0 folder) at its own size",
        )
        parser.add_argument(
            "--daemon",
            type=Path,
            metavar="CONFIG",
            help="instead: run the daemon on CONFIG with a listener in place of its link and "
            "print how often it sends OBSTACLE_DISTANCE, how much of it is fresh, fps and latency",
        )
        parser.add_argument(
            "--seconds", type=_seconds, default=10.0, help="with --daemon: the measured window"
        )
        parser.add_argument(
            "--threads",
            type=int,
            action="append",
            help="with --daemon: run with this pipeline.threads (repeat to compare, e.g. "
            "--threads 1 --threads 2)",
        )
        parser.add_argument(
            "--source-fps",
            type=float,
            help="with --daemon: the synthetic cameras' frame rate (above the pipeline's, "
            "fps is the sustained rate)",
        )
        parser.set_defaults(handler=run_vision_bench)
    elif name == "bench-debugview":
        parser.add_argument(
            "--config",
            type=Path,
            default=Path("config/demo.yaml"),
            help="the daemon configuration to run (default: config/demo.yaml)",
        )
        parser.add_argument(
            "--seconds", type=_seconds, default=20.0, help="length of each measured window"
        )
        parser.add_argument("--stream-fps", type=float, default=10.0, help="the view's frame rate")
        parser.add_argument("--json", type=Path, help="also write the figures as JSON")
        parser.set_defaults(handler=run_debugview_bench)
    elif name == "bench-sim":
        parser.add_argument("--frames", type=int, default=20, help="pairs rendered per size")
        parser.add_argument("--cycles", type=int, default=600, help="planner cycles")
        parser.add_argument("--json", type=Path, help="also write the figures as JSON")
        parser.set_defaults(handler=run_sim_bench)
    else:
        parser.add_argument("--rate", type=float, default=2000.0, help="messages per second")
        parser.add_argument("--seconds", type=_seconds, default=5.0, help="measurement length")
        parser.add_argument(
            "--asked",
            action="store_true",
            help="instead of fixed streams at --rate, the streams avoidd asks of an autopilot "
            "(ATTITUDE 50 Hz and the rest at the default rates), each with its received rate",
        )
        parser.add_argument(
            "--stranger",
            action="store_true",
            help="the stream comes from a stranger (an autopilot is adopted at another address "
            "first): what dropping a flood unread costs",
        )
        parser.add_argument("--json", type=Path, help="also write the figures as JSON")
        parser.set_defaults(handler=run_link_bench)


def _seconds(text: str) -> float:
    value = float(text)
    if not value > 0:  # NaN too
        raise argparse.ArgumentTypeError(f"{text}: a measured window must last more than 0 s")
    return value


def run_vision_bench(args: argparse.Namespace) -> int:
    """Time the pipeline's stages and print the table (or, with ``--daemon``, the daemon)."""
    if args.daemon is not None:
        return run_daemon_bench(args)
    from avoidd.bench.vision import (
        DISPARITIES,
        MATCHERS,
        RESOLUTIONS,
        WORST_CASE,
        WORST_CASE_SIZE,
        euroc_frames,
        format_bench,
        run_bench,
        worst_case_frames,
    )

    resolutions = RESOLUTIONS[:2] if args.quick else RESOLUTIONS
    disparities = DISPARITIES[:1] if args.quick else DISPARITIES
    # The worst-case frames (most pixels obstacle points) at 640x480, after the rendered ones.
    recorded = [worst_case_frames(name, *WORST_CASE_SIZE, args.frames) for name in WORST_CASE]
    if args.euroc is not None:
        recorded.append(euroc_frames(args.euroc, args.frames))
    records = run_bench(
        args.matcher or list(MATCHERS),
        resolutions,
        disparities,
        args.frames,
        recorded,
        with_list=True,
    )
    print(format_bench(records))
    if args.json is not None:
        args.json.write_text(json.dumps(records, indent=2) + "\n")
    return EXIT_OK


def run_daemon_bench(args: argparse.Namespace) -> int:
    """Run the daemon on a configuration for a while and print what it sent."""
    from avoidd.bench.daemon import compare_threads, format_report, run_bench

    reports = []
    for threads in args.threads or [None]:
        try:
            report = asyncio.run(run_bench(args.daemon, args.seconds, threads, args.source_fps))
        except ValueError as exc:
            print(f"avoidd: {exc}", file=sys.stderr)
            return EXIT_CONFIG
        print(format_report(report))
        reports.append(report)
    for line in compare_threads(reports):
        print(line)
    if args.json is not None:
        data = reports[0] if len(reports) == 1 else reports
        args.json.write_text(json.dumps(data, indent=2) + "\n")
    return EXIT_OK


def run_link_bench(args: argparse.Namespace) -> int:
    """Measure the CPU of decoding a busy incoming stream and print it."""
    from avoidd.bench.link import format_report, run_bench

    report = asyncio.run(run_bench(args.rate, args.seconds, args.asked, args.stranger))
    print(format_report(report))
    if args.json is not None:
        args.json.write_text(json.dumps(report, indent=2) + "\n")
    return EXIT_OK


def run_debugview_bench(args: argparse.Namespace) -> int:
    """Measure the daemon's CPU with the debug view off, unwatched and watched; print it."""
    from avoidd.bench.debugview import format_report, run_bench

    report = asyncio.run(run_bench(args.config, args.seconds, args.stream_fps))
    print(format_report(report))
    if args.json is not None:
        args.json.write_text(json.dumps(report, indent=2) + "\n")
    return EXIT_OK


def run_sim_bench(args: argparse.Namespace) -> int:
    """Print the simulator's figures."""
    from avoidd.bench.sim import OBJECTS, lockstep_time, planner_cost, render_rates

    render = render_rates(args.frames)
    planner = planner_cost(args.cycles)
    lockstep = lockstep_time()
    report = {"render": render, "planner": planner, "lockstep_30s": lockstep}
    print(f"stereo renderer, {OBJECTS}-object world, one core:")
    for row in render:
        print(
            f"  {row['size']:>8}: {row['pairs_per_s']:6.1f} pairs/s ({row['ms_per_pair']} ms); "
            f"ray-cast scene renderer {row['raycast_scene_ms_per_pair']} ms "
            f"(x{row['speedup']})"
        )
    print(
        f"planner: decide {planner['decide_ms_mean']} ms mean, {planner['decide_ms_p95']} ms "
        f"p95, {planner['decide_cpu_ms_mean']} ms of CPU; observe "
        f"{planner['observe_ms_mean']} ms ({planner['remembered_points']} points)"
    )
    print(f"lockstep, 30 s pole forest, 320x240 stereo at 15 Hz: {lockstep['wall_s']} s wall")
    if args.json is not None:
        args.json.write_text(json.dumps(report, indent=2) + "\n")
    return EXIT_OK
