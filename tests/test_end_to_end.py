"""The daemon as a real process on the synthetic camera, heard by a MAVLink peer on UDP."""

from __future__ import annotations

import asyncio
import signal
import sys
from pathlib import Path

import numpy as np

from avoidd.config import load_config
from avoidd.mavlink.layout import read_bins
from avoidd.perception.sectors import bin_of_bearing
from avoidd.sources.synthetic import SyntheticSource
from avoidd.sources.truth import nearest_obstacle
from avoidd.types import Mount, RectifiedRig
from avoidd.vision.calibration import load_calibration
from tests.helpers import REPO, open_udp_peer, synthetic_config, wait_for

RIG_640 = {
    "width": 640,
    "height": 480,
    "fx": 400.0,
    "fy": 400.0,
    "cx": 319.5,
    "cy": 239.5,
    "baseline_m": 0.12,
    "doffs": 0.0,
}


def truth_of(config_path: Path) -> tuple[float, int]:
    config = load_config(config_path)
    head = config.heads[0]
    rig: RectifiedRig = load_calibration(head.calibration).rig
    assert head.source.kind == "synthetic"
    frame = SyntheticSource(head.source, rig, paced=False).read()
    assert frame.truth is not None
    assert frame.pose is not None
    nearest = nearest_obstacle(frame.truth, Mount(), frame.pose, config.perception)
    assert nearest is not None
    return nearest.distance_m, int(bin_of_bearing(nearest.bearing_deg))


async def test_daemon_process_on_synthetic_camera(tmp_path: Path) -> None:
    peer = await open_udp_peer()
    source = {
        "kind": "synthetic",
        "fps": 15,
        "seed": 9,
        "obstacles": [
            {"shape": "box", "forward_m": 4.5, "right_m": 1.6, "width_m": 1.0, "depth_m": 0.8},
            {"shape": "pole", "forward_m": 7.0, "right_m": -2.0, "width_m": 0.2},
        ],
    }
    config = synthetic_config(tmp_path, f"udpout:127.0.0.1:{peer.port}", rig=RIG_640, source=source)
    truth_m, truth_bin = truth_of(config)
    log = (tmp_path / "daemon.log").open("w")
    process = await asyncio.create_subprocess_exec(
        sys.executable,
        "-m",
        "avoidd",
        "run",
        "--config",
        str(config),
        stdout=log,
        stderr=log,
        cwd=REPO,
    )
    try:
        measured = lambda: [m for m in peer.of_type("OBSTACLE_DISTANCE") if min(m.distances) < 2001]  # noqa: E731
        assert await wait_for(lambda: len(measured()) > 0, 30.0), "no measured scan arrived"
        start = len(peer.messages)
        await asyncio.sleep(4.0)
    finally:
        process.send_signal(signal.SIGTERM)
        code = await asyncio.wait_for(process.wait(), timeout=15.0)
        log.close()
        peer.close()
    text = (tmp_path / "daemon.log").read_text()
    assert code == 0, text
    assert "avoidd stopped" in text

    window = peer.messages[start:]
    times = [r.t_s for r in window if r.message.get_type() == "OBSTACLE_DISTANCE"]
    rate_hz = (len(times) - 1) / (times[-1] - times[0])
    assert rate_hz >= 10.0, f"OBSTACLE_DISTANCE at {rate_hz:.1f} Hz"
    scans = [r.message for r in window if r.message.get_type() == "OBSTACLE_DISTANCE"]
    fresh = [m for m in scans if min(m.distances) < 2001]
    assert len(fresh) >= 0.9 * len(scans), "scans went stale while running"
    errors = []
    for message in fresh:
        distances = np.array(
            read_bins(message.distances, message.increment_f, message.angle_offset)
        )
        nearest_bin = int(np.argmin(distances))
        errors.append(distances[truth_bin] / 100.0 / truth_m - 1.0)
        assert nearest_bin in {(truth_bin - 1) % 72, truth_bin, (truth_bin + 1) % 72}
    assert abs(float(np.median(errors))) <= 0.03, f"median error {np.median(errors):+.3f}"
    assert float(np.max(np.abs(errors))) <= 0.05
    heartbeats = [r.message for r in window if r.message.get_type() == "HEARTBEAT"]
    assert len(heartbeats) >= 3 and all(h.system_status == 4 for h in heartbeats)
