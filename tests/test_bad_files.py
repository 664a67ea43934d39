"""Files that are not what a configuration says (issue 52, item 8): one clear line and exit 2.

Control characters in any YAML file, a FIFO, a device or a folder where a file is named, a
recording whose frames are not the calibration's size, a huge image: each is refused by
``avoidd check-config`` (and so by ``run``) with one line naming the file and the remedy,
without hanging and without reading more than a file of its kind may hold. Each case runs as
its own process with a timeout: a FIFO that hung would otherwise hang the suite.
``tests/bench_bad_input.py`` times the same cases as a user waits for them.
"""

from __future__ import annotations

import os
import struct
import subprocess
import sys
import zlib
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
import pytest

from tests.helpers import REPO, synthetic_config, write_yaml
from tests.test_offline_config import _config, _pairs

CONTROL = {"NUL": "\x00", "BEL": "\x07", "ESC": "\x1b", "DEL": "\x7f", "a non-character": "\ufffe"}
"""Characters YAML refuses, by the name the error line gives them."""


def huge_png(path: Path, width: int, height: int) -> Path:
    """A valid grey PNG of ``width`` x ``height`` zeros, written without holding it in memory."""
    chunks = [(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0))]
    packer = zlib.compressobj(9)
    row = bytes(width + 1)  # filter byte 0, then the row
    data = b"".join(packer.compress(row) for _ in range(height)) + packer.flush()
    chunks.append((b"IDAT", data))
    chunks.append((b"IEND", b""))
    with path.open("wb") as out:
        out.write(b"\x89PNG\r\n\x1a\n")
        for kind, body in chunks:
            out.write(struct.pack(">I", len(body)) + kind + body)
            out.write(struct.pack(">I", zlib.crc32(kind + body) & 0xFFFFFFFF))
    return path


def _new(folder: Path) -> Path:
    folder.mkdir(parents=True)
    return folder


def _signed(folder: Path, signing: dict[str, object]) -> Path:
    return synthetic_config(_new(folder), "udpout:127.0.0.1:14550", mavlink={"signing": signing})


def hostile_files(folder: Path, with_huge_png: bool = True) -> Iterator[tuple[str, Path, str]]:
    """Every case: its name, the config to check, and a fragment its one line must hold."""
    good = synthetic_config(_new(folder / "good"), "udpout:127.0.0.1:14550")
    text = good.read_text()
    for name, char in CONTROL.items():
        case = folder / f"control-{len(name)}-{name.split()[-1]}.yaml"
        case.write_text(text.replace("version: 1\n", f"version: 1\n# a {char} here\n"))
        yield f"yaml: {name} in the config", case, f"{case}:2: character U+{ord(char):04X}"
    calibration = folder / "good" / "calib.yaml"
    bad_calibration = folder / "bel-calib.yaml"
    bad_calibration.write_text("# \x07\n" + calibration.read_text())
    case = folder / "bel-calibration.yaml"
    case.write_text(text.replace(str(calibration), str(bad_calibration)))
    yield "yaml: BEL in the calibration", case, f"{bad_calibration}:1: character U+0007 (BEL)"
    fifo = folder / "fifo.yaml"
    os.mkfifo(fifo)
    yield "config is a FIFO", fifo, f"{fifo}: a FIFO (named pipe), not a regular file"
    yield "config is a folder", folder, f"{folder}: a folder, not a regular file"
    yield "config is /dev/zero", Path("/dev/zero"), "/dev/zero: a character device"
    case = folder / "fifo-calibration.yaml"
    case.write_text(text.replace(str(calibration), str(fifo)))
    yield "calibration is a FIFO", case, f"{fifo} is a FIFO (named pipe), not a regular file"
    key_fifo = folder / "key.fifo"
    os.mkfifo(key_fifo)
    for name, key in (("a FIFO", key_fifo), ("/dev/zero", Path("/dev/zero")), ("a folder", folder)):
        case = _signed(folder / f"key-{name.split()[-1].strip('/')}", {"key_file": str(key)})
        yield f"key_file is {name}", case, f"{key}: cannot read the signing key"
    key = folder / "good.key"
    key.write_bytes(bytes(range(32)))
    for name, stamp in (("a folder", folder / "stamps"), ("a FIFO", folder / "stamp.fifo")):
        if name == "a folder":
            stamp.mkdir()
        else:
            os.mkfifo(stamp)
        case = _signed(
            folder / f"stamp-{name.split()[-1]}",
            {"key_file": str(key), "timestamp_file": str(stamp)},
        )
        yield f"timestamp_file is {name}", case, f"timestamp_file: {stamp} is {name}"
    params = folder / "params"
    params.mkdir()
    case = synthetic_config(
        _new(folder / "params-folder"),
        "udpout:127.0.0.1:14550",
        sections={"avoidance": {"params_file": str(params)}},
    )
    yield "params_file is a folder", case, f"avoidance.params_file: {params} is a folder"
    recording = _pairs(folder / "small" / "rec", 2)
    for side in ("left", "right"):
        for image in (recording / side).iterdir():
            cv2.imwrite(str(image), np.zeros((120, 160), np.uint8))
    case = _config(folder / "small", {"kind": "files", "path": "rec"}, mavlink=True)
    yield "recording of the wrong size", case, "the first left view is 160x120 but"
    if with_huge_png:
        recording = _pairs(folder / "huge" / "rec", 1)
        huge_png(recording / "left" / "000.png", 20000, 20000)
        case = _config(folder / "huge", {"kind": "files", "path": "rec"}, mavlink=True)
        yield "a 20000x20000 PNG", case, "000.png: 20000x20000 pixels, more than the"


def _check_config(path: Path) -> tuple[int, list[str]]:
    result = subprocess.run(
        [sys.executable, "-m", "avoidd", "check-config", str(path)],
        capture_output=True,
        text=True,
        timeout=60,  # a hang guard: a FIFO read without the fix never ends
        cwd=REPO,
        check=False,
    )
    return result.returncode, result.stderr.splitlines()


@pytest.fixture(scope="module")
def cases(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Path, str]]:
    folder = tmp_path_factory.mktemp("hostile")
    return {name: (path, fragment) for name, path, fragment in hostile_files(folder)}


CASE_NAMES = [
    *(f"yaml: {name} in the config" for name in CONTROL),
    "yaml: BEL in the calibration",
    "config is a FIFO",
    "config is a folder",
    "config is /dev/zero",
    "calibration is a FIFO",
    "key_file is a FIFO",
    "key_file is /dev/zero",
    "key_file is a folder",
    "timestamp_file is a folder",
    "timestamp_file is a FIFO",
    "params_file is a folder",
    "recording of the wrong size",
    "a 20000x20000 PNG",
]


def test_every_case_is_tested(cases: dict[str, tuple[Path, str]]) -> None:
    assert sorted(cases) == sorted(CASE_NAMES)


@pytest.mark.parametrize("name", CASE_NAMES)
def test_a_hostile_file_is_one_clear_line_and_exit_2(
    cases: dict[str, tuple[Path, str]], name: str
) -> None:
    path, fragment = cases[name]
    code, lines = _check_config(path)
    assert code == 2, lines
    assert len(lines) == 2 and lines[1] == "configuration invalid; nothing was started", lines
    assert fragment in lines[0], (fragment, lines[0])
    assert "Traceback" not in "\n".join(lines)


def test_the_huge_png_is_a_real_png(tmp_path: Path) -> None:
    # The huge case must be a picture a decoder would take, not a header that fails anyway.
    small = huge_png(tmp_path / "small.png", 300, 200)
    image = cv2.imread(str(small), cv2.IMREAD_UNCHANGED)
    assert image is not None and image.shape == (200, 300) and not image.any()


def test_yaml_errors_of_pyyaml_itself_stay_one_line(tmp_path: Path) -> None:
    path = write_yaml(tmp_path / "a.yaml", {"version": 1})
    path.write_text("version: 1\nheads: [\n")
    code, lines = _check_config(path)
    assert code == 2 and len(lines) == 2 and "YAML syntax error" in lines[0]
