"""``avoidd bench-link``: CPU that avoidd spends decoding a busy incoming MAVLink stream.

A mock autopilot in a separate process streams ATTITUDE, LOCAL_POSITION_NED and DISTANCE_SENSOR
over loopback UDP at the asked total rate; this process receives them with the daemon's own link
and vehicle code and measures its CPU time (user + system) and event-loop lag over a window.
With ``stranger`` the link first adopts an autopilot at another address (its heartbeats sent
from here), so the stream is a stranger's: the figure is what dropping a flood unread costs.
"""

from __future__ import annotations

import asyncio
import contextlib
import resource
import socket
import sys
import time
from typing import Any

from avoidd.aio import cancel_task
from avoidd.config import MavlinkConfig, StreamsConfig
from avoidd.looplag import LagMonitor
from avoidd.mavlink.codec import Codec
from avoidd.mavlink.link import MavLink
from avoidd.mavlink.vehicle import Vehicle

_SHARES = (("ATTITUDE", 0.5), ("LOCAL_POSITION_NED", 0.25), ("DISTANCE_SENSOR", 0.25))
_WARMUP_S = 1.5


def _cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def _ignore(severity: int, text: str, key: str | None = None) -> None:
    """An announcer that drops everything (nobody to tell during a benchmark)."""


async def _adopted_autopilot(port: int) -> None:
    """An autopilot's heartbeat twice a second from a socket of its own, until cancelled."""
    codec = Codec(1, 1)
    heartbeat = codec.pack(codec.build("HEARTBEAT", 2, 3, 0, 0, 4))  # a quadrotor, ArduPilot
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        while True:
            sock.sendto(heartbeat, ("127.0.0.1", port))
            await asyncio.sleep(0.5)


async def run_bench(
    rate_hz: float, seconds: float, asked: bool = False, stranger: bool = False
) -> dict[str, Any]:
    """Stream ``rate_hz`` messages per second at this process for ``seconds`` and measure.

    Args:
        rate_hz: Total rate of the mock's fixed streams (unused with ``asked``).
        seconds: Length of the measured window.
        asked: Instead of fixed streams, the mock sends what avoidd asks of it with
            ``MAV_CMD_SET_MESSAGE_INTERVAL`` at the default ``mavlink.streams`` rates, as a
            real autopilot would.
        stranger: The link has adopted an autopilot at another address first: the stream is
            a stranger's, counted and dropped unread.

    Returns:
        Figures: messages received per second (in all and by type), CPU percent of one core,
        microseconds of CPU per message, parse errors and the largest event-loop lag.
    """
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    config = MavlinkConfig(
        connection=f"udpin:127.0.0.1:{port}",
        streams=StreamsConfig()
        if asked
        else StreamsConfig(
            attitude_hz=0, local_position_hz=0, distance_sensor_hz=0, system_time_hz=0
        ),
    )
    link = MavLink(config.link, Codec(1, 196))
    vehicle = Vehicle(link, config, _ignore)
    await link.open()
    adopted = asyncio.create_task(_adopted_autopilot(port)) if stranger else None
    if adopted is not None:
        while link.autopilot_sender is None:
            await asyncio.sleep(0.01)
    command = _sender(port, rate_hz, _WARMUP_S + seconds + 2.0, asked, stranger)
    mock = await asyncio.create_subprocess_exec(sys.executable, *command)
    lag = LagMonitor()
    lag_task = asyncio.create_task(lag.run())
    try:
        await asyncio.sleep(_WARMUP_S)
        if asked:
            await _acknowledged(vehicle)
        lag.reset()
        by_type0 = dict(link.received)
        count0 = sum(link.received.values()) + _dropped(link)
        cpu0, wall0 = _cpu_s(), time.perf_counter()
        await asyncio.sleep(seconds)
        cpu_s, wall_s = _cpu_s() - cpu0, time.perf_counter() - wall0
        count = sum(link.received.values()) + _dropped(link) - count0
        by_type = {
            k: v - by_type0.get(k, 0)
            for k, v in sorted(link.received.items())
            if v > by_type0.get(k, 0)
        }
    finally:
        await cancel_task(lag_task)
        await cancel_task(adopted)
        with contextlib.suppress(ProcessLookupError):
            mock.terminate()
        await mock.wait()
        await link.close()
    return {
        "streams": "asked" if asked else "stranger" if stranger else "fixed",
        "rate_asked_hz": "default streams" if asked else rate_hz,
        "seconds": round(wall_s, 3),
        "received_per_s": round(count / wall_s, 1),
        "received_per_s_by_type": {k: round(v / wall_s, 1) for k, v in by_type.items()},
        "cpu_percent_one_core": round(100.0 * cpu_s / wall_s, 2),
        "cpu_us_per_message": round(1e6 * cpu_s / max(count, 1), 2),
        "parse_errors": link.parse_errors,
        "max_loop_lag_ms": round(lag.max_lag_ms, 2),
        "max_own_loop_lag_ms": round(lag.max_own_lag_ms, 2),
    }


def format_report(report: dict[str, Any]) -> str:
    """The figures as a short human-readable block."""
    return "\n".join(
        [
            f"incoming MAVLink over loopback UDP, {_asked(report)} for {report['seconds']} s",
            f"  received          {report['received_per_s']:.0f} msg/s: "
            + ", ".join(f"{k} {v:.1f}" for k, v in report["received_per_s_by_type"].items()),
            f"  CPU               {report['cpu_percent_one_core']:.1f}% of one core "
            f"({report['cpu_us_per_message']:.1f} us per message)",
            f"  parse errors      {report['parse_errors']}",
            f"  max loop lag      {report['max_loop_lag_ms']:.1f} ms "
            f"({report['max_own_loop_lag_ms']:.1f} ms not waiting for a CPU)",
        ]
    )


async def _acknowledged(vehicle: Vehicle) -> None:
    """Tick the vehicle (as the daemon does) until the mock acknowledged every request."""
    deadline_s = time.monotonic() + 10.0
    while not (vehicle.link_up and vehicle.requests and vehicle.streams_acknowledged):
        if time.monotonic() > deadline_s:
            raise RuntimeError("the mock autopilot acknowledged no stream request")
        vehicle.tick(time.monotonic_ns())
        await asyncio.sleep(0.05)
    await asyncio.sleep(0.5)


def _sender(port: int, rate_hz: float, duration_s: float, asked: bool, stranger: bool) -> list[str]:
    """The Python arguments of the process that sends: the mock autopilot, or a flood."""
    if stranger:  # a copy of one frame, sent fast (see avoidd.bench.flood)
        return ["-m", "avoidd.bench.flood", str(port), f"{rate_hz:g}", f"{duration_s:g}"]
    streams = [] if asked else [f"--stream={name}={rate_hz * share:g}" for name, share in _SHARES]
    command = ["-m", "avoidd", "--log-level=WARNING", "mock-autopilot"]
    return [*command, f"udpout:127.0.0.1:{port}", f"--duration={duration_s}", *streams]


def _dropped(link: MavLink) -> int:
    """Datagrams of strangers counted and dropped unread so far."""
    return sum(count.datagrams for count in link.strangers.values())


def _asked(report: dict[str, Any]) -> str:
    if report["streams"] == "asked":
        return "streams asked with SET_MESSAGE_INTERVAL at the default rates"
    if report["streams"] == "stranger":
        return f"a stranger's {report['rate_asked_hz']:g} msg/s, dropped unread"
    return f"fixed streams of {report['rate_asked_hz']:g} msg/s in all"
