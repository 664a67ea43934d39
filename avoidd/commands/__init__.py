"""The command layer: one module per command family; the parser imports only the one it runs.

``COMMANDS`` names every subcommand, its module and its one-line summary, so ``avoidd --help``
lists them all without importing any. The chosen command's module is imported and its
``configure(name, parser)`` adds the options and sets ``handler``: a function of the parsed
arguments that returns the exit code (pip's ``commands/__init__.py`` works the same way).
"""

from __future__ import annotations

import argparse
import importlib
from collections.abc import Sequence
from typing import TYPE_CHECKING

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_CONFIG = 2

if TYPE_CHECKING:
    Subcommands = argparse._SubParsersAction[argparse.ArgumentParser]

COMMANDS: dict[str, tuple[str, str]] = {
    "run": ("run", "run the daemon"),
    "record": (
        "record",
        "record every head's frames and the autopilot's state for replay (no avoidance)",
    ),
    "check-config": ("check_config", "validate a configuration, touch nothing"),
    "replay": ("replay", "process every frame offline into JSON lines"),
    "eval": ("evaluate", "score matchers on stereo data with ground truth (Middlebury, KITTI)"),
    "eval-perception": (
        "evaluate",
        "score obstacle perception on rendered scenes with exact truth",
    ),
    "bench": ("bench", "per-stage milliseconds of each matcher next to bare OpenCV SGBM"),
    "bench-link": ("bench", "measure CPU for decoding a stream of incoming MAVLink"),
    "bench-sim": ("bench", "simulator render rate, planner cost, lockstep scenario time"),
    "bench-debugview": ("bench", "CPU of the debug view: off, on without a viewer, with one"),
    "sim": ("sim", "closed-loop scenarios in the simulator: run one, or a batch"),
    "goto": ("goto", "send the running avoidd a goal, as a ground station does"),
    "cameras": ("cameras", "list the V4L2 cameras attached, with a config snippet for each"),
    "calibrate": ("calibrate", "stereo calibration from left/ and right/ images of a board"),
    "print-board": ("calibrate", "a calibration board as a PNG to print at true size"),
    "render-board": ("calibrate", "render board pairs through a virtual rig (to try calibrate)"),
    "import-calibration": (
        "calibrate",
        "convert a EuRoC sensor.yaml pair or a Middlebury calib.txt",
    ),
    "check-rectification": (
        "calibrate",
        "|dy| of features matched across rectified real pairs",
    ),
    "measure": (
        "measure",
        "range a pixel (or the nearest obstacle) by stereo and by the ground-plane geometry",
    ),
    "calibrate-mount": (
        "measure",
        "camera height and tilt from a view of flat ground, or from measured h and OP",
    ),
    "mock-autopilot": (
        "mock_autopilot",
        "run a mock ArduPilot/PX4 autopilot (for tests and sitl/)",
    ),
}
"""Subcommand -> (module in this package, summary), in the order ``--help`` lists them."""


def chosen_command(argv: Sequence[str]) -> str | None:
    """The first argument that names a subcommand, or None (``--help``, a typo)."""
    return next((arg for arg in argv if arg in COMMANDS), None)


def add_commands(commands: Subcommands, chosen: str | None) -> None:
    """Add every subcommand; only ``chosen`` gets its options (its module is imported)."""
    for name, (module, summary) in COMMANDS.items():
        parser = commands.add_parser(name, help=summary, description=summary)
        if name == chosen:
            importlib.import_module(f"avoidd.commands.{module}").configure(name, parser)
