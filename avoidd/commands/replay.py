"""``avoidd replay``: every frame of a head's source through the pipeline, into JSON lines."""

from __future__ import annotations

import argparse
from pathlib import Path

from avoidd.commands import EXIT_OK
from avoidd.errors import ConfigError, SourceError
from avoidd.loading import load_all
from avoidd.replay import format_summary, replay, select_head


def configure(name: str, parser: argparse.ArgumentParser) -> None:
    """Add the options of ``replay``."""
    parser.add_argument("--config", type=Path, required=True, help="YAML configuration file")
    parser.add_argument(
        "--input", type=Path, help="folder of left/right pairs or side-by-side video"
    )
    parser.add_argument("--max-frames", type=int, help="stop after N frames")
    parser.add_argument("--head", help="head to replay (default: the first)")
    parser.add_argument("--out", type=Path, required=True, help="output .jsonl file")
    parser.add_argument(
        "--plot",
        type=Path,
        help="also draw the nearest reading over time (and the truth, when the input has it) "
        "to this PNG",
    )
    parser.add_argument(
        "--realtime",
        action="store_true",
        help="pace frames by their capture times (a recording plays at its recorded speed)",
    )
    parser.set_defaults(handler=run_replay)


def run_replay(args: argparse.Namespace) -> int:
    """Replay one head and print the summary.

    Raises:
        ConfigError: A bad argument or configuration (exit 2).
        SourceError: No frame could be processed (exit 1), with the reason.
    """
    if args.max_frames is not None and args.max_frames < 1:
        raise ConfigError([f"--max-frames {args.max_frames}: give 1 or more, or leave it out"])
    config, calibrations = load_all(args.config, input_given=args.input is not None)
    head = select_head(config, args.head)
    if args.input is not None and not args.input.exists():
        raise ConfigError([f"--input {args.input}: not found; give a folder or a video file"])
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with args.out.open("w", encoding="utf-8") as out:
        summary = replay(
            config,
            calibrations[head.name],
            head,
            out,
            args.input,
            args.max_frames,
            realtime=args.realtime,
        )
    print(format_summary(summary))
    print(f"wrote {summary.frames} lines to {args.out}")
    if args.plot is not None and summary.frames:
        from avoidd.replay_plot import plot_nearest, read_records, series_of

        args.plot.parent.mkdir(parents=True, exist_ok=True)
        title = f"{head.name}: {summary.frames} frames of {summary.source}"
        plot_nearest(series_of(read_records(args.out)), title, args.plot)
        print(f"wrote {args.plot}")
    if summary.frames == 0:
        reason = (
            f"all {summary.dropped} frames were unusable (see the warnings above)"
            if summary.dropped
            else "it delivered no frame (an empty or unreadable video?)"
        )
        raise SourceError(f"replay: no frame processed from {summary.source}: {reason}")
    return EXIT_OK
