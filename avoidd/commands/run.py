"""``avoidd run``: the daemon in the foreground until SIGINT or SIGTERM."""

from __future__ import annotations

import argparse
import asyncio
import logging
from pathlib import Path
from typing import TYPE_CHECKING

from avoidd.config import AppConfig
from avoidd.daemon import Daemon
from avoidd.errors import ConfigError
from avoidd.loading import load_all
from avoidd.vision.calibration import Calibration

if TYPE_CHECKING:
    from avoidd.record import Recorder

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
    from avoidd.commands.record import check_limits

    check_limits(None, args.record_max_gb, "--record-")
    return asyncio.run(_run_recording(args, config, calibrations))


def _open_recording(args: argparse.Namespace, config: AppConfig) -> Recorder | None:
    """The recorder of ``--record``, or None (logged) when it cannot record: flying comes first.

    A folder already in use (a board without a clock repeats its ``strftime`` names after a
    reboot) gets a free ``-2``, ``-3`` ... suffix instead.
    """
    from avoidd.record import Recorder, expand_folder, folder_in_use, prepare_folder

    wanted = expand_folder(args.record)
    names = [wanted, *(wanted.with_name(f"{wanted.name}-{n}") for n in range(2, 1000))]
    folder = next((name for name in names if not folder_in_use(name)), None)
    if folder is None:
        logger.error("--record %s: every name up to -999 is in use; not recording", wanted)
        return None
    if folder != wanted:
        logger.warning("--record %s: in use; recording into %s instead", wanted, folder)
    max_bytes = None if args.record_max_gb is None else int(args.record_max_gb * 1e9)
    try:
        prepare_folder(folder, args.config, config)
        recorder = Recorder(folder, [h.name for h in config.heads], max_bytes)
    except (ConfigError, OSError) as exc:
        why = exc.lines[0] if isinstance(exc, ConfigError) else f"{folder}: {exc}"
        logger.error("%s; the daemon runs without recording", why)
        return None

    def stopped(why: str) -> None:
        logger.warning("recording stopped: %s; the daemon goes on; %s", why, recorder.summary())

    recorder.on_stop = stopped
    return recorder


async def _run_recording(
    args: argparse.Namespace, config: AppConfig, calibrations: dict[str, Calibration]
) -> int:
    """The daemon with a recorder on its heads; a recording problem stops only the recording."""
    from avoidd.record import capture_state

    recorder = _open_recording(args, config)
    if recorder is None:
        return await Daemon(config, calibrations).run()
    daemon = Daemon(config, calibrations, on_frame=recorder.offer)
    recorder.start(
        asyncio.get_running_loop(),
        lambda frame: capture_state(frame, daemon.pose_for(frame), daemon.vehicle),
    )
    logger.info("recording every head into %s", recorder.folder)
    try:
        return await daemon.run()
    finally:
        await recorder.aclose()
        logger.info("recording closed: %s", recorder.summary())
