"""``avoidd record``: every head's frames and the autopilot's state into a folder, no avoidance."""

from __future__ import annotations

import argparse
import asyncio
from pathlib import Path

from avoidd.errors import ConfigError
from avoidd.loading import load_all


def configure(name: str, parser: argparse.ArgumentParser) -> None:
    """Add the options of ``record``."""
    parser.add_argument("--config", type=Path, required=True, help="YAML configuration file")
    parser.add_argument(
        "--out",
        type=Path,
        required=True,
        metavar="DIR",
        help="new folder to record into (strftime fields such as %%Y%%m%%d-%%H%%M%%S filled in)",
    )
    parser.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    parser.add_argument(
        "--max-gb", type=float, metavar="G", help="stop before the recording passes G GB"
    )
    parser.set_defaults(handler=run_record)


def check_limits(duration_s: float | None, max_gb: float | None, prefix: str = "--") -> None:
    """Refuse limits that are not positive (exit 2).

    Raises:
        ConfigError: A limit of 0 or less.
    """
    for name, value in (("duration", duration_s), ("max-gb", max_gb)):
        if value is not None and not value > 0:
            raise ConfigError([f"{prefix}{name} {value:g}: give a number above 0, or leave it out"])


def run_record(args: argparse.Namespace) -> int:
    """Record until a limit, SIGINT or SIGTERM; 0 on a clean stop."""
    from avoidd.record import Recorder, expand_folder, prepare_folder, record

    check_limits(args.duration, args.max_gb)
    config, calibrations = load_all(args.config)
    _ = config.mavlink.link  # a config without a connection stops here (exit 2)
    folder = expand_folder(args.out)
    prepare_folder(folder, args.config, config)
    max_bytes = None if args.max_gb is None else int(args.max_gb * 1e9)
    recorder = Recorder(folder, [h.name for h in config.heads], max_bytes)
    return asyncio.run(record(config, calibrations, recorder, args.duration))
