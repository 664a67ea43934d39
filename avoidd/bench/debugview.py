"""``avoidd bench-debugview``: the CPU the debug view costs, without a viewer and with one.

The daemon runs in this process on a configuration (the demo by default) with its link
pointed at a UDP sink here, three times for the same window: with the debug view off, on with
nobody watching, and on with one viewer. The viewer is another process that reads what the
page asks for (the MJPEG stream of every head and of the sent scan, ``/api/stats`` each
second) and throws it away, so its own work is not counted. Process CPU time over wall time
gives the share of one core; the difference from the run without the view is its cost.
"""

from __future__ import annotations

import asyncio
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from avoidd.config import AppConfig
from avoidd.daemon import Daemon
from avoidd.loading import load_all

_WARM_UP_S = 3.0

# The viewer: reads URLs given as arguments in threads, discarding the bytes; the last
# argument is polled once a second instead of streamed.
_VIEWER = """
import sys, threading, time, urllib.request
def stream(url):
    with urllib.request.urlopen(url) as response:
        while response.read(65536):
            pass
def poll(url):
    while True:
        urllib.request.urlopen(url).read()
        time.sleep(1.0)
for url in sys.argv[1:-1]:
    threading.Thread(target=stream, args=(url,), daemon=True).start()
threading.Thread(target=poll, args=(sys.argv[-1],), daemon=True).start()
time.sleep(3600)
"""


class _Sink(asyncio.DatagramProtocol):
    """Where the daemon's MAVLink goes: nowhere (no autopilot answers)."""


async def _measure(daemon: Daemon, seconds: float) -> dict[str, float]:
    """CPU share, frames processed and debug-view encodings over a window."""
    head_frames = sum(head.stats.processed for head in daemon.heads)
    server = daemon.debug_server
    encodes = server.counter.encodes if server is not None else 0
    encode_s = server.counter.seconds if server is not None else 0.0
    # This coroutine runs on the event loop's thread: its thread time is the loop's CPU
    # (MAVLink, the send loops and the debug server's handlers; not the vision threads).
    wall0, cpu0, loop0 = time.monotonic(), time.process_time(), time.thread_time()
    await asyncio.sleep(seconds)
    wall_s, cpu_s = time.monotonic() - wall0, time.process_time() - cpu0
    loop_s = time.thread_time() - loop0
    frames = sum(head.stats.processed for head in daemon.heads) - head_frames
    return {
        "seconds": round(wall_s, 2),
        "cpu_percent": round(100.0 * cpu_s / wall_s, 1),
        "loop_cpu_percent": round(100.0 * loop_s / wall_s, 2),
        "frames_per_s": round(frames / wall_s, 2),
        "cpu_ms_per_frame": round(1000.0 * cpu_s / max(frames, 1), 1),
        "encodes_per_s": round(
            ((server.counter.encodes if server is not None else 0) - encodes) / wall_s, 2
        ),
        "encode_cpu_percent": round(
            100.0 * ((server.counter.seconds if server is not None else 0.0) - encode_s) / wall_s,
            2,
        ),
    }


async def _run_phases(
    config: AppConfig, calibrations: dict[str, Any], seconds: float, viewer: bool
) -> list[dict[str, float]]:
    """Run the daemon; measure a window (and, with ``viewer``, a second one with a viewer)."""
    daemon = Daemon(config, calibrations)
    task = asyncio.create_task(daemon.run())
    results = []
    process = None
    try:
        deadline = time.monotonic() + 60.0
        while not all(head.latest is not None for head in daemon.heads) or (
            config.debug_server.enabled
            and (daemon.debug_server is None or not daemon.debug_server.port)
        ):
            if time.monotonic() > deadline or task.done():
                raise RuntimeError("the daemon processed no frame within a minute")
            await asyncio.sleep(0.05)
        await asyncio.sleep(_WARM_UP_S)
        results.append(await _measure(daemon, seconds))
        if viewer and daemon.debug_server is not None:
            base = f"http://127.0.0.1:{daemon.debug_server.port}"
            urls = [f"{base}/stream/head/{head.name}.mjpg" for head in daemon.heads]
            urls += [f"{base}/stream/polar.mjpg", f"{base}/api/stats"]
            process = subprocess.Popen([sys.executable, "-c", _VIEWER, *urls])
            await asyncio.sleep(_WARM_UP_S)
            results.append(await _measure(daemon, seconds))
    finally:
        if process is not None:
            process.kill()
            process.wait()
        daemon.stop()
        await asyncio.wait_for(task, timeout=30.0)
    return results


async def run_bench(config_path: Path, seconds: float, stream_fps: float) -> dict[str, Any]:
    """Measure the daemon's CPU without the debug view, with it unwatched, and watched.

    Args:
        config_path: A daemon configuration; its link and debug server are replaced.
        seconds: Length of each measured window.
        stream_fps: The view's stream rate.

    Returns:
        The figures of each window and the view's cost (difference from the run without it).
    """
    config, calibrations = load_all(config_path)
    loop = asyncio.get_running_loop()
    transport, _ = await loop.create_datagram_endpoint(_Sink, local_addr=("127.0.0.1", 0))
    port = transport.get_extra_info("sockname")[1]
    mavlink = config.mavlink.model_copy(update={"connection": f"udpout:127.0.0.1:{port}"})
    config = config.model_copy(update={"mavlink": mavlink})
    try:
        off = config.debug_server.model_copy(update={"enabled": False})
        (without,) = await _run_phases(
            config.model_copy(update={"debug_server": off}), calibrations, seconds, False
        )
        on = config.debug_server.model_copy(
            update={"enabled": True, "host": "127.0.0.1", "port": 0, "stream_fps": stream_fps}
        )
        idle, watched = await _run_phases(
            config.model_copy(update={"debug_server": on}), calibrations, seconds, True
        )
    finally:
        transport.close()
    rig = [
        f"{head.name} {calibrations[head.name].rig.width}x{calibrations[head.name].rig.height}"
        for head in config.heads
    ]
    return {
        "config": str(config_path),
        "heads": rig,
        "stream_fps": stream_fps,
        "off": without,
        "idle": idle,
        "viewer": watched,
        "idle_cost_percent": round(idle["cpu_percent"] - without["cpu_percent"], 1),
        "viewer_cost_percent": round(watched["cpu_percent"] - without["cpu_percent"], 1),
        # On a busy machine the heads process fewer frames in one window than in another:
        # the pipeline's CPU per frame (from the run without the view) takes that out.
        "idle_cost_per_frame_percent": _beyond_pipeline(idle, without),
        "viewer_cost_per_frame_percent": _beyond_pipeline(watched, without),
        # The view's own work, measured where it runs: the event loop's extra CPU (serving)
        # plus the worker-thread CPU of drawing and encoding. Least disturbed by other load.
        "idle_cost_direct_percent": _direct(idle, without),
        "viewer_cost_direct_percent": _direct(watched, without),
    }


def _direct(run: dict[str, float], without: dict[str, float]) -> float:
    """The event loop's extra CPU over the run without the view, plus drawing and encoding."""
    extra_loop = run["loop_cpu_percent"] - without["loop_cpu_percent"]
    return round(extra_loop + run["encode_cpu_percent"], 1)


def _beyond_pipeline(run: dict[str, float], without: dict[str, float]) -> float:
    """CPU of a run beyond what its frames cost in the run without the view."""
    pipeline = without["cpu_ms_per_frame"] * run["frames_per_s"] / 10.0
    return round(run["cpu_percent"] - pipeline, 1)


def format_report(report: dict[str, Any]) -> str:
    """The figures as a short table."""
    lines = [
        f"debug view on {report['config']} ({', '.join(report['heads'])}), "
        f"streams at {report['stream_fps']:g} fps; CPU in % of one core:",
        f"  {'run':<22}{'CPU %':>7}{'frames/s':>10}{'CPU ms/frame':>14}"
        f"{'loop %':>8}{'JPEG/s':>8}{'draw+encode %':>15}",
    ]
    runs = (("off", "view off"), ("idle", "view on, no viewer"), ("viewer", "one viewer"))
    for key, name in runs:
        row = report[key]
        lines.append(
            f"  {name:<22}{row['cpu_percent']:>7.1f}{row['frames_per_s']:>10.1f}"
            f"{row['cpu_ms_per_frame']:>14.1f}{row['loop_cpu_percent']:>8.1f}"
            f"{row['encodes_per_s']:>8.1f}"
            f"{row['encode_cpu_percent']:>15.2f}"
        )
    lines.append(
        f"  cost of the view: {report['idle_cost_percent']:+.1f} % unwatched, "
        f"{report['viewer_cost_percent']:+.1f} % with one viewer (targets: 5 % and 15 %); "
        f"at equal frames processed: {report['idle_cost_per_frame_percent']:+.1f} % and "
        f"{report['viewer_cost_per_frame_percent']:+.1f} %; "
        f"direct (loop + drawing): {report['idle_cost_direct_percent']:+.1f} % and "
        f"{report['viewer_cost_direct_percent']:+.1f} %"
    )
    return "\n".join(lines)
