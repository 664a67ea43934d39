"""``avoidd bench --daemon CONFIG``: how often the daemon sends, and how much of it is fresh.

The daemon runs in this process on a configuration's heads, with its link pointed at a UDP
listener here in place of the autopilot (no autopilot speaks, so a stale scan is withheld, not
sent). Over a window that starts once the first scan has arrived, the listener counts what it
hears and the heads' counters say how many frames were processed, how long each stage took
and what share of the window it was busy; the process's CPU time over the window says how
much of the machine the daemon used.
"""

from __future__ import annotations

import asyncio
import statistics
import time
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from avoidd.config import AppConfig, SyntheticSourceConfig
from avoidd.daemon import Daemon
from avoidd.daemon.head import HeadStats
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


async def run_bench(
    config_path: Path,
    seconds: float,
    threads: int | None = None,
    source_fps: float | None = None,
) -> dict[str, Any]:
    """Run the daemon on ``config_path`` for ``seconds`` after its first scan and measure.

    Args:
        config_path: A daemon configuration; its ``mavlink.connection`` is replaced.
        seconds: Length of the measured window.
        threads: Overrides ``pipeline.threads`` (None: the configuration's).
        source_fps: Overrides the frame rate of the heads' synthetic cameras (a camera
            faster than the pipeline makes ``fps`` the pipeline's sustained rate).

    Returns:
        Figures: the configured and measured OBSTACLE_DISTANCE rates, the share of scans
        that report an obstacle, scans withheld for stale data, HEARTBEAT states, the
        capture-to-send latency of the scans (p50, p99), the process's CPU (cores busy, ms
        per processed frame), and per head the frames processed per second, the
        capture-to-result latency (mean, p50, p99) and each stage's median time and busy
        share (``match_ms``, ``finish_ms``, ``match_busy``, ``finish_busy``).

    Raises:
        RuntimeError: No scan arrived within a minute.
        ValueError: ``source_fps`` given for a head whose camera is not synthetic.
    """
    config, calibrations = load_all(config_path)
    config = _overridden(config, threads, source_fps)
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
        cpu0_s, clock0_s = time.process_time(), time.perf_counter()
        processed0 = {head.name: head.stats.processed for head in daemon.heads}
        busy0 = {head.name: _busy_s(head.stats, clock0_s) for head in daemon.heads}
        withheld0 = daemon.outputs.withheld if daemon.outputs is not None else 0
        await asyncio.sleep(seconds)
        wall_s = time.monotonic() - start_s
        cpu_s, clock1_s = time.process_time() - cpu0_s, time.perf_counter()
        processed = {
            head.name: head.stats.processed - processed0[head.name] for head in daemon.heads
        }
        stages = {
            head.name: _stages(
                head.stats, busy0[head.name], _busy_s(head.stats, clock1_s), clock0_s, clock1_s
            )
            for head in daemon.heads
        }
        latency = {head.name: list(head.stats.latency_ms) for head in daemon.heads}
        threads_used = daemon.threads
        withheld = (daemon.outputs.withheld if daemon.outputs is not None else 0) - withheld0
    finally:
        daemon.stop()
        await asyncio.wait_for(task, timeout=15.0)
        transport.close()
    scans = listener.of_type("OBSTACLE_DISTANCE", start_s)
    # time_usec is the capture time on this process's monotonic clock (see Outputs).
    send_ms = [
        (t - m.time_usec / 1e6) * 1000.0
        for t, m in listener.heard
        if t >= start_s and m.get_type() == "OBSTACLE_DISTANCE"
    ]
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
        "threads": threads_used,
        "capture_to_send_ms": _percentiles(send_ms),
        # The whole process (capture, stages, OpenCV's threads, the link) over the window.
        "cpu_cores_busy": round(cpu_s / wall_s, 2),
        "cpu_ms_per_frame": round(1000.0 * cpu_s / sum(processed.values()), 1)
        if any(processed.values())
        else 0.0,
        "heartbeat_states": states,
        "heads": [
            {
                "name": name,
                "fps": round(processed[name] / wall_s, 2),
                "mean_latency_ms": round(statistics.fmean(latency[name]), 1)
                if latency[name]
                else 0.0,
                "latency_ms": _percentiles(latency[name]),
                **stages[name],
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
    send = report["capture_to_send_ms"]
    lines.append(
        f"  {report['threads']} vision thread(s); capture to send p50 {send['p50']:.0f} ms, "
        f"p99 {send['p99']:.0f} ms"
    )
    lines.append(
        f"  process CPU {report['cpu_cores_busy']:.2f} cores busy, "
        f"{report['cpu_ms_per_frame']:.0f} ms per processed frame"
    )
    for h in report["heads"]:
        lines += [
            f"  head {h['name']}: {h['fps']:.1f} fps processed, capture to result mean "
            f"{h['mean_latency_ms']:.0f} ms, p50 {h['latency_ms']['p50']:.0f} ms, "
            f"p99 {h['latency_ms']['p99']:.0f} ms",
            f"    match {h['match_ms']:.0f} ms (busy {100 * h['match_busy']:.0f}%), finish "
            f"{h['finish_ms']:.0f} ms (busy {100 * h['finish_busy']:.0f}%), medians",
        ]
    return "\n".join(lines)


def _busy_s(stats: HeadStats, now_s: float) -> tuple[float, float]:
    """Seconds a head's match and finish stages have been busy up to ``now_s``."""
    return stats.match.busy_s(now_s), stats.finish.busy_s(now_s)


def _stages(
    stats: HeadStats,
    busy0: tuple[float, float],
    busy1: tuple[float, float],
    start_s: float,
    end_s: float,
) -> dict[str, float]:
    """A head's stage times within a window (medians, ms) and each stage's busy share of it.

    Args:
        stats: The head's counters.
        busy0: Its stages' :func:`_busy_s` at the window's start.
        busy1: The same at the window's end.
        start_s: The window's start (``time.perf_counter``).
        end_s: Its end.
    """

    def median_ms(runs: Iterable[tuple[float, float]]) -> float:
        inside = [ms for ended_s, ms in runs if start_s <= ended_s <= end_s]
        return round(statistics.median(inside), 1) if inside else 0.0

    window_s = end_s - start_s
    return {
        "match_ms": median_ms(stats.match.recent),
        "finish_ms": median_ms(stats.finish.recent),
        "match_busy": round((busy1[0] - busy0[0]) / window_s, 3),
        "finish_busy": round((busy1[1] - busy0[1]) / window_s, 3),
    }


def _percentiles(values: list[float]) -> dict[str, float]:
    """p50 and p99 of some milliseconds (0 when there are none)."""
    if not values:
        return {"p50": 0.0, "p99": 0.0}
    p50, p99 = np.percentile(np.asarray(values), [50.0, 99.0])
    return {"p50": round(float(p50), 1), "p99": round(float(p99), 1)}


def _overridden(config: AppConfig, threads: int | None, source_fps: float | None) -> AppConfig:
    """The configuration with the bench's overrides (thread count, camera rate)."""
    if threads is not None:
        pipeline = config.pipeline.model_copy(update={"threads": threads})
        config = config.model_copy(update={"pipeline": pipeline})
    if source_fps is not None:
        heads = []
        for head in config.heads:
            if not isinstance(head.source, SyntheticSourceConfig):
                raise ValueError(
                    f"bench --source-fps: head '{head.name}' reads {head.source.kind}, not a "
                    "synthetic camera; drop --source-fps or use a synthetic configuration"
                )
            source = head.source.model_copy(update={"fps": source_fps})
            heads.append(head.model_copy(update={"source": source}))
        config = config.model_copy(update={"heads": heads})
    return config


def compare_threads(reports: list[dict[str, Any]]) -> list[str]:
    """Lines comparing runs with more threads to the one-thread run (first head).

    The frame rate as a multiple of the one-thread rate, and the capture-to-result p99 as a
    multiple of the one-thread frame time (1 / its frame rate).
    """
    single = next((r for r in reports if r["threads"] == 1), None)
    if single is None or not single["heads"] or single["heads"][0]["fps"] <= 0:
        return []
    fps_1 = single["heads"][0]["fps"]
    lines = []
    for report in reports:
        if report["threads"] == 1 or not report["heads"]:
            continue
        head = report["heads"][0]
        lines.append(
            f"{report['threads']} threads: {head['fps'] / fps_1:.2f}x the one-thread frame rate "
            f"({head['fps']:.1f} vs {fps_1:.1f} fps); latency p99 "
            f"{head['latency_ms']['p99'] * fps_1 / 1000.0:.2f}x the one-thread frame time "
            f"({head['latency_ms']['p99']:.0f} vs {1000.0 / fps_1:.0f} ms)"
        )
    return lines
