"""``avoidd check-config``: validate a configuration and everything it names, touch nothing."""

from __future__ import annotations

import argparse
from pathlib import Path

from avoidd.commands import EXIT_OK
from avoidd.loading import load_all


def configure(name: str, parser: argparse.ArgumentParser) -> None:
    """Add the options of ``check-config``."""
    parser.add_argument("config", type=Path, help="YAML configuration file")
    parser.set_defaults(handler=check_config)


def check_config(args: argparse.Namespace) -> int:
    """Validate and print a summary of each head and the link."""
    config, calibrations = load_all(args.config)
    for head in config.heads:
        rig = calibrations[head.name].rig
        print(
            f"head '{head.name}': {head.source.kind}, {rig.width}x{rig.height}, "
            f"fx {rig.fx:.1f} px, baseline {rig.baseline_m:.4f} m, "
            f"HFOV {rig.hfov_deg:.1f} deg, yaw {head.mount.yaw_deg:+.0f} deg"
        )
    signed = ", signed" if config.mavlink.signing is not None else ""
    print(f"MAVLink {config.mavlink.link} as system {config.mavlink.system_id}{signed}")
    print(f"{args.config}: OK")
    return EXIT_OK
