"""The daemon as a real process on the synthetic camera, heard by a MAVLink peer on UDP."""

from __future__ import annotations

import ast
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
from tests.helpers import REPO, dialect, open_udp_peer, synthetic_config, wait_for

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
    # Data counts as fresh for 5 s (the most the config allows), so that a machine too busy to
    # keep up delays the scans rather than withholds them all as stale.
    config = synthetic_config(
        tmp_path,
        f"udpout:127.0.0.1:{peer.port}",
        rig=RIG_640,
        source=source,
        pipeline={"max_age_ms": 5000, "log_interval_s": 1.0},
    )
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
    scans = lambda: peer.of_type("OBSTACLE_DISTANCE")  # noqa: E731
    measured = lambda: [m for m in scans() if min(m.distances) < 2001]  # noqa: E731
    try:
        assert await wait_for(lambda: len(measured()) > 0, 120.0), "no measured scan arrived"
        first = next(i for i, m in enumerate(scans()) if min(m.distances) < 2001)
        # Thirty more scans, however long this machine takes to send them. (How often the
        # daemon sends and how many of its scans are fresh is a benchmark's figure:
        # `avoidd bench --daemon CONFIG`.)
        assert await wait_for(lambda: len(scans()) >= first + 31, 120.0), "scans stopped"
    finally:
        process.send_signal(signal.SIGTERM)
        code = await asyncio.wait_for(process.wait(), timeout=15.0)
        log.close()
        peer.close()
    text = (tmp_path / "daemon.log").read_text()
    assert code == 0, text
    assert "avoidd stopped" in text

    # Everything the daemon counted as sent arrived, once and in order.
    counters = ast.literal_eval(text.split("avoidd stopped; MAVLink ")[1].splitlines()[0])
    assert len(scans()) == counters["sent"]["OBSTACLE_DISTANCE"], counters
    seqs = [r.message.get_seq() for r in peer.messages]
    assert seqs == [(seqs[0] + i) % 256 for i in range(len(seqs))]
    stamps = [m.time_usec for m in scans()]
    assert stamps == sorted(stamps)
    # No autopilot has spoken, so a stale scan is withheld rather than sent: from the first
    # measured scan on, every scan sent holds the obstacle, in its bin, at its distance.
    errors = []
    for message in scans()[first:]:
        distances = np.array(
            read_bins(message.distances, message.increment_f, message.angle_offset)
        )
        nearest_bin = int(np.argmin(distances))
        errors.append(distances[truth_bin] / 100.0 / truth_m - 1.0)
        assert nearest_bin in {(truth_bin - 1) % 72, truth_bin, (truth_bin + 1) % 72}
    assert len(errors) >= 31
    assert abs(float(np.median(errors))) <= 0.03, f"median error {np.median(errors):+.3f}"
    assert float(np.max(np.abs(errors))) <= 0.05
    # Once a result exists the daemon never says it is booting again; it is active or, when
    # its data goes stale, critical.
    start = next(i for i, r in enumerate(peer.messages) if r.message is scans()[first])
    after = [
        r.message.system_status
        for r in peer.messages[start:]
        if r.message.get_type() == "HEARTBEAT"
    ]
    assert after and set(after) <= {dialect.MAV_STATE_ACTIVE, dialect.MAV_STATE_CRITICAL}, after
