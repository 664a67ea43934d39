"""Benchmark: how long ``avoidd check-config`` takes to refuse each bad input, as a user runs it.

Every case is a separate ``python -m avoidd check-config FILE`` process, Python's start and
avoidd's imports included (what a user waits for). The cases: the broken-configuration corpus
(``tests/test_config_corpus.py``) and the hostile inputs of ``tests/test_bad_input.py``: a config
that is not UTF-8, one larger than 1 MB, a YAML alias bomb, deep nesting, a 5000-digit number,
and the broken ``frames.csv`` indexes of ``BAD_INDEXES`` (negative or overflowing times, not
UTF-8, broken early in 10 MB, more or fewer rows than images, 70 MB), and the files of
``tests/test_bad_files.py`` (control characters in YAML, a FIFO, a device or a folder where a
file is named, a recording of the wrong size, a 20000x20000 PNG). The target (issue 21): each
answered within 1 s.

Run: ``.venv/bin/python -m tests.bench_bad_input [--quick] [--json FILE]``. Prints one line per
case sorted by time, then the median, 95th percentile and maximum next to a bare Python start and
a bare ``import avoidd.cli`` (the floor no refusal can beat); exits 1 when a case took over 1 s
or was not refused with exit code 2.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

from tests.helpers import REPO, synthetic_config
from tests.test_bad_files import hostile_files
from tests.test_bad_input import BAD_INDEXES, _bomb, bad_recording
from tests.test_config_corpus import CALIBRATION, CASES, DEMO
from tests.test_offline_config import _config

TARGET_S = 1.0


def _corpus(folder: Path) -> Iterator[tuple[str, Path]]:
    base = DEMO.replace("calibration: calibration/synthetic-640x480.yaml", "calibration: CAL")
    for index, (old, new, names) in enumerate(CASES):
        text = base.replace(old, new, 1).replace("calibration: CAL", f"calibration: {CALIBRATION}")
        path = folder / f"corpus-{index:02d}.yaml"
        path.write_text(text)
        yield f"config {index}: {names}", path


def _hostile(folder: Path) -> Iterator[tuple[str, Path]]:
    good = synthetic_config(folder, "udpout:127.0.0.1:14550")
    text = good.read_text()
    cases = {
        "not UTF-8": text.replace("version: 1\n", "version: 1\n# caf\xe9\n").encode("latin-1"),
        "larger than 1 MB": (text + ("# " + "x" * 98 + "\n") * 10_001).encode(),
        "alias bomb": _bomb().encode(),
        "nested 5000 deep": ("version: 1\nheads: " + "[" * 5000 + "]" * 5000 + "\n").encode(),
        "5000-digit number": ("version: 1\nheads: 1" + "0" * 5000 + "\n").encode(),
    }
    for name, data in cases.items():
        path = folder / f"hostile-{len(name)}-{name.split()[0]}.yaml"
        path.write_bytes(data)
        yield f"yaml: {name}", path


def _indexes(folder: Path) -> Iterator[tuple[str, Path]]:
    for index, (csv, fragment) in enumerate(BAD_INDEXES):
        name = fragment.split(": ", 1)[-1]
        case = folder / f"index-{index}"
        bad_recording(case / "rec", csv)
        yield f"frames.csv: {name}", _config(case, {"kind": "files", "path": "rec"}, True)


def _time(args: list[str]) -> tuple[float, int, str]:
    start = time.perf_counter()
    result = subprocess.run(args, capture_output=True, text=True, cwd=REPO, timeout=60, check=False)
    lines = result.stderr.strip().splitlines()
    return time.perf_counter() - start, result.returncode, lines[0] if lines else ""


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark; 1 when a case missed the target or was not refused."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="every fifth corpus case only")
    parser.add_argument("--json", type=Path, help="also write the figures here")
    args = parser.parse_args(argv)
    python = sys.executable
    floor_python = min(_time([python, "-c", "pass"])[0] for _ in range(3))
    floor_import = min(_time([python, "-c", "import avoidd.cli"])[0] for _ in range(3))
    rows: list[tuple[float, int, str, str]] = []
    with tempfile.TemporaryDirectory(prefix="avoidd-bench-bad-") as temp:
        folder = Path(temp)
        files = [(name, path) for name, path, _ in hostile_files(folder / "files")]
        cases = [*_corpus(folder), *_hostile(folder), *_indexes(folder), *files]
        if args.quick:
            cases = [c for i, c in enumerate(cases) if i % 5 == 0 or not c[0].startswith("conf")]
        for name, path in cases:
            took_s, code, line = _time([python, "-m", "avoidd", "check-config", str(path)])
            rows.append((took_s, code, name, line.replace(str(folder), "TMP")))
    rows.sort(reverse=True)
    for took_s, code, name, line in rows:
        print(f"{took_s:6.3f} s  exit {code}  {name:38.38s}  {line[:90]}")
    times = [r[0] for r in rows]
    p95 = statistics.quantiles(times, n=20)[-1] if len(times) >= 2 else times[0]
    wrong = [r for r in rows if r[1] != 2]
    slow = [r for r in rows if r[0] > TARGET_S]
    print(
        f"\n{len(rows)} bad inputs: median {statistics.median(times):.3f} s, p95 {p95:.3f} s, "
        f"max {max(times):.3f} s (target {TARGET_S:.1f} s); bare python start "
        f"{floor_python:.3f} s, import avoidd.cli {floor_import:.3f} s; "
        f"{len(slow)} over the target, {len(wrong)} not refused with exit 2"
    )
    if args.json is not None:
        figures = {
            "cases": [
                {"name": n, "seconds": round(t, 4), "exit": c, "line": line}
                for t, c, n, line in rows
            ],
            "median_s": statistics.median(times),
            "p95_s": p95,
            "max_s": max(times),
            "python_start_s": floor_python,
            "import_s": floor_import,
        }
        args.json.write_text(json.dumps(figures, indent=2) + "\n")
    return 1 if slow or wrong else 0


if __name__ == "__main__":
    sys.exit(main())
