"""``avoidd run``: the daemon in the foreground until SIGINT or SIGTERM."""

from __future__ import annotations

import argparse
import asyncio
import logging
from pathlib import Path

from avoidd.config import AppConfig
from avoidd.daemon import Daemon
from avoidd.errors import ConfigError
from avoidd.loading import load_all
from avoidd.vision.calibration import Calibration

logger = logging.getLogger(__name__)


def configure(name: str, parser: argparse.ArgumentParser) -> None:
    """Add the options of ``run``."""
    parser.add_argument("--config", type=Path, required=True, help="YAML configuration file")
    parser.add_argument(
        "--record",
        type=Path,
        metavar="DIR",
        help="also record every head's frames into this new folder (see avoidd record)",
    )
    parser.add_argument(
        "--record-max-gb",
        type=float,
        metavar="G",
        help="stop recording (not the daemon) before the recording passes G GB",
    )
    parser.set_defaults(handler=run_daemon)


def run_daemon(args: argparse.Namespace) -> int:
    """Load the configuration and run the daemon; returns its exit code."""
    config, calibrations = load_all(args.config)
    _ = config.mavlink.link  # a config without a connection stops here (exit 2)
    if args.record is None:
        if args.record_max_gb is not None:
            raise ConfigError(["--record-max-gb: only with --record DIR"])
        return asyncio.run(Daemon(config, calibrations).run())
    return asyncio.run(_run_recording(args, config, calibrations))


async def _run_recording(
    args: argparse.Namespace, config: AppConfig, calibrations: dict[str, Calibration]
) -> int:
    """The daemon with a recorder on its heads; a recording limit stops only the recording."""
    from avoidd.commands.record import check_limits
    from avoidd.record import Recorder, capture_state, expand_folder, prepare_folder

    check_limits(None, args.record_max_gb, "--record-")
    folder = expand_folder(args.record)
    prepare_folder(folder, args.config, config)
    max_bytes = None if args.record_max_gb is None else int(args.record_max_gb * 1e9)

    def stopped(why: str) -> None:
        logger.warning("recording stopped: %s; the daemon goes on; %s", why, recorder.summary())

    recorder = Recorder(folder, [h.name for h in config.heads], max_bytes, on_stop=stopped)
    daemon = Daemon(config, calibrations, on_frame=recorder.offer)
    recorder.start(
        asyncio.get_running_loop(),
        lambda frame: capture_state(frame, daemon.pose_for(frame), daemon.vehicle),
    )
    logger.info("recording every head into %s", folder)
    try:
        return await daemon.run()
    finally:
        await recorder.aclose()
        logger.info("recording closed: %s", recorder.summary())
