"""``avoidd eval`` (matchers on data with ground truth) and ``avoidd eval-perception``."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from avoidd.commands import EXIT_CONFIG, EXIT_OK
from avoidd.errors import ConfigError
from avoidd.evaluation.edges import edge_suite, format_edges, run_edge_case
from avoidd.evaluation.holes import SUITES, format_holes, hole_suite, run_hole_case
from avoidd.evaluation.metrics import REGIONS
from avoidd.evaluation.near import format_near, near_suite, run_near_case
from avoidd.evaluation.run import evaluate, format_details, format_runs
from avoidd.evaluation.scenes import SuiteSummary, contact_suite, draws, run_case, suite
from avoidd.progress import Progress


def configure(name: str, parser: argparse.ArgumentParser) -> None:
    """Add the options of ``eval`` or ``eval-perception``."""
    if name == "eval":
        parser.add_argument(
            "path", type=Path, help="a scene folder, a dataset folder, or a folder of them"
        )
        parser.add_argument(
            "--matcher",
            action="append",
            help="sgbm (default), sgbm-gated, sgbm-nopad, sad, sad-pad, census, segment, "
            "opencv-sgbm; repeat",
        )
        parser.add_argument("--max-scenes", type=int, help="stop after N scenes")
        parser.add_argument(
            "--region",
            choices=REGIONS,
            default="all",
            help="pixels scored: all with ground truth (default), or overlap: only columns >= "
            "the search range, which both cameras see (bare SGBM leaves the band left of it "
            "empty)",
        )
        parser.add_argument(
            "--num-disparities",
            type=_positive,
            metavar="N",
            help="search range for every scene, rounded up to a multiple of 16; default: the "
            "dataset's ndisp (Middlebury 2014 calib.txt), else the largest disparity its "
            "ground-truth encoding holds, else 192 (KITTI); never the ground truth's values",
        )
        parser.add_argument(
            "--threads",
            type=_positive,
            metavar="N",
            help="OpenCV threads while matching (restored after); the tables say the count",
        )
        parser.add_argument("--json", type=Path, help="also write the scores as JSON")
        parser.add_argument(
            "--detail",
            action="store_true",
            help="also print per matcher: estimates on whole pixels, sub-pixel error, and "
            "estimates too far in the left border band and right of it",
        )
        parser.set_defaults(handler=run_eval)
    else:
        parser.add_argument("--scenes", type=int, default=24, help="obstacle scenes (default 24)")
        parser.add_argument(
            "--seed",
            type=int,
            action="append",
            help="scene generator seed (default 2024); repeat for several draws, whose "
            "scenes are then named SEED/NAME and summed up per draw and over all",
        )
        parser.add_argument(
            "--contact-scenes", type=int, default=12, help="roll-free contact scenes"
        )
        parser.add_argument(
            "--near-scenes", type=int, default=24, help="walls, boxes, poles at 0.3-1.2 m"
        )
        parser.add_argument(
            "--edge-scenes", type=int, default=24, help="silhouettes across bin boundaries"
        )
        parser.add_argument(
            "--hole-scenes",
            type=int,
            default=24,
            help="scenes per hole suite (walls, pole rows, clutter): bins over a surface that "
            "read unknown or too far",
        )
        parser.set_defaults(handler=run_eval_perception)


def _positive(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"{value}: must be 1 or more")
    return value


def run_eval(args: argparse.Namespace) -> int:
    """Score the matchers and print (and optionally write) the table.

    A fault in what was asked (no scene, an unknown matcher) is printed as it is, with exit
    code 2: ``eval`` starts nothing, so the generic "configuration invalid" line would mislead.
    """
    try:
        runs = evaluate(
            args.path,
            args.matcher or ["sgbm"],
            args.max_scenes,
            region=args.region,
            num_disparities=args.num_disparities,
            threads=args.threads,
        )
    except ConfigError as exc:
        print("\n".join(exc.lines), file=sys.stderr)
        return EXIT_CONFIG
    print(format_runs(runs))
    if args.detail:
        print(format_details(runs))
    if args.json is not None:
        payload = [run.as_json() for run in runs]
        document = payload[0] if len(payload) == 1 else payload
        args.json.write_text(json.dumps(document, indent=2) + "\n")
    return EXIT_OK


def run_eval_perception(args: argparse.Namespace) -> int:
    """Score perception on the rendered suites and print the summaries."""
    seeds = args.seed or [2024]
    scenes = suite(args.scenes, seeds[0]) if len(seeds) == 1 else draws(seeds, args.scenes)
    cases = scenes + contact_suite(args.contact_scenes)
    near_cases = near_suite(args.near_scenes) if args.near_scenes else []
    edge_cases = edge_suite(args.edge_scenes) if args.edge_scenes else []
    hole_cases = [(name, case) for name in SUITES for case in hole_suite(name, args.hole_scenes)]
    total = len(cases) + len(near_cases) + len(edge_cases) + len(hole_cases)
    with Progress(total) as progress:
        results = []
        for case in cases:
            results.append(run_case(case))
            progress.step(case.name)
        near = []
        for case in near_cases:
            near.append(run_near_case(case))
            progress.step(f"near {case.name}")
        edges = []
        for case in edge_cases:
            edges.append(run_edge_case(case))
            progress.step(f"edge {case.name}")
        holes = []
        for name, case in hole_cases:
            holes.append(run_hole_case(case, name))
            progress.step(f"holes {case.name}")
    summary = SuiteSummary(results)
    print(summary.format())
    if len(seeds) > 1:
        for seed in seeds:
            draw = SuiteSummary([r for r in summary.results if r.name.startswith(f"{seed}/")])
            print(f"draw {seed}: {draw.headline()}")
    if near:
        print()
        print(format_near(near))
    if edges:
        print()
        print(format_edges(edges))
    if holes:
        print()
        print(format_holes(holes))
    return EXIT_OK
