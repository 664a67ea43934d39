"""Soak: the demo daemon's memory stays flat once warm.

Two minutes in CI; ``AVOIDD_SOAK_S=1800 pytest tests/test_soak.py -s`` is the 30-minute run.
The daemon runs as its own process on the demo config (the synthetic camera), sending to a
loopback port nobody reads; its resident memory after a warm-up is compared with the end.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.helpers import REPO, free_udp_port

WARM_UP_S = 30.0
SOAK_S = float(os.environ.get("AVOIDD_SOAK_S", "120"))


def _rss_kib(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise AssertionError(f"no VmRSS for process {pid}")


@pytest.mark.timeout(SOAK_S + 120)
def test_memory_stays_flat_after_warm_up(tmp_path: Path) -> None:
    soak_s = SOAK_S
    config = tmp_path / "soak.yaml"
    demo = (REPO / "config" / "demo.yaml").read_text()
    calibration = REPO / "config" / "calibration" / "synthetic-640x480.yaml"
    config.write_text(
        demo.replace(
            "calibration: calibration/synthetic-640x480.yaml", f"calibration: {calibration}"
        ).replace("udpout:127.0.0.1:14550", f"udpout:127.0.0.1:{free_udp_port()}")
    )
    log = (tmp_path / "daemon.log").open("w")
    daemon = subprocess.Popen(
        [sys.executable, "-m", "avoidd", "run", "--config", str(config)],
        cwd=REPO,
        stdout=log,
        stderr=subprocess.STDOUT,
    )
    try:
        samples: list[tuple[float, int]] = []
        start = time.monotonic()
        while (elapsed := time.monotonic() - start) < soak_s:
            assert daemon.poll() is None, (tmp_path / "daemon.log").read_text()[-2000:]
            if elapsed >= WARM_UP_S:
                samples.append((elapsed, _rss_kib(daemon.pid)))
            time.sleep(5.0)
        daemon.send_signal(signal.SIGTERM)
        assert daemon.wait(timeout=30) == 0
    finally:
        if daemon.poll() is None:
            daemon.kill()
            daemon.wait()
        log.close()
    assert len(samples) >= 3
    warm_kib, end_kib = samples[0][1], samples[-1][1]
    growth = (end_kib - warm_kib) / warm_kib
    print(f"RSS {warm_kib} KiB at {samples[0][0]:.0f} s, {end_kib} KiB at {samples[-1][0]:.0f} s")
    assert growth < 0.05, samples
    assert "Traceback" not in (tmp_path / "daemon.log").read_text()
