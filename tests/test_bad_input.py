"""No traceback from input: hostile or broken files give one clear line and the config exit code."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from avoidd.cli import main
from tests.helpers import REPO, synthetic_config
from tests.test_offline_config import _config, _pairs


def _check(path: Path, capsys: pytest.CaptureFixture[str]) -> tuple[int, list[str]]:
    """Run check-config in process: its exit code and its stderr lines."""
    code = main(["check-config", str(path)])
    return code, capsys.readouterr().err.splitlines()


def _one_line(lines: list[str], *fragments: str) -> str:
    """The single problem line (followed by the 'nothing was started' line) with fragments."""
    assert len(lines) == 2, lines
    assert lines[1] == "configuration invalid; nothing was started"
    for fragment in fragments:
        assert fragment in lines[0], (fragment, lines[0])
    return lines[0]


def test_a_config_that_is_not_utf8_is_one_line_naming_the_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    good = synthetic_config(tmp_path, "udpout:127.0.0.1:14550").read_bytes()
    bad = tmp_path / "latin1.yaml"
    bad.write_bytes(good.replace(b"version: 1\n", b"version: 1\n# caf\xe9 au lait\n"))
    code, lines = _check(bad, capsys)
    assert code == 2
    _one_line(lines, f"{bad}:2:", "byte 0xe9 is not UTF-8", "save the file as UTF-8")


def test_a_huge_config_is_refused_before_parsing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    good = synthetic_config(tmp_path, "udpout:127.0.0.1:14550").read_text()
    huge = tmp_path / "huge.yaml"
    # Valid YAML all the way (a comment block), so only its size can refuse it.
    huge.write_text(good + ("# " + "x" * 98 + "\n") * 10_001)
    code, lines = _check(huge, capsys)
    assert code == 2
    _one_line(lines, f"{huge}:", "larger than 1 MB")


def _bomb(levels: int = 9) -> str:
    """A "billion laughs": nine aliases per level, nine levels (9**9 strings), ~400 bytes."""
    lines = ["version: 1", 'a: &a ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    for level in range(1, levels):
        name, previous = chr(ord("a") + level), chr(ord("a") + level - 1)
        lines.append(f"{name}: &{name} [{', '.join(['*' + previous] * 9)}]")
    lines.append(f"heads: *{chr(ord('a') + levels - 1)}")
    return "\n".join(lines) + "\n"


@pytest.mark.timeout(60)  # a hang guard: without the budget this never ends
def test_a_yaml_alias_bomb_is_refused(tmp_path: Path) -> None:
    bomb = tmp_path / "bomb.yaml"
    bomb.write_text(_bomb())
    assert len(bomb.read_bytes()) < 1024
    result = subprocess.run(
        [sys.executable, "-m", "avoidd", "check-config", str(bomb)],
        capture_output=True,
        text=True,
        timeout=50,
        cwd=REPO,
        check=False,
    )
    assert result.returncode == 2
    _one_line(result.stderr.splitlines(), f"{bomb}:", "more than 100000 values", "alias")


@pytest.mark.parametrize(
    ("text", "fragments"),
    [
        # A few aliases are fine: they get as far as validation.
        ("version: 1\nx: &x [1, 2]\ny: *x\n", (":1: heads: required key is missing",)),
        ("version: 1\nheads: &a [*a]\n", (":2:", "refers to the node that contains it")),
        ("version: 1\nheads: " + "[" * 5000 + "]" * 5000 + "\n", (":2:", "nested more than")),
        ("version: 1\nheads: 1" + "0" * 5000 + "\n", (":2:", "cannot read the value")),
        ("version: 1\nwhen: 2001-13-45\n", (":2:", "cannot read the value '2001-13-45'")),
    ],
)
def test_hostile_yaml_is_one_clear_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], text: str, fragments: tuple[str, ...]
) -> None:
    path = tmp_path / "hostile.yaml"
    path.write_text(text)
    code, lines = _check(path, capsys)
    assert code == 2
    assert lines[0].startswith(f"{path}:")
    for fragment in fragments:
        assert fragment in lines[0], lines


BAD_INDEXES: list[tuple[bytes | None, str]] = [
    (b"t_capture_ns\n-5\n100\n", "frames.csv:2: t_capture_ns -5 is out of range"),
    (b"t_capture_ns\n1\n" + b"1" + b"0" * 30 + b"\n", "frames.csv:3: t_capture_ns 1000"),
    (b"t_capture_ns\n1\n9223372036854775808\n", "frames.csv:3: t_capture_ns 9223"),
    (
        b"t_capture_ns,left,right\n1,000.png,000.png\n2,caf\xe9.png,001.png\n",
        "frames.csv:3: byte 0xe9 is not UTF-8",
    ),
    # A bad row early in a long index is reported without reading on (10 MB here).
    (b"t_capture_ns\n1\nxyz\n" + b"5\n" * 5_000_000, "frames.csv:3: t_capture_ns is not"),
    (b"t_capture_ns\n1\n2\n3\n", "frames.csv:4: more rows than the 2 images in left/"),
    (b"t_capture_ns\n1\n", "frames.csv: 1 rows but 2 images in left/"),
    # Larger than an index may be (a sparse file: nothing is written): refused unread.
    (None, "frames.csv: 70 MB, larger than the 64 MB an index may be"),
]
"""Broken frames.csv contents (None: a sparse 70 MB file) and what their one line must say."""


def bad_recording(folder: Path, csv: bytes | None) -> Path:
    """Two image pairs in ``folder`` with ``csv`` as their frames.csv (None: sparse 70 MB)."""
    recording = _pairs(folder, 2)
    if csv is None:
        with (recording / "frames.csv").open("wb") as index:
            index.truncate(70_000_000)
    else:
        (recording / "frames.csv").write_bytes(csv)
    return recording


@pytest.mark.parametrize(("csv", "fragment"), BAD_INDEXES)
def test_a_bad_frames_csv_is_one_line_naming_file_and_line(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    caplog: pytest.LogCaptureFixture,
    csv: bytes | None,
    fragment: str,
) -> None:
    recording = bad_recording(tmp_path / "rec", csv)
    config = _config(tmp_path, {"kind": "files", "path": "rec"}, mavlink=True)
    code, lines = _check(config, capsys)
    assert code == 2
    _one_line(lines, fragment, "heads.front.source.path")
    # replay given the recording as --input: the same line, as a runtime failure (exit 1).
    out = tmp_path / "out.jsonl"
    args = ["replay", "--config", str(config), "--input", str(recording), "--out", str(out)]
    assert main(args) == 1
    errors = [r.getMessage() for r in caplog.records if r.levelname == "ERROR"]
    assert len(errors) == 1 and fragment in errors[0]


def _line_of(text: str, needle: str) -> int:
    """1-based line of the first occurrence of ``needle``."""
    return text[: text.index(needle)].count("\n") + 1


def _with(tmp_path: Path, old: str, new: str) -> tuple[Path, str]:
    """The synthetic config with one piece of its text replaced (which must be there)."""
    path = synthetic_config(
        tmp_path,
        "udpout:127.0.0.1:14550",
        sections={"avoidance": {"enabled": False}},
    )
    text = path.read_text()
    assert old in text, (old, text)
    path.write_text(text.replace(old, new, 1))
    return path, new


@pytest.mark.parametrize(
    ("old", "new", "key", "fragment"),
    [
        # No silent coercion.
        ("system_id: 7", "system_id: '7'", "mavlink.system_id", "1 to 255 (no quotes), or auto"),
        ("system_id: 7", "system_id: true", "mavlink.system_id", "1 to 255 (no quotes), or auto"),
        ("version: 1", "version: 1.0", "version", "whole number"),
        ("version: 1", "version: true", "version", "whole number"),
        ("fps: 15", "fps: '15'", "heads[0].source.fps", "valid number"),
        ("seed: 3", "seed: 3.0", "heads[0].source.seed", "valid integer"),
        ("enabled: false", "enabled: 0", "avoidance.enabled", "valid boolean"),
        ("rate_hz: 15.0", "rate_hz: true", "mavlink.obstacle_distance.rate_hz", "valid number"),
        ("max_age_ms: 400", "max_age_ms: '400'", "pipeline.max_age_ms", "valid integer"),
        # Sane ranges.
        # (1e-6 is a number, as in YAML 1.2, not the string YAML 1.1 makes of it)
        ("log_interval_s: 1.0", "log_interval_s: 1e-6", "pipeline.log_interval_s", "0.5"),
        ("fps: 15", "fps: 1e-300", "heads[0].source.fps", "greater than or equal to 0.1"),
        ("fps: 15", "fps: 1.0e-300", "heads[0].source.fps", "0.1"),
        ("fps: 15", "fps: 1.0e+300", "heads[0].source.fps", "240"),
        ("fps: 15", "fps: .inf", "heads[0].source.fps", "finite number"),
        ("system_id: 7", "system_id: 7\n  heartbeat_hz: 1.0e-300", "mavlink.heartbeat_hz", "0.5"),
        (
            "system_id: 7",
            "system_id: 7\n  streams: {attitude_hz: 1.0e-9}",
            "mavlink.streams.attitude_hz",
            "0 (not asked) or from 0.1 to 1000 Hz",
        ),
    ],
)
def test_values_are_never_coerced_and_stay_in_sane_ranges(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    old: str,
    new: str,
    key: str,
    fragment: str,
) -> None:
    path, needle = _with(tmp_path, old, new)
    code, lines = _check(path, capsys)
    assert code == 2
    line = _line_of(path.read_text(), needle.split("\n")[-1].strip().split(":")[0])
    _one_line(lines, f"{path}:{line}: {key}: ", fragment)


def test_v4l2_back_off_limits_must_be_in_order(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    source = {
        "kind": "v4l2",
        "devices": ["/dev/video0"],
        "width": 320,
        "height": 240,
        "reopen_min_s": 5.0,
        "reopen_max_s": 1.0,
    }
    path = synthetic_config(tmp_path, "udpout:127.0.0.1:14550", source=source)
    code, lines = _check(path, capsys)
    assert code == 2
    line = _line_of(path.read_text(), "source:")
    _one_line(
        lines,
        f"{path}:{line}: heads[0].source: reopen_min_s (5 s) is above reopen_max_s (1 s)",
        "swap them",
    )


def test_an_infinite_focal_length_names_the_calibration_file_line_and_key(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = synthetic_config(tmp_path, "udpout:127.0.0.1:14550")
    calibration = tmp_path / "calib.yaml"
    text = calibration.read_text().replace("fx: 200.0", "fx: .inf")
    calibration.write_text(text)
    code, lines = _check(path, capsys)
    assert code == 2
    line = _line_of(text, "fx:")
    _one_line(lines, f"{calibration}:{line}: rectified.fx: ", "finite number")


def test_files_path_that_is_neither_a_folder_of_pairs_nor_a_video_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import os

    (tmp_path / "notes.txt").write_text("not a video\n")
    (tmp_path / "empty").mkdir()
    os.mkfifo(tmp_path / "pipe")
    for name, fragment in [
        ("notes.txt", "cannot open the video"),
        ("empty", "expected 'left/' and 'right/' folders"),
        ("pipe", "neither a folder nor a regular file"),
    ]:
        config = _config(tmp_path, {"kind": "files", "path": name}, mavlink=True)
        code, lines = _check(config, capsys)
        assert code == 2
        _one_line(lines, "heads.front.source.path", f"{tmp_path / name}: {fragment}")


def test_numbers_with_an_exponent_and_no_dot_are_numbers(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path, _ = _with(tmp_path, "fps: 15", "fps: 1.5e1")
    text = path.read_text().replace("log_interval_s: 1.0", "log_interval_s: 2e0")
    path.write_text(text)
    code, _ = _check(path, capsys)
    assert code == 0


@pytest.mark.timeout(60)  # a hang guard, as above
def test_a_euroc_sensor_file_gets_the_same_yaml_limits(tmp_path: Path) -> None:
    """import-calibration reads EuRoC's YAML through the bounded loader too."""
    bomb = tmp_path / "sensor.yaml"
    bomb.write_text("%YAML:1.0\n" + _bomb())
    other = tmp_path / "cam1.yaml"
    other.write_bytes(b"%YAML:1.0\ncamera_model: \xff\n")
    for first, second, fragments in (
        (bomb, bomb, (f"{bomb}:", "more than 100000 values")),
        (other, other, (f"{other}:2:", "not UTF-8")),
    ):
        result = subprocess.run(
            [sys.executable, "-m", "avoidd", "import-calibration", "euroc", str(first),
             str(second), "--out", str(tmp_path / "out.yaml")],
            capture_output=True,
            text=True,
            timeout=50,
            cwd=REPO,
            check=False,
        )  # fmt: skip
        assert result.returncode == 2, result.stderr
        _one_line(result.stderr.splitlines(), *fragments)


def test_the_bad_input_benchmark_builds_every_case(tmp_path: Path) -> None:
    """The benchmark (``make bench-bad-input``) times these cases; here only that it has them
    all and each is a file (its timings are figures, not assertions)."""
    from tests import bench_bad_input as bench
    from tests.test_config_corpus import CASES

    built = [*bench._corpus(tmp_path), *bench._hostile(tmp_path), *bench._indexes(tmp_path)]
    names = [name for name, _ in built]
    assert len(built) == len(CASES) + 5 + len(BAD_INDEXES) and len(set(names)) == len(names)
    assert all(path.is_file() for _, path in built)
    assert "yaml: alias bomb" in names
    assert "frames.csv: 70 MB, larger than the 64 MB an index may be" in names


def _fake_sitl(folder: Path, binary: str, others: tuple[str, ...]) -> Path:
    """A SITL folder whose binary only leaves a mark when run (it must never be)."""
    mark = folder / "started"
    path = folder / binary
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(f"#!/bin/sh\ntouch {mark}\n")
    path.chmod(0o755)
    for name in others:
        (folder / name).mkdir(parents=True, exist_ok=True)
    return mark


@pytest.mark.parametrize(
    ("autopilot", "scenario", "needs", "variable"),
    [
        ("px4", "sitl/px4/wall-stop.yaml", "bin/px4 and etc", "$AVOIDD_PX4_SITL_DIR"),
        (
            "ardupilot",
            "sitl/ardupilot/wall-stop.yaml",
            "arducopter and copter.parm",
            "$AVOIDD_SITL_DIR",
        ),
    ],
)
def test_sim_against_a_sitl_folder_without_the_autopilot_names_it_and_the_remedy(
    autopilot: str,
    scenario: str,
    needs: str,
    variable: str,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    empty = tmp_path / "no-sitl-here"
    empty.mkdir()
    code = main(["sim", autopilot, str(REPO / scenario), "--binary-dir", str(empty)])
    assert code == 2
    line = _one_line(capsys.readouterr().err.splitlines(), f"--binary-dir {empty}:")
    assert f"give --binary-dir the folder holding {needs}" in line, line
    # Not given: the default comes from the variable, and the line says so.
    monkeypatch.setenv(variable.lstrip("$"), str(empty))
    assert main(["sim", autopilot, str(REPO / scenario)]) == 2
    line = _one_line(capsys.readouterr().err.splitlines(), f"{empty} ({variable}):")
    assert f"set {variable} to the folder holding {needs}" in line, line
    # Without the variable either: the built-in default, shown as the full path it tried.
    monkeypatch.delenv(variable.lstrip("$"))
    monkeypatch.chdir(tmp_path)
    assert main(["sim", autopilot, str(REPO / scenario)]) == 2
    fallback = (tmp_path / ".." / "shared" / "sitl" / autopilot).absolute()
    _one_line(capsys.readouterr().err.splitlines(), f"{fallback} (the default, {variable} unset)")


def test_sim_against_sitl_takes_a_folder_named_like_the_binary_for_no_binary(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "bin" / "px4").mkdir(parents=True)  # a folder is "executable" to os.access
    (tmp_path / "etc").mkdir()
    argv = ["sim", "px4", str(REPO / "sitl/px4/wall-stop.yaml"), "--binary-dir", str(tmp_path)]
    assert main(argv) == 2
    _one_line(capsys.readouterr().err.splitlines(), "missing bin/px4 (an executable file)")


def test_sim_against_sitl_reports_a_bad_scenario_and_a_bad_setting_together(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    mark = _fake_sitl(tmp_path, "bin/px4", ("etc",))
    scenario = tmp_path / "broken.yaml"
    scenario.write_text("version: 1\nname: broken\nduration_s: -5\n")
    argv = ["sim", "px4", str(scenario), "--cp-dist", "0", "--binary-dir", str(tmp_path)]
    assert main(argv) == 2
    lines = capsys.readouterr().err.splitlines()
    assert lines[-1] == "configuration invalid; nothing was started"
    assert "--cp-dist 0.0" in lines[0], lines
    assert any(str(scenario) in line for line in lines[1:-1]), lines
    assert not mark.exists()


@pytest.mark.parametrize(
    ("argv", "binary", "others", "fragments"),
    [
        (
            ["px4", "sitl/px4/wall-stop.yaml", "--cp-dist", "0"],
            "bin/px4",
            ("etc",),
            ("--cp-dist 0.0", "CP_DIST"),
        ),
        (
            ["px4", "sitl/px4/wall-stop.yaml", "--cp-dist", "16"],
            "bin/px4",
            ("etc",),
            ("--cp-dist 16.0",),
        ),
        (
            ["ardupilot", "sitl/ardupilot/wall-stop.yaml", "--avoid-margin", "0.5"],
            "arducopter",
            ("copter.parm",),
            ("--avoid-margin 0.5", "AVOID_MARGIN"),
        ),
        (
            ["ardupilot", "sitl/ardupilot/wall-stop.yaml", "--push", "20"],
            "arducopter",
            ("copter.parm",),
            ("--push 20.0", "0.1 to 10 m/s"),
        ),
    ],
)
def test_sim_against_sitl_refuses_autopilot_settings_out_of_range_before_starting_it(
    argv: list[str],
    binary: str,
    others: tuple[str, ...],
    fragments: tuple[str, ...],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    mark = _fake_sitl(tmp_path, binary, others)
    argv = [argv[0], str(REPO / argv[1]), *argv[2:], "--binary-dir", str(tmp_path)]
    assert main(["sim", *argv]) == 2
    _one_line(capsys.readouterr().err.splitlines(), *fragments)
    assert not mark.exists(), "the autopilot was started"
