"""``avoidd run``: the daemon in the foreground until SIGINT or SIGTERM."""

from __future__ import annotations

import argparse
import asyncio
from pathlib import Path

from avoidd.daemon import Daemon
from avoidd.loading import load_all


def configure(name: str, parser: argparse.ArgumentParser) -> None:
    """Add the options of ``run``."""
    parser.add_argument("--config", type=Path, required=True, help="YAML configuration file")
    parser.set_defaults(handler=run_daemon)


def run_daemon(args: argparse.Namespace) -> int:
    """Load the configuration and run the daemon; returns its exit code."""
    config, calibrations = load_all(args.config)
    _ = config.mavlink.link  # a config without a connection stops here (exit 2)
    return asyncio.run(Daemon(config, calibrations).run())
