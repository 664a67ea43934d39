"""``avoidd bench --daemon CONFIG``: how often the daemon sends, and how much of it is fresh.

The daemon runs in this process on a configuration's heads, with its link pointed at a UDP
listener here in place of the autopilot (no autopilot speaks, so a stale scan is withheld, not
sent). Over a window that starts once the first scan has arrived, the listener counts what it
hears and the heads' counters say how many frames were processed.
"""

from __future__ import annotations

import asyncio
import statistics
import time
from pathlib import Path
from typing import Any

from avoidd.daemon import Daemon
from avoidd.loading import load_all
from avoidd.mavlink import codec as mav
from avoidd.mavlink.codec import Codec, Message

_FIRST_SCAN_TIMEOUT_S = 60.0
_STATES = {
    mav.MAV_STATE_BOOT: "BOOT",
    mav.MAV_STATE_STANDBY: "STANDBY",
    mav.MAV_STATE_ACTIVE: "ACTIVE",
    mav.MAV_STATE_CRITICAL: "CRITICAL",
}


class _Listener(asyncio.DatagramProtocol):
    """Decodes what the daemon sends and keeps each message with its arrival time."""

    def __init__(self) -> None:
        self.codec = Codec(255, 190)
        self.heard: list[tuple[float, Message]] = []
        self.transport: asyncio.BaseTransport | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport

    def datagram_received(self, data: bytes, addr: Any) -> None:
        now_s = time.monotonic()
        self.heard.extend((now_s, message) for message in self.codec.decode(data))

    def of_type(self, kind: str, since_s: float = 0.0) -> list[Message]:
        return [m for t, m in self.heard if t >= since_s and m.get_type() == kind]


async def run_bench(config_path: Path, seconds: float) -> dict[str, Any]:
    """Run the daemon on ``config_path`` for ``seconds`` after its first scan and measure.

    Args:
        config_path: A daemon configuration; its ``mavlink.connection`` is replaced.
        seconds: Length of the measured window.

    Returns:
        Figures: the configured and measured OBSTACLE_DISTANCE rates, the share of scans
        that report an obstacle, scans withheld for stale data, HEARTBEAT states, and per
        head the frames processed per second and the mean capture-to-result latency.

    Raises:
        RuntimeError: No scan arrived within a minute.
    """
    config, calibrations = load_all(config_path)
    loop = asyncio.get_running_loop()
    transport, listener = await loop.create_datagram_endpoint(
        _Listener, local_addr=("127.0.0.1", 0)
    )
    port = transport.get_extra_info("sockname")[1]
    mavlink = config.mavlink.model_copy(update={"connection": f"udpout:127.0.0.1:{port}"})
    daemon = Daemon(config.model_copy(update={"mavlink": mavlink}), calibrations)
    task = asyncio.create_task(daemon.run())
    try:
        deadline = time.monotonic() + _FIRST_SCAN_TIMEOUT_S
        max_cm = mavlink.obstacle_distance.max_distance_cm

        def warmed_up() -> bool:
            # The first scans can know no bin yet (the temporal filter confirms a reading over
            # a few frames): the measurement starts with the first scan that knows one.
            return any(min(m.distances) <= max_cm for m in listener.of_type("OBSTACLE_DISTANCE"))

        while not warmed_up():
            if time.monotonic() > deadline or task.done():
                raise RuntimeError(f"{config_path}: no OBSTACLE_DISTANCE within a minute")
            await asyncio.sleep(0.02)
        start_s = time.monotonic()
        processed0 = {head.name: head.stats.processed for head in daemon.heads}
        withheld0 = daemon.outputs.withheld if daemon.outputs is not None else 0
        await asyncio.sleep(seconds)
        wall_s = time.monotonic() - start_s
        processed = {
            head.name: head.stats.processed - processed0[head.name] for head in daemon.heads
        }
        latency = {
            head.name: statistics.fmean(head.stats.latency_ms) if head.stats.latency_ms else 0.0
            for head in daemon.heads
        }
        withheld = (daemon.outputs.withheld if daemon.outputs is not None else 0) - withheld0
    finally:
        daemon.stop()
        await asyncio.wait_for(task, timeout=15.0)
        transport.close()
    scans = listener.of_type("OBSTACLE_DISTANCE", start_s)
    with_obstacle = sum(1 for m in scans if min(m.distances) <= max_cm)
    states: dict[str, int] = {}
    for heartbeat in listener.of_type("HEARTBEAT", start_s):
        name = _STATES.get(heartbeat.system_status, str(heartbeat.system_status))
        states[name] = states.get(name, 0) + 1
    return {
        "config": str(config_path),
        "seconds": round(wall_s, 2),
        "obstacle_distance_configured_hz": mavlink.obstacle_distance.rate_hz,
        "obstacle_distance_hz": round(len(scans) / wall_s, 2),
        "scans": len(scans),
        "scans_with_obstacle_percent": round(100.0 * with_obstacle / max(len(scans), 1), 1),
        "withheld_stale": withheld,
        "heartbeat_states": states,
        "heads": [
            {
                "name": name,
                "fps": round(processed[name] / wall_s, 2),
                "mean_latency_ms": round(latency[name], 1),
            }
            for name in processed
        ],
    }


def format_report(report: dict[str, Any]) -> str:
    """The figures as a short human-readable block."""
    lines = [
        f"daemon on {report['config']} for {report['seconds']} s after its first scan:",
        f"  OBSTACLE_DISTANCE {report['obstacle_distance_hz']:.1f} Hz "
        f"(configured {report['obstacle_distance_configured_hz']:g}), {report['scans']} scans, "
        f"{report['scans_with_obstacle_percent']:.1f}% reporting an obstacle, "
        f"{report['withheld_stale']} withheld as stale",
        "  HEARTBEAT states: "
        + (", ".join(f"{k} {v}" for k, v in report["heartbeat_states"].items()) or "none"),
    ]
    lines += [
        f"  head {h['name']}: {h['fps']:.1f} fps processed, mean latency "
        f"{h['mean_latency_ms']:.0f} ms"
        for h in report["heads"]
    ]
    return "\n".join(lines)
