"""``avoidd mock-autopilot``: a mock ArduPilot or PX4 speaking real MAVLink 2, for tests."""

from __future__ import annotations

import argparse
import asyncio
from pathlib import Path

from avoidd.commands import EXIT_OK
from avoidd.errors import ConfigError
from avoidd.mavlink.mock_autopilot import MockAutopilot, serve
from avoidd.mavlink.signing import load_key


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
    try:
        autopilot = MockAutopilot(
            flavour=args.flavour,
            system_id=args.system_id,
            mode=args.mode or "",
            armed=args.armed,
            key=load_key(args.key_file, None) if args.key_file else None,
            fixed_streams=streams,
        )
    except (KeyError, ValueError) as exc:
        raise ConfigError([f"mock-autopilot: {exc}"]) from None
    asyncio.run(serve(autopilot, args.connection, args.duration))
    return EXIT_OK
