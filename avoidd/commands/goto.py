"""``avoidd goto``: send the running avoidd a goal, as a ground station does."""

from __future__ import annotations

import argparse
import asyncio

from avoidd.commands import EXIT_FAILURE, EXIT_OK
from avoidd.errors import ConfigError
from avoidd.mavlink.goto import GlobalGoal, LocalGoal, send_goal


def configure(name: str, parser: argparse.ArgumentParser) -> None:
    """Add the options of ``goto``."""
    parser.add_argument(
        "connection",
        help="where avoidd's MAVLink can be reached, e.g. udpout:127.0.0.1:14551 (avoidd's own "
        "mavlink.gcs_connection, or a router's ground-station endpoint)",
    )
    where = parser.add_mutually_exclusive_group(required=True)
    where.add_argument(
        "--ned",
        nargs=3,
        type=float,
        metavar=("NORTH_M", "EAST_M", "ALT_M"),
        help="local goal: metres north and east of the autopilot's origin, height above it",
    )
    where.add_argument(
        "--global",
        dest="global_",
        nargs=3,
        type=float,
        metavar=("LAT_DEG", "LON_DEG", "ALT_M"),
        help="global goal (sent as DO_REPOSITION); altitude above home unless --amsl",
    )
    parser.add_argument("--amsl", action="store_true", help="the altitude is above sea level")
    parser.add_argument("--system-id", type=int, help="vehicle system id (default: learned)")
    parser.add_argument("--timeout", type=float, default=10.0, help="seconds to wait (10)")
    parser.set_defaults(handler=run_goto)


def run_goto(args: argparse.Namespace) -> int:
    """Send the goal; 0 when avoidd took it, 1 when it refused or did not answer."""
    if not 0.5 <= args.timeout <= 600:
        raise ConfigError([f"--timeout {args.timeout}: give 0.5 to 600 seconds"])
    goal: LocalGoal | GlobalGoal
    if args.ned is not None:
        goal = LocalGoal(*args.ned)
    else:
        lat_deg, lon_deg, altitude_m = args.global_
        goal = GlobalGoal(lat_deg, lon_deg, altitude_m, amsl=args.amsl)
    try:
        answer = asyncio.run(send_goal(args.connection, goal, args.system_id, args.timeout))
    except ValueError as exc:
        raise ConfigError([f"goto: {exc}"]) from None
    print(answer.text)
    return EXIT_OK if answer.accepted else EXIT_FAILURE
