"""The ``avoidd`` command line: the parser, logging set-up and the mapping of errors to exit codes.

The commands themselves live in :mod:`avoidd.commands`, one module per family.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import signal
import sys
from collections.abc import Sequence

from avoidd import __version__
from avoidd.commands import EXIT_CONFIG, EXIT_FAILURE, EXIT_OK, add_commands, chosen_command
from avoidd.errors import AvoiddError, ConfigError

logger = logging.getLogger("avoidd")


def _setup_logging(level: str) -> None:
    # Under journald the journal stamps each line; elsewhere a time helps.
    if os.environ.get("JOURNAL_STREAM"):
        fmt = "%(levelname)s %(name)s: %(message)s"
    else:
        fmt = "%(asctime)s %(levelname)s %(name)s: %(message)s"
    logging.basicConfig(level=getattr(logging, level), format=fmt, stream=sys.stderr)
    _quiet_opencv()


def _quiet_opencv() -> None:
    """Keep OpenCV's own warnings out of the log unless ``OPENCV_LOG_LEVEL`` asks for them.

    OpenCV prints to stderr by itself, per call: two lines for every unreadable image, which a
    missing input folder turns into two lines per frame. avoidd reports such faults itself.
    The variable is read when OpenCV first logs; if it is already loaded, its level is set too.
    """
    if "OPENCV_LOG_LEVEL" in os.environ:
        return
    os.environ["OPENCV_LOG_LEVEL"] = "ERROR"
    cv2 = sys.modules.get("cv2")
    if cv2 is not None:
        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)


def build_parser(chosen: str | None = None) -> argparse.ArgumentParser:
    """The argument parser of the ``avoidd`` command.

    Args:
        chosen: The subcommand that will run: only its options are added (and only its module
            imported); the others are listed by name and summary.
    """
    parser = argparse.ArgumentParser(
        prog="avoidd", description="Stereo-vision obstacle avoidance for ArduPilot and PX4."
    )
    parser.add_argument("--version", action="version", version=f"avoidd {__version__}")
    parser.add_argument(
        "--log-level", default="INFO", choices=["DEBUG", "INFO", "WARNING", "ERROR"]
    )
    add_commands(parser.add_subparsers(dest="command", required=True), chosen)
    return parser


class _Terminated(BaseException):
    """SIGTERM before the command took signals over: a stop asked for, exit 0 like a later one."""


def _terminate(signum: int, frame: object) -> None:
    raise _Terminated


def _stop_on_sigterm() -> object:
    """Make SIGTERM a clean stop from now on; returns the handler it replaced (None: none).

    Until the command installs its own handling (the daemon's event loop, the recorder's),
    SIGTERM would kill the process with the default action (exit 143; systemd's stop during
    the first 0.7 s of imports and loading did): it stops as Ctrl-C does instead. Only the
    main thread may set it; elsewhere nothing changes.
    """
    try:
        return signal.signal(signal.SIGTERM, _terminate)
    except ValueError:
        return None


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``avoidd`` command.

    Args:
        argv: Arguments without the program name (default: ``sys.argv[1:]``).

    Returns:
        The exit code: 0 ok (Ctrl-C and SIGTERM included, however early), 1 runtime failure,
        2 configuration error.
    """
    previous = _stop_on_sigterm()
    try:
        return _main(list(sys.argv[1:] if argv is None else argv))
    except (KeyboardInterrupt, _Terminated):
        return EXIT_OK
    finally:
        if previous is not None:
            with contextlib.suppress(ValueError, TypeError):
                signal.signal(signal.SIGTERM, previous)  # type: ignore[arg-type]


def _main(argv: list[str]) -> int:
    # Ctrl-C or SIGTERM while the command's modules load is no error either (see main).
    args = build_parser(chosen_command(argv)).parse_args(argv)
    _setup_logging(args.log_level)
    try:
        code: int = args.handler(args)
    except ConfigError as exc:
        for line in exc.lines:
            print(line, file=sys.stderr)
        print("configuration invalid; nothing was started", file=sys.stderr)
        return EXIT_CONFIG
    except AvoiddError as exc:
        logger.error("%s", exc)
        return EXIT_FAILURE
    return code
