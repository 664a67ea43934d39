"""``avoidd mock-autopilot``: a mock ArduPilot or PX4 speaking real MAVLink 2, for tests."""

from __future__ import annotations

import argparse
import asyncio
from pathlib import Path
from typing import Any

import numpy as np

from avoidd.commands import EXIT_OK
from avoidd.errors import ConfigError
from avoidd.mavlink.geo import valid_lat_lon
from avoidd.mavlink.mock_autopilot import MockAutopilot, serve
from avoidd.mavlink.signing import load_key

DEFAULT_ORIGIN = (47.397742, 8.545594, 488.0)
"""Where the flying mock is, unless told: the PX4 SITL's default home (Zurich)."""


def configure(name: str, parser: argparse.ArgumentParser) -> None:
    """Add the options of ``mock-autopilot``."""
    parser.add_argument(
        "connection", help="udpin:/udpout:/tcpin:/tcp:HOST:PORT, or pty:PATH for a serial line"
    )
    parser.add_argument("--flavour", choices=["ardupilot", "px4"], default="ardupilot")
    parser.add_argument("--system-id", type=int, default=1)
    parser.add_argument("--mode", help="flight mode name (default STABILIZE / POSCTL)")
    parser.add_argument("--armed", action="store_true")
    parser.add_argument("--key-file", type=Path, help="sign with this key; ignore unsigned input")
    parser.add_argument(
        "--stream", action="append", default=[], help="NAME=HZ: stream without being asked"
    )
    parser.add_argument("--duration", type=float, help="stop after this many seconds")
    parser.add_argument(
        "--fly",
        action="store_true",
        help="a vehicle that flies: GUIDED/OFFBOARD velocity and position setpoints move it, "
        "and it reports where it is (LOCAL_POSITION_NED, GLOBAL_POSITION_INT); with a home and "
        "an origin",
    )
    parser.add_argument(
        "--origin",
        nargs=3,
        type=float,
        metavar=("LAT_DEG", "LON_DEG", "ALT_M"),
        help=f"EKF origin and home (default with --fly: {' '.join(map(str, DEFAULT_ORIGIN))}, "
        "the PX4 SITL default)",
    )
    parser.add_argument(
        "--altitude",
        type=float,
        default=2.0,
        help="with --fly: metres above the origin it starts hovering at (2)",
    )
    parser.set_defaults(handler=run_mock)


def run_mock(args: argparse.Namespace) -> int:
    """Serve the mock autopilot until the duration ends or it is interrupted."""
    streams: dict[str, float] = {}
    for item in args.stream:
        name, _, rate = item.partition("=")
        try:
            streams[name] = float(rate)
        except ValueError:
            raise ConfigError([f"--stream {item}: write NAME=HZ, e.g. ATTITUDE=50"]) from None
    origin = tuple(args.origin) if args.origin else (DEFAULT_ORIGIN if args.fly else None)
    if origin is not None and not valid_lat_lon(origin[0], origin[1]):
        raise ConfigError([f"--origin {origin[0]} {origin[1]}: not a latitude and longitude"])
    if origin is not None and not -500.0 <= origin[2] <= 9000.0:
        raise ConfigError([f"--origin altitude {origin[2]}: give -500 to 9000 metres AMSL"])
    settings: dict[str, Any] = {
        "flavour": args.flavour,
        "system_id": args.system_id,
        "mode": args.mode or "",
        "armed": args.armed,
        "key": load_key(args.key_file, None) if args.key_file else None,
        "fixed_streams": streams,
        "origin": origin,
    }
    flying = None
    try:
        autopilot: MockAutopilot
        if args.fly:
            if not 0.0 <= args.altitude <= 100.0:
                raise ConfigError([f"--altitude {args.altitude}: give 0 to 100 metres"])
            from avoidd.sim.mav_autopilot import SimulatedAutopilot
            from avoidd.sim.vehicle import Multirotor, VehicleState

            # What a ground station's map needs, whether avoidd asks for it or not.
            settings["fixed_streams"] = {"GLOBAL_POSITION_INT": 5.0, **streams}
            start = VehicleState(position_m=np.array([0.0, 0.0, -args.altitude]))
            autopilot = flying = SimulatedAutopilot(**settings, vehicle=Multirotor(state=start))
        else:
            autopilot = MockAutopilot(**settings)
    except (KeyError, ValueError) as exc:
        raise ConfigError([f"mock-autopilot: {exc}"]) from None
    asyncio.run(serve(autopilot, args.connection, args.duration))
    if flying is not None:
        north, east, down = (float(v) for v in flying.vehicle.state.position_m)
        print(f"the vehicle ended {north:.1f} m north, {east:.1f} m east, {-down:.1f} m up")
    return EXIT_OK
