#!/usr/bin/env python3
"""Seconds from starting ``avoidd run`` to its ``READY=1``, as systemd sees it (several runs).

Stands in for systemd's notification socket, starts the daemon the way the unit does, times the
first ``READY=1`` datagram from the moment the process is spawned, stops the daemon with SIGTERM
and checks that it said ``STOPPING=1`` and exited 0. Standard library only::

    python3 systemd/time-to-ready.py --config config/demo.yaml --runs 5
    python3 time-to-ready.py --avoidd /opt/avoidd/venv/bin/avoidd --config /etc/avoidd/avoidd.yaml
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def one_run(command: list[str], timeout_s: float) -> tuple[float | None, str]:
    """Start the daemon once; return seconds to READY=1 (None if it never came) and its status."""
    with tempfile.TemporaryDirectory() as folder:
        address = str(Path(folder) / "notify")
        listener = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        listener.bind(address)
        listener.settimeout(0.1)
        env = dict(os.environ, NOTIFY_SOCKET=address)
        started = time.monotonic()
        daemon = subprocess.Popen(command, env=env, stderr=subprocess.DEVNULL)
        ready_s = None
        status = ""
        try:
            while ready_s is None and time.monotonic() - started < timeout_s:
                if daemon.poll() is not None:
                    break
                try:
                    message = listener.recv(4096).decode()
                except TimeoutError:
                    continue
                fields = dict(line.split("=", 1) for line in message.split("\n") if "=" in line)
                status = fields.get("STATUS", status)
                if fields.get("READY") == "1":
                    ready_s = time.monotonic() - started
        finally:
            daemon.send_signal(signal.SIGTERM)
            code = daemon.wait(timeout=60)
            stopping = False
            try:
                while True:
                    stopping |= "STOPPING=1" in listener.recv(4096).decode()
            except TimeoutError:
                pass
            listener.close()
        if code != 0 or not stopping:
            status += f" (exit {code}, STOPPING=1 {'seen' if stopping else 'missing'})"
        return ready_s, status


def main() -> int:
    """Parse the options, time the runs, print one line each and a summary."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", required=True, help="avoidd configuration file")
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--avoidd", default=shutil.which("avoidd") or "avoidd")
    parser.add_argument("--timeout", type=float, default=60.0, help="give up on a run after this")
    args = parser.parse_args()
    command = [args.avoidd, "run", "--config", args.config]
    times: list[float] = []
    for run in range(1, args.runs + 1):
        ready_s, status = one_run(command, args.timeout)
        shown = "no READY" if ready_s is None else f"{ready_s:.2f} s"
        print(f"run {run}: {shown}; {status}", flush=True)
        if ready_s is not None:
            times.append(ready_s)
    if not times:
        return 1
    print(
        f"start to READY=1: median {statistics.median(times):.2f} s, "
        f"max {max(times):.2f} s over {len(times)} run(s)"
    )
    return 0 if len(times) == args.runs else 1


if __name__ == "__main__":
    sys.exit(main())
