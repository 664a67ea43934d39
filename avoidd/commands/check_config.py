"""``avoidd check-config``: validate a configuration and everything it names, touch nothing."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from avoidd.commands import EXIT_OK
from avoidd.loading import head_min_range_m, head_resolved_range_m, load_all, obstacle_range_cm


def configure(name: str, parser: argparse.ArgumentParser) -> None:
    """Add the options of ``check-config``."""
    parser.add_argument("config", type=Path, help="YAML configuration file")
    parser.set_defaults(handler=check_config)


def check_config(args: argparse.Namespace) -> int:
    """Validate and print a summary of each head, what it can measure, and the link."""
    config, calibrations = load_all(args.config)
    for head in config.heads:
        rig = calibrations[head.name].rig
        band = head.matcher.num_disparities
        # The first num_disparities columns cannot be matched: the effective field of view
        # starts at that column.
        left_deg = math.degrees(math.atan((band - rig.cx) / rig.fx))
        right_deg = math.degrees(math.atan((rig.width - 1 - rig.cx) / rig.fx))
        min_range = head_min_range_m(head, calibrations[head.name])
        resolved = head_resolved_range_m(head, calibrations[head.name])
        near = "with" if head.near_field.enabled else "without"
        print(
            f"head '{head.name}': {head.source.kind}, {rig.width}x{rig.height}, "
            f"fx {rig.fx:.1f} px, baseline {rig.baseline_m:.4f} m, "
            f"HFOV {rig.hfov_deg:.1f} deg, yaw {head.mount.yaw_deg:+.0f} deg\n"
            f"  measures from {min_range:.2f} m ({near} the near-field pass; "
            f"f*B/(num_disparities-1) = {rig.fx * rig.baseline_m / (band - 1):.2f} m), "
            f"effective HFOV {right_deg - left_deg:.1f} deg "
            f"({left_deg:+.1f} to {right_deg:+.1f} deg, left {band} columns unmatched)\n"
            f"  resolves to {resolved:.1f} m (f*B/(2*disparity_error_px), "
            f"{head.disparity_error_px:g} px: a 50% range error there; clear claims no farther)"
        )
    mavlink = config.mavlink
    min_cm, max_cm = obstacle_range_cm(
        mavlink.obstacle_distance, ((h, calibrations[h.name]) for h in config.heads)
    )
    signed = ", signed" if mavlink.signing is not None else ""
    if mavlink.connection is None:
        print("MAVLink: no connection (offline commands only; `avoidd run` needs one)")
    else:
        print(f"MAVLink {mavlink.link} as system {mavlink.system_id}{signed}")
    cut = ""
    configured_cm = mavlink.obstacle_distance.max_distance_cm
    if max_cm < configured_cm:
        cut = f" (max_distance_cm {configured_cm} cut to what the rig resolves)"
    print(f"OBSTACLE_DISTANCE range {min_cm} to {max_cm} cm{cut}")
    print(f"{args.config}: OK")
    return EXIT_OK
