"""The README's quick start, walked as written: the demo daemon, the mock autopilot and ``goto``,
three processes on real UDP (the demo's two ports swapped for free ones, so a test beside a
running ``make run`` does not collide with it).
"""

from __future__ import annotations

import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.helpers import REPO, free_udp_port


def _readme_line(pattern: str) -> str:
    """The README's command matching ``pattern`` (a test on the README's own words)."""
    text = (REPO / "README.md").read_text()
    found = re.search(pattern, text)
    assert found is not None, f"the README no longer says {pattern!r}"
    return found.group(0)


def _avoidd(*argv: str) -> list[str]:
    return [sys.executable, "-m", "avoidd", *argv]


@pytest.mark.timeout(120)
def test_the_quick_start_runs_as_the_readme_says(tmp_path: Path) -> None:
    mock_line = _readme_line(r"avoidd mock-autopilot udpin:127\.0\.0\.1:14550[^\n`]*")
    goto_line = _readme_line(r"avoidd goto udpout:127\.0\.0\.1:14551 --ned 12 -4 3")
    autopilot, endpoint = free_udp_port(), free_udp_port()
    demo = (REPO / "config" / "demo.yaml").read_text()
    assert "udpout:127.0.0.1:14550" in demo and "udpin:127.0.0.1:14551" in demo
    config = tmp_path / "demo.yaml"
    config.write_text(
        demo.replace("calibration: calibration/", f"calibration: {REPO}/config/calibration/")
        .replace("127.0.0.1:14550", f"127.0.0.1:{autopilot}")
        .replace("127.0.0.1:14551", f"127.0.0.1:{endpoint}")
    )
    mock_argv = mock_line.replace("14550", str(autopilot)).split()[1:]
    goto_argv = goto_line.replace("14551", str(endpoint)).split()[1:]
    mock = subprocess.Popen(
        _avoidd(*mock_argv), cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT
    )
    daemon = subprocess.Popen(
        _avoidd("run", "--config", str(config)),
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
    )
    try:
        # goto as the README says: it waits for avoidd's heartbeat on the endpoint.
        deadline = time.monotonic() + 60.0
        goto = None
        while time.monotonic() < deadline:
            goto = subprocess.run(
                _avoidd(*goto_argv), cwd=REPO, capture_output=True, text=True, timeout=60
            )
            if goto.returncode == 0:
                break
            time.sleep(1.0)
        assert goto is not None and goto.returncode == 0, goto
        assert "avoidd: goal N12.0 E-4.0 A3.0" in goto.stdout, goto.stdout
    finally:
        daemon.send_signal(signal.SIGINT)
        daemon_out = daemon.communicate(timeout=30)[0].decode()
        mock.send_signal(signal.SIGINT)
        mock_out = mock.communicate(timeout=30)[0].decode()
    assert "MAVLink link up: ArduPilot system 1, mode GUIDED, armed" in daemon_out, daemon_out
    assert daemon.returncode == 0, daemon_out
    # The mock heard avoidd's distances and its heartbeat.
    assert "OBSTACLE_DISTANCE" in mock_out and "HEARTBEAT" in mock_out, mock_out
