"""A corpus of broken configurations: each is refused by ``check-config`` with exit 2 and one
line that names the file, the line of the mistake, the key and what is valid; never a traceback.

Each case changes one thing in ``config/demo.yaml`` (the file a new user starts from). Answer
times are not asserted here (timings belong in benchmarks): run as ``avoidd check-config FILE``
processes, Python's start included, every case took 0.3 to 0.9 s on the 2-core machine.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from avoidd.cli import main
from tests.helpers import REPO

DEMO = (REPO / "config" / "demo.yaml").read_text()
CALIBRATION = REPO / "config" / "calibration" / "synthetic-640x480.yaml"

REMEDIES = (
    "use",
    "add",
    "remove",
    "check",
    "give",
    "keep only",
    "did you mean",
    "should be",
    "must be",
    "needs a token",
    "is a number from",
    "cannot exceed",
)
"""Words by which a line says what to do or what is valid (one must follow the key)."""

# (text in the demo, what it becomes, what the one line must name)
CASES = [
    ("version: 1", "version: 2", "version"),
    ("version: 1", "version: 1.0", "version"),
    ("version: 1\n", "version: 1\nbogus_section: 3\n", "bogus_section"),
    ("  - name: front", "  - name: ''", "heads[0].name"),
    ("  - name: front", "  - name: front\n    nonsense: 1", "heads[0].nonsense"),
    ("yaw_deg: 0,", "yaw_deg: 400,", "heads[0].mount.yaw_deg"),
    ("pitch_deg: 0,", "pitch_deg: abc,", "heads[0].mount.pitch_deg"),
    ("position_m: [0.0, 0.0, 0.0]", "position_m: [0.0, 0.0]", "heads[0].mount.position_m"),
    ("kind: synthetic", "kind: webcam", "heads[0].source.kind"),
    ("fps: 15\n      seed", "fps: 0\n      seed", "heads[0].source.fps"),
    ("fps: 15\n      seed", "fps: 1e-300\n      seed", "heads[0].source.fps"),
    ("seed: 1\n", "seed: -1\n", "heads[0].source.seed"),
    ("camera_height_m: 1.5", "camera_height_m: .inf", "heads[0].source.camera_height_m"),
    ("kind: sgbm", "kind: magic", "heads[0].matcher.kind"),
    ("num_disparities: 64", "num_disparities: 60", "heads[0].matcher.num_disparities"),
    ("num_disparities: 64", "num_disparities: '64'", "heads[0].matcher.num_disparities"),
    ("block_size: 5", "block_size: 4", "heads[0].matcher.block_size"),
    ("mode: sgbm_3way", "mode: fastest", "heads[0].matcher.mode"),
    ("median_size: 5", "median_size: 4", "heads[0].postprocess.median_size"),
    ("subpixel_refine: false", "subpixel_refine: maybe", "heads[0].postprocess.subpixel_refine"),
    ("min_pixels: 20", "min_pixels: -3", "heads[0].sectors.min_pixels"),
    ("connection: udpout:127.0.0.1:14550", "connection: udp:127.0.0.1", "mavlink.connection"),
    (
        "connection: udpout:127.0.0.1:14550",
        "connection: udpout:127.0.0.1:99999",
        "mavlink.connection",
    ),
    ("system_id: auto", "system_id: 0", "mavlink.system_id"),
    ("system_id: auto", "system_id: '7'", "mavlink.system_id"),
    ("system_id: auto", "system_id: true", "mavlink.system_id"),
    ("component_id: 196", "component_id: 300", "mavlink.component_id"),
    ("link_timeout_s: 3", "link_timeout_s: -1", "mavlink.link_timeout_s"),
    (
        "rate_hz: 15, max_distance_cm: 2000",
        "rate_hz: 0, max_distance_cm: 2000",
        "mavlink.obstacle_distance.rate_hz",
    ),
    (
        "max_distance_cm: 2000",
        "max_distance_cm: 99999999",
        "mavlink.obstacle_distance.max_distance_cm",
    ),
    (
        "distance_sensor: {enabled: true",
        "distance_sensor: {enabled: yes-please",
        "mavlink.distance_sensor.enabled",
    ),
    ("max_points: 16", "max_points: 0", "mavlink.obstacle_distance_3d.max_points"),
    ("attitude_hz: 50", "attitude_hz: -5", "mavlink.streams.attitude_hz"),
    ("max_age_ms: 300", "max_age_ms: 0", "pipeline.max_age_ms"),
    ("log_interval_s: 5", "log_interval_s: 0.000001", "pipeline.log_interval_s"),
    ("height_m: 1.5, margin_m: 0.3", "height_m: -1.5, margin_m: 0.3", "perception.ground.height_m"),
    ("above_m: 2.0", "above_m: .nan", "perception.band.above_m"),
    ("confirm_frames: 2", "confirm_frames: 5", "perception.temporal"),
    ("hold_ms: 200", "hold_ms: -200", "perception.temporal.hold_ms"),
    (
        "version: 1\n",
        "version: 1\navoidance: {enabled: true, margin_m: 50}\n",
        "avoidance.margin_m",
    ),
    (
        "version: 1\n",
        "version: 1\navoidance: {enabled: true, unknown: maybe}\n",
        "avoidance.unknown",
    ),
    (
        "version: 1\n",
        "version: 1\navoidance: {enabled: true, setpoint_rate_hz: 1}\n",
        "avoidance.setpoint_rate_hz",
    ),
    ("version: 1\n", "version: 1\navoidance: {goal: {north_m: 1, east_m: 2}}\n", "avoidance.goal"),
    ("calibration: CAL", "calibration: /nonexistent/cal.yaml", "calibration"),
    ("host: 127.0.0.1, port: 8080", "host: 0.0.0.0, port: 8080", "debug_server.host"),
    (
        "enabled: false, host: 127.0.0.1",
        "enabled: false, allow_remote: true, host: 192.168.4.1",
        "debug_server.host",
    ),
    ("port: 8080}", "port: 80800}", "debug_server.port"),
    ("version: 1\n", "version: 1\nversion: 1\n", "version"),
    ("pipeline:\n", "pipeline:\n\tmax_age_ms: 300\n", "YAML syntax error"),
    ("band: {above_m: 2.0", "band: {above_m: [2.0", "YAML syntax error"),
]


def test_the_corpus_is_large_and_every_case_changes_the_demo() -> None:
    assert len(CASES) >= 40
    for old, new, _ in CASES:
        assert old in DEMO or old == "calibration: CAL", old
        assert old != new


@pytest.mark.parametrize(("old", "new", "names"), CASES, ids=[c[2] for c in CASES])
def test_a_broken_configuration_is_one_line_naming_file_line_and_key(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], old: str, new: str, names: str
) -> None:
    base = DEMO.replace("calibration: calibration/synthetic-640x480.yaml", "calibration: CAL")
    text = base.replace(old, new, 1).replace("calibration: CAL", f"calibration: {CALIBRATION}")
    path = tmp_path / "broken.yaml"
    path.write_text(text)
    assert main(["check-config", str(path)]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    lines = err.splitlines()
    assert len(lines) == 2, lines
    assert lines[1] == "configuration invalid; nothing was started"
    # The line the mistake is on (a missing key: the line of the mapping that lacks it).
    first = text.index(new.split("\n")[0] if old != "calibration: CAL" else "calibration: /")
    start = text.count("\n", 0, first) + 1
    span = range(start, start + new.count("\n") + 1)
    prefix, _, rest = lines[0].partition(f"{path}:")
    assert prefix == "" and rest, lines[0]
    line_number = int(rest.split(":", 1)[0])
    assert line_number in span, (line_number, span, lines[0])
    assert names in lines[0], lines[0]
    # ... and what to do: the valid values or the change to make.
    remedy = lines[0].split(f"{names}:", 1)[-1]
    assert re.search(rf"\b({'|'.join(REMEDIES)})\b", remedy), lines[0]
