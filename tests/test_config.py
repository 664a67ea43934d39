from __future__ import annotations

import subprocess
import sys
import typing
from pathlib import Path
from typing import Any

import pytest
from pydantic import BaseModel

from avoidd.cli import main
from avoidd.config import (
    AppConfig,
    AttitudeConfig,
    AvoidanceConfig,
    BandConfig,
    CensusConfig,
    ControlConfig,
    DebugServerConfig,
    DistanceSensorConfig,
    FilesSourceConfig,
    GoalConfig,
    GroundConfig,
    HeadConfig,
    HistogramConfig,
    MavlinkConfig,
    MountConfig,
    NearFieldConfig,
    ObstacleDistance3dConfig,
    ObstacleDistanceConfig,
    ObstaclesConfig,
    PerceptionConfig,
    PipelineConfig,
    PostprocessConfig,
    PreprocessConfig,
    SadConfig,
    SectorsConfig,
    SegmentConfig,
    ServiceConfig,
    SgbmConfig,
    SigningConfig,
    SimSourceConfig,
    StreamsConfig,
    SyntheticObstacleConfig,
    SyntheticSourceConfig,
    TemporalConfig,
    TextureConfig,
    V4l2SourceConfig,
    load_config,
)
from avoidd.config.connection import LinkSpec, parse_connection
from avoidd.config.debug_server import VideoConfig
from avoidd.errors import ConfigError
from avoidd.loading import load_all
from tests.helpers import REPO

BASE = """\
version: 1
heads:
  - name: front
    calibration: calib.yaml
    source:
      kind: synthetic
      fps: 15
    matcher:
      num_disparities: 64
mavlink:
  connection: udpout:127.0.0.1:14550
"""

CALIBRATION = """\
version: 1
rectified: {width: 320, height: 240, fx: 200, fy: 200, cx: 159.5, cy: 119.5, baseline_m: 0.1}
"""


def write(tmp_path: Path, text: str, name: str = "avoidd.yaml") -> Path:
    (tmp_path / "calib.yaml").write_text(CALIBRATION)
    path = tmp_path / name
    path.write_text(text)
    return path


def problems(path: Path) -> list[str]:
    with pytest.raises(ConfigError) as info:
        load_all(path)
    return info.value.lines


def test_valid_config_loads_with_defaults(tmp_path: Path) -> None:
    config = load_config(write(tmp_path, BASE))
    head = config.heads[0]
    assert head.calibration == tmp_path / "calib.yaml"
    assert head.matcher.num_disparities == 64
    assert head.mount.yaw_deg == 0.0
    assert config.mavlink.component_id == 196
    assert config.mavlink.obstacle_distance.rate_hz == 15.0
    assert config.mavlink.link == LinkSpec(kind="udpout", host="127.0.0.1", port=14550)
    with pytest.raises(ValueError):
        config.heads[0].name = "other"  # type: ignore[misc]


@pytest.mark.parametrize("name", sorted(p.name for p in (REPO / "config").glob("*.yaml")))
def test_shipped_configs_validate(name: str) -> None:
    config, calibrations = load_all(REPO / "config" / name)
    assert set(calibrations) == {h.name for h in config.heads}


@pytest.mark.parametrize(
    ("old", "new", "expected"),
    [
        (
            "num_disparities: 64",
            "num_disparity: 64",
            "avoidd.yaml:9: heads[0].matcher.num_disparity: unknown key; "
            "did you mean 'num_disparities'?",
        ),
        (
            "fps: 15",
            "fps: 15\n      path: frames",
            "avoidd.yaml:8: heads[0].source.path: unknown key; a key of another section "
            "or kind, not of this one; remove it here",
        ),
        (
            "version: 1",
            "version: 1\nbogus_section: 3",
            "avoidd.yaml:2: bogus_section: unknown key; remove it or check the spelling",
        ),  # only the keys valid where the mistake is are suggested (not mavlink's connection)
        (
            "connection: udpout",
            "conection: udpout",
            "avoidd.yaml:11: mavlink.conection: unknown key; did you mean 'connection'?",
        ),
        (
            "num_disparities: 64",
            "num_disparities: 60",
            "avoidd.yaml:9: heads[0].matcher.num_disparities: must be a multiple of 16; "
            "use 64 (got 60)",
        ),
        (
            "kind: synthetic",
            "kind: webcam",
            "avoidd.yaml:6: heads[0].source.kind: unknown kind 'webcam'; "
            "use one of 'synthetic', 'files', 'v4l2', 'sim'",
        ),
        (
            "fps: 15",
            "fps: fast",
            "avoidd.yaml:7: heads[0].source.fps: Input should be a valid number (got 'fast')",
        ),
        (
            "fps: 15",
            "fps: 0",
            "avoidd.yaml:7: heads[0].source.fps: Input should be greater than or equal to 0.1 "
            "(got 0)",
        ),
        (
            "udpout:127.0.0.1:14550",
            "udp:127.0.0.1:14550",
            "avoidd.yaml:11: mavlink.connection: unknown connection 'udp:127.0.0.1:14550'; use "
            "udpout:HOST:PORT, udpin:HOST:PORT, tcp:HOST:PORT, tcpin:HOST:PORT or /dev/ttyX,BAUD "
            "(got 'udp:127.0.0.1:14550')",
        ),
        ("version: 1", "version: 2", "avoidd.yaml:1: version: Input should be 1 (got 2)"),
        (
            "fps: 15",
            "fps: 15\n      fps: 4",
            "avoidd.yaml:8: heads[0].source.fps: duplicate key; keep only one of them",
        ),
        (
            "fps: 15",
            "fps: [15",
            "avoidd.yaml:8: YAML syntax error: expected ',' or ']', but got ':'; "
            "check indentation and quoting",
        ),
        (
            "name: front",
            "name: Front Camera",
            "avoidd.yaml:3: heads[0].name: use lower case letters, digits, '-' or '_', "
            "e.g. 'front' (got 'Front Camera')",
        ),
    ],
)
def test_broken_config_names_line_path_value_and_fix(
    tmp_path: Path, old: str, new: str, expected: str
) -> None:
    lines = problems(write(tmp_path, BASE.replace(old, new)))
    assert lines == [f"{tmp_path}/{expected}"]


def test_missing_section_is_reported_on_its_parent(tmp_path: Path) -> None:
    # The mavlink section may be left out (offline use); a head's source may not.
    text = BASE.replace("    source:\n      kind: synthetic\n      fps: 15\n", "")
    assert problems(write(tmp_path, text)) == [
        f"{tmp_path}/avoidd.yaml:3: heads[0].source: required key is missing; add it"
    ]


def test_every_problem_is_listed(tmp_path: Path) -> None:
    text = BASE.replace("fps: 15", "fps: -1").replace("127.0.0.1:14550", "127.0.0.1:99999")
    lines = problems(write(tmp_path, text))
    assert [line.split(": ")[0:2] for line in lines] == [
        [f"{tmp_path}/avoidd.yaml:7", "heads[0].source.fps"],
        [f"{tmp_path}/avoidd.yaml:11", "mavlink.connection"],
    ]


def test_missing_calibration_file_names_the_resolved_path(tmp_path: Path) -> None:
    lines = problems(write(tmp_path, BASE.replace("calib.yaml", "nope.yaml")))
    assert lines == [
        f"{tmp_path}/avoidd.yaml:4: heads[0].calibration: file not found: {tmp_path}/nope.yaml; "
        "check the path (relative to the config file) (got 'nope.yaml')"
    ]


def test_calibration_errors_name_the_calibration_file(tmp_path: Path) -> None:
    path = write(tmp_path, BASE)
    (tmp_path / "calib.yaml").write_text(
        "version: 1\nstereo:\n  width: 640\n  height: 480\n"
        "  K1: [[400, 0, 320], [0, 400, 240], [0, 0, 1]]\n  D1: [0, 0, 0, 0]\n"
        "  K2: [[400, 0, 320], [0, 400, 240], [0, 0, 1]]\n  D2: [0, 0, 0, 0]\n"
        "  R: [[1, 0, 0], [0, 2, 0], [0, 0, 1]]\n  T_m: [-0.1, 0, 0]\n"
    )
    assert problems(path) == [
        f"{tmp_path}/calib.yaml:9: stereo.R: R is not a rotation matrix (orthonormal, "
        "determinant +1) (got a list)"
    ]


def test_synthetic_head_needs_rectified_calibration(tmp_path: Path) -> None:
    path = write(tmp_path, BASE)
    (tmp_path / "calib.yaml").write_text(
        CALIBRATION.replace("baseline_m: 0.1", "baseline_m: 0.1, doffs: 3")
    )
    (line,) = problems(path)
    assert "renders a synthetic scene, which needs a 'rectified' calibration with doffs 0" in line


def test_v4l2_size_must_match_calibration(tmp_path: Path) -> None:
    text = BASE.replace(
        "kind: synthetic\n      fps: 15",
        "kind: v4l2\n      devices: [/dev/video0, /dev/video1]\n"
        "      width: 640\n      height: 480",
    )
    (line,) = problems(write(tmp_path, text))
    assert "asks 640x480 but" in line and "is for 320x240; make them agree" in line


def test_check_config_cli_exit_codes(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    good = write(tmp_path, BASE)
    assert main(["check-config", str(good)]) == 0
    assert "OK" in capsys.readouterr().out
    bad = write(tmp_path, BASE.replace("fps: 15", "fps: nope"), "bad.yaml")
    assert main(["check-config", str(bad)]) == 2
    err = capsys.readouterr().err
    assert f"{bad}:7: heads[0].source.fps" in err
    assert "nothing was started" in err


def test_run_with_bad_config_exits_before_touching_hardware(tmp_path: Path) -> None:
    # The camera device does not exist: a run that got as far as opening it would log that.
    text = BASE.replace(
        "kind: synthetic\n      fps: 15",
        "kind: v4l2\n      devices: [/dev/video-absent]\n      width: 320\n      height: 240",
    ).replace("num_disparities: 64", "num_disparities: 65")
    path = write(tmp_path, text)
    result = subprocess.run(
        [sys.executable, "-m", "avoidd", "run", "--config", str(path)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 2
    assert "heads[0].matcher.num_disparities: must be a multiple of 16; use 80" in result.stderr
    assert "video-absent" not in result.stderr


@pytest.mark.parametrize(
    ("text", "spec"),
    [
        ("udpout:127.0.0.1:14550", LinkSpec("udpout", "127.0.0.1", 14550)),
        ("udpin:0.0.0.0:14555", LinkSpec("udpin", "0.0.0.0", 14555)),
        ("tcp:localhost:5760", LinkSpec("tcp", "localhost", 5760)),
        ("udpout:[::1]:14550", LinkSpec("udpout", "::1", 14550)),
        ("/dev/ttyAMA0,921600", LinkSpec("serial", device="/dev/ttyAMA0", baud=921600)),
        ("/dev/ttyACM0", LinkSpec("serial", device="/dev/ttyACM0", baud=115200)),
        ("tcpin:127.0.0.1:5760", LinkSpec("tcpin", "127.0.0.1", 5760)),
        ("serial:/run/fc/ttyAP,57600", LinkSpec("serial", device="/run/fc/ttyAP", baud=57600)),
    ],
)
def test_connection_strings(text: str, spec: LinkSpec) -> None:
    assert parse_connection(text) == spec
    assert parse_connection(str(spec)) == spec


@pytest.mark.parametrize(
    ("text", "fragment"),
    [
        ("udp:1.2.3.4:5", "unknown connection"),
        ("udpout:127.0.0.1", "missing host or port"),
        ("udpout:127.0.0.1:0", "port must be a number from 1 to 65535"),
        ("tcp:0.0.0.0:5760", "needs a destination address"),
        ("udpout:[::1:14550", "IPv6 host needs brackets"),
        ("/dev/ttyS0,12345", "unsupported baud rate 12345"),
        ("/dev/ttyS0,fast", "is not a number"),
        ("serial:relative/tty,57600", "serial:/absolute/path"),
    ],
)
def test_bad_connection_strings(text: str, fragment: str) -> None:
    with pytest.raises(ValueError, match=fragment):
        parse_connection(text)


@pytest.mark.parametrize("name", ["demo.yaml", "rig360.yaml"])
def test_shipped_configs_load(name: str) -> None:
    config, calibrations = load_all(REPO / "config" / name)
    assert set(calibrations) == {head.name for head in config.heads}
    if name == "rig360.yaml":
        assert [h.mount.yaw_deg for h in config.heads] == [0, 90, 180, 270]
        assert config.mavlink.distance_sensor.enabled


def test_row_band_is_refused_with_a_pointer(tmp_path: Path) -> None:
    text = (REPO / "config" / "demo.yaml").read_text()
    text = text.replace("min_pixels: 20", "row_band: [0.3, 0.5]\n      min_pixels: 20")
    (tmp_path / "calibration").mkdir()
    calibration = REPO / "config" / "calibration" / "synthetic-640x480.yaml"
    (tmp_path / "calibration" / calibration.name).write_text(calibration.read_text())
    (tmp_path / "old.yaml").write_text(text)
    with pytest.raises(ConfigError) as caught:
        load_all(tmp_path / "old.yaml")
    assert "row_band is gone" in "\n".join(caught.value.lines)


# Every section of the file, written out, each with a marker line ``#@ PATH`` as its first line.
# A test swaps one marker for a misspelt key; the other markers stay comments, so lines keep.
EVERY_SECTION = """\
#@ (top level)
version: 1
heads:
  - #@ heads[0]
    name: synth
    calibration: calib.yaml
    mount:
      #@ heads[0].mount
      yaw_deg: 0
    source:
      #@ heads[0].source
      kind: synthetic
      obstacles:
        - #@ heads[0].source.obstacles[0]
          shape: pole
          forward_m: 5
    matcher:
      #@ heads[0].matcher
      kind: sgbm
    near_field:
      #@ heads[0].near_field
      enabled: true
    preprocess:
      #@ heads[0].preprocess
      median_px: 3
      texture:
        #@ heads[0].preprocess.texture
        method: mean
    postprocess:
      #@ heads[0].postprocess
      median_size: 5
    sectors:
      #@ heads[0].sectors
      min_pixels: 20
    histogram:
      #@ heads[0].histogram
      bins: 40
  - name: files
    calibration: calib.yaml
    source:
      #@ heads[1].source
      kind: files
      path: frames
    matcher:
      #@ heads[1].matcher
      kind: sad
  - name: cameras
    calibration: calib.yaml
    source:
      #@ heads[2].source
      kind: v4l2
      devices: [/dev/video0, /dev/video1]
      width: 320
      height: 240
    matcher:
      #@ heads[2].matcher
      kind: census
  - name: segments
    calibration: calib.yaml
    source:
      #@ heads[3].source
      kind: sim
      world: world.yaml
    matcher:
      #@ heads[3].matcher
      kind: segment
mavlink:
  #@ mavlink
  connection: udpout:127.0.0.1:14550
  obstacle_distance:
    #@ mavlink.obstacle_distance
    rate_hz: 15
  distance_sensor:
    #@ mavlink.distance_sensor
    enabled: false
  obstacle_distance_3d:
    #@ mavlink.obstacle_distance_3d
    enabled: false
  streams:
    #@ mavlink.streams
    attitude_hz: 50
  signing:
    #@ mavlink.signing
    key_credential: avoidd-signing
  control:
    #@ mavlink.control
    ground_stations: [255]
pipeline:
  #@ pipeline
  max_age_ms: 300
service:
  #@ service
  ready_timeout_s: 10
perception:
  #@ perception
  ground:
    #@ perception.ground
    height_m: 1.5
  band:
    #@ perception.band
    above_m: 2.0
  attitude:
    #@ perception.attitude
    roll_deg: 0
  temporal:
    #@ perception.temporal
    confirm_frames: 2
  obstacles:
    #@ perception.obstacles
    min_points: 30
avoidance:
  #@ avoidance
  enabled: false
  goal:
    #@ avoidance.goal
    north_m: 10
    east_m: 0
    altitude_m: 2
debug_server:
  #@ debug_server
  enabled: false
  video:
    #@ debug_server.video
    enabled: false
"""

SECTION_MODELS: dict[str, type[BaseModel]] = {
    "(top level)": AppConfig,
    "heads[0]": HeadConfig,
    "heads[0].mount": MountConfig,
    "heads[0].source": SyntheticSourceConfig,
    "heads[0].source.obstacles[0]": SyntheticObstacleConfig,
    "heads[0].matcher": SgbmConfig,
    "heads[0].near_field": NearFieldConfig,
    "heads[0].preprocess": PreprocessConfig,
    "heads[0].preprocess.texture": TextureConfig,
    "heads[0].postprocess": PostprocessConfig,
    "heads[0].sectors": SectorsConfig,
    "heads[0].histogram": HistogramConfig,
    "heads[1].source": FilesSourceConfig,
    "heads[1].matcher": SadConfig,
    "heads[2].source": V4l2SourceConfig,
    "heads[2].matcher": CensusConfig,
    "heads[3].source": SimSourceConfig,
    "heads[3].matcher": SegmentConfig,
    "mavlink": MavlinkConfig,
    "mavlink.obstacle_distance": ObstacleDistanceConfig,
    "mavlink.distance_sensor": DistanceSensorConfig,
    "mavlink.obstacle_distance_3d": ObstacleDistance3dConfig,
    "mavlink.streams": StreamsConfig,
    "mavlink.signing": SigningConfig,
    "mavlink.control": ControlConfig,
    "pipeline": PipelineConfig,
    "service": ServiceConfig,
    "perception": PerceptionConfig,
    "perception.ground": GroundConfig,
    "perception.band": BandConfig,
    "perception.attitude": AttitudeConfig,
    "perception.temporal": TemporalConfig,
    "perception.obstacles": ObstaclesConfig,
    "avoidance": AvoidanceConfig,
    "avoidance.goal": GoalConfig,
    "debug_server": DebugServerConfig,
    "debug_server.video": VideoConfig,
}


def section_models(model: type[BaseModel]) -> set[type[BaseModel]]:
    """The model and every model nested in its fields (through lists, unions, Annotated)."""
    found: set[type[BaseModel]] = set()
    pending: list[Any] = [model]
    while pending:
        item = pending.pop()
        if isinstance(item, type) and issubclass(item, BaseModel):
            if item not in found:
                found.add(item)
                pending.extend(info.annotation for info in item.model_fields.values())
        else:
            pending.extend(typing.get_args(item))
    return found


def misspell(name: str) -> str:
    """The name with its last letter changed."""
    return name[:-1] + ("q" if name[-1] != "q" else "x")


def every_section_file(tmp_path: Path, typo_at: str | None = None) -> tuple[Path, int]:
    """The file with every section, a misspelt key at ``typo_at``; returns it and that line."""
    (tmp_path / "frames").mkdir(exist_ok=True)
    (tmp_path / "world.yaml").write_text("version: 1\nobstacles: []\n")
    lines = EVERY_SECTION.splitlines()
    typo_line = 0
    for number, line in enumerate(lines, start=1):
        indent, marker, where = line.partition("#@ ")
        if marker and where == typo_at:
            field = next(iter(SECTION_MODELS[where].model_fields))
            lines[number - 1] = f"{indent}{misspell(field)}: 1"
            typo_line = number
    return write(tmp_path, "\n".join(lines) + "\n"), typo_line


def test_every_section_is_in_the_unknown_key_file(tmp_path: Path) -> None:
    assert set(SECTION_MODELS.values()) == section_models(AppConfig)
    path, _ = every_section_file(tmp_path)
    config = load_config(path)
    assert [type(head.source) for head in config.heads] == [
        SyntheticSourceConfig,
        FilesSourceConfig,
        V4l2SourceConfig,
        SimSourceConfig,
    ]
    assert [head.matcher.kind for head in config.heads] == ["sgbm", "sad", "census", "segment"]


@pytest.mark.parametrize("where", list(SECTION_MODELS))
def test_unknown_key_in_every_section_names_line_path_and_spelling(
    tmp_path: Path, where: str
) -> None:
    path, line = every_section_file(tmp_path, where)
    field = next(iter(SECTION_MODELS[where].model_fields))
    key = misspell(field)
    dotted = key if where == "(top level)" else f"{where}.{key}"
    with pytest.raises(ConfigError) as caught:
        load_config(path)
    assert caught.value.lines == [f"{path}:{line}: {dotted}: unknown key; did you mean '{field}'?"]


def test_allow_unsigned_takes_only_mavlink_message_names(tmp_path: Path) -> None:
    text = BASE + (
        "  signing:\n"
        "    key_credential: avoidd-signing\n"
        "    allow_unsigned: [RADIO_STATUS, ATTITUDE, RADIO_STATUSS]\n"
    )
    assert problems(write(tmp_path, text)) == [
        f"{tmp_path}/avoidd.yaml:14: mavlink.signing.allow_unsigned[2]: 'RADIO_STATUSS' is not "
        "a MAVLink message name (e.g. RADIO_STATUS) (got 'RADIO_STATUSS')"
    ]


def test_key_hints_follow_aliases_and_every_kind_of_tag(tmp_path: Path) -> None:
    """Hints come from the keys valid where the mistake is: a scenario's ``pass`` (the field
    ``passing``), an obstacle's own ``shape`` (not every shape's keys)."""
    from avoidd.config.sim import load_scenario, load_world

    world = tmp_path / "world.yaml"
    world.write_text(
        "version: 1\nobstacles:\n"
        "  - {shape: wall, start_ne_m: [12, -6], end_ne_m: [12, 6], height_m: 8, diameter_m: 3}\n"
    )
    with pytest.raises(ConfigError) as caught:
        load_world(world)
    assert caught.value.lines == [
        f"{world}:3: obstacles[0].diameter_m: unknown key; a key of another section or kind, "
        "not of this one; remove it here"
    ]
    scenario = tmp_path / "scenario.yaml"
    scenario.write_text(
        f"version: 1\nname: x\nworld: {world}\ngoal: {{north_m: 24, east_m: 0, altitude_m: 2}}\n"
        "pass: {no_collision: true, closest_aproach_m: [0.5, 2.0], fps: 3}\n"
    )
    with pytest.raises(ConfigError) as caught:
        load_scenario(scenario)
    assert f"{scenario}:5: pass.closest_aproach_m: unknown key; did you mean " in str(caught.value)
    assert "'closest_approach_m'?" in str(caught.value)
    assert f"{scenario}:5: pass.fps: unknown key; a key of another section or kind" in str(
        caught.value
    )
