"""``sim batch --ray``: the same jobs as Ray tasks give the same results as local processes."""

from __future__ import annotations

import io
import json
import sys
import time
from pathlib import Path
from typing import Any

import pytest

import avoidd.progress
from avoidd.cli import main


def _scenarios(tmp_path: Path) -> list[Path]:
    # One generated world, one world file (which the driver must read and ship).
    generated = tmp_path / "r-open.yaml"
    generated.write_text(
        "version: 1\nname: r-open\nworld: {kind: open, seed: 1, length_m: 12}\n"
        "perception: oracle\nduration_s: 4\npass: {no_collision: true, min_clearance_m: 0.9}\n"
    )
    worlds = tmp_path / "worlds"
    worlds.mkdir()
    (worlds / "slab.yaml").write_text(
        "version: 1\nseed: 5\ntreeline_m: null\nobstacles:\n"
        "  - {shape: box, north_m: 8, east_m: 0, length_m: 0.3, width_m: 6, height_m: 4}\n"
    )
    on_file = tmp_path / "r-slab.yaml"
    on_file.write_text(
        "version: 1\nname: r-slab\nworld: worlds/slab.yaml\ngoal: {north_m: 12, east_m: 0}\n"
        "perception: oracle\nduration_s: 4\npass: {no_collision: true}\n"
    )
    return [generated, on_file]


def _ray_pids() -> set[int]:
    pids = set()
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            command = (entry / "cmdline").read_bytes()
        except OSError:
            continue
        if b"raylet" in command or b"gcs_server" in command or command.startswith(b"ray::"):
            pids.add(int(entry.name))
    return pids


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def _batch(
    args: list[str], capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> tuple[int, str, str, float]:
    drawn = _Terminal()
    plain = avoidd.progress.Progress
    monkeypatch.setattr(avoidd.progress, "Progress", lambda total: plain(total, stream=drawn))
    started = time.monotonic()
    code = main(["sim", "batch", *args])
    took = time.monotonic() - started
    monkeypatch.setattr(avoidd.progress, "Progress", plain)
    return code, capsys.readouterr().out, drawn.getvalue(), took


def _without_wall_time(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [{k: v for k, v in row.items() if k != "wall_time_s"} for row in rows]


@pytest.mark.timeout(240)
def test_sim_batch_on_a_local_ray_instance_equals_local_processes(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    ray = pytest.importorskip("ray", reason="Ray is not installed (pip install 'avoidd[ray]')")
    files = [str(path) for path in _scenarios(tmp_path)]
    before = _ray_pids()
    local_json, ray_json = tmp_path / "local.json", tmp_path / "ray.json"
    common = [*files, "--seeds", "1", "--workers", "1"]
    code, out, bar, local_s = _batch([*common, "--json", str(local_json)], capsys, monkeypatch)
    assert code == 0, out
    assert "2/2" in bar
    code, ray_out, ray_bar, ray_s = _batch(
        [*common, "--ray", "local", "--json", str(ray_json)], capsys, monkeypatch
    )
    with capsys.disabled():
        print(f"\ntiny batch (2 scenarios x 1 seed): local {local_s:.1f} s, Ray {ray_s:.1f} s")
    assert code == 0, ray_out
    assert "[" + "#" * 30 + "] 2/2" in ray_bar
    local_rows = json.loads(local_json.read_text())
    ray_rows = json.loads(ray_json.read_text())
    assert [r["name"] for r in ray_rows] == ["r-open", "r-slab"]
    assert _without_wall_time(ray_rows) == _without_wall_time(local_rows)
    # The same table (but for the wall time column) and the same totals.
    assert [line[:79] for line in ray_out.splitlines()] == [line[:79] for line in out.splitlines()]
    assert "2 runs: 0 collisions" in ray_out
    assert not ray.is_initialized()
    deadline = time.monotonic() + 15.0
    while _ray_pids() - before and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not _ray_pids() - before, "Ray processes outlived the batch"


def test_sim_batch_ray_unreachable_is_one_line_and_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    pytest.importorskip("ray", reason="Ray is not installed (pip install 'avoidd[ray]')")
    files = [str(path) for path in _scenarios(tmp_path)]
    assert main(["sim", "batch", *files, "--ray", "ray://127.0.0.1:1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cannot reach the Ray cluster" in err[0], err
    assert "--ray local" in err[0]


def test_sim_batch_ray_not_installed_is_one_line_and_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    files = [str(path) for path in _scenarios(tmp_path)]
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray raises ImportError
    assert main(["sim", "batch", *files, "--ray", "auto"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        "--ray auto: Ray is not installed; pip install 'avoidd[ray]' (or run without --ray)"
    ]
