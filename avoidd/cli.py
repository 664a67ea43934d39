"""The ``avoidd`` command line: run, check-config, replay, eval, bench, mock-autopilot and more."""

from __future__ import annotations

import argparse
import asyncio
import logging
import os
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from avoidd import __version__
from avoidd.config import AppConfig, load_config
from avoidd.errors import AvoiddError, ConfigError
from avoidd.vision.calibration import Calibration, load_calibration

logger = logging.getLogger("avoidd")

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_CONFIG = 2


def _setup_logging(level: str) -> None:
    # Under journald the journal stamps each line; elsewhere a time helps.
    if os.environ.get("JOURNAL_STREAM"):
        fmt = "%(levelname)s %(name)s: %(message)s"
    else:
        fmt = "%(asctime)s %(levelname)s %(name)s: %(message)s"
    logging.basicConfig(level=getattr(logging, level), format=fmt, stream=sys.stderr)


def load_all(path: Path) -> tuple[AppConfig, dict[str, Calibration]]:
    """Load a configuration and the calibration of each head, collecting every problem.

    Args:
        path: The configuration file.

    Returns:
        The configuration and the calibrations by head name.

    Raises:
        ConfigError: Any problem in the configuration or a calibration file.
    """
    config = load_config(path)
    calibrations: dict[str, Calibration] = {}
    problems: list[str] = []
    for head in config.heads:
        try:
            calibration = load_calibration(head.calibration)
        except ConfigError as exc:
            problems.extend(exc.lines)
            continue
        source = head.source
        rig = calibration.rig
        if source.kind == "synthetic" and (calibration.maps is not None or rig.doffs_px != 0):
            problems.append(
                f"{head.calibration}: head '{head.name}' renders a synthetic scene, which needs "
                "a 'rectified' calibration with doffs 0"
            )
        if source.kind == "v4l2" and (source.width, source.height) != (rig.width, rig.height):
            problems.append(
                f"{path}: heads.{head.name}.source asks {source.width}x{source.height} but "
                f"{head.calibration} is for {rig.width}x{rig.height}; make them agree"
            )
        if source.kind == "synthetic" and (
            source.camera_pitch_deg != head.mount.pitch_deg or head.mount.roll_deg != 0.0
        ):
            problems.append(
                f"{path}: heads.{head.name}: the synthetic camera is pitched "
                f"{source.camera_pitch_deg} deg but mount.pitch_deg says {head.mount.pitch_deg} "
                f"(roll {head.mount.roll_deg}); make the mount pitch equal camera_pitch_deg, "
                "roll 0"
            )
        if config.mavlink.distance_sensor.enabled:
            from avoidd.mavlink.messages import sensor_orientation
            from avoidd.types import Mount

            m = head.mount
            if sensor_orientation(Mount(m.yaw_deg, m.pitch_deg, m.roll_deg)) is None:
                problems.append(
                    f"{path}: heads.{head.name}.mount: yaw {m.yaw_deg} deg, pitch {m.pitch_deg} "
                    "deg has no DISTANCE_SENSOR orientation (yaw within 2.5 deg of a multiple "
                    "of 45, pitch within +-30); fix the mount or set "
                    "mavlink.distance_sensor.enabled: false"
                )
        calibrations[head.name] = calibration
    signing = config.mavlink.signing
    if signing is not None:
        from avoidd.mavlink.signing import load_key

        try:
            load_key(signing.key_file, signing.key_credential)
        except ConfigError as exc:
            problems.extend(exc.lines)
        folder = signing.timestamp_file.parent if signing.timestamp_file else None
        if folder is not None and not os.access(folder, os.W_OK):
            problems.append(
                f"mavlink.signing.timestamp_file: folder {folder} missing or not writable; "
                "create it (systemd: StateDirectory=avoidd)"
            )
    if problems:
        raise ConfigError(problems)
    return config, calibrations


def _cmd_check_config(args: argparse.Namespace) -> int:
    config, calibrations = load_all(args.config)
    for head in config.heads:
        rig = calibrations[head.name].rig
        print(
            f"head '{head.name}': {head.source.kind}, {rig.width}x{rig.height}, "
            f"fx {rig.fx:.1f} px, baseline {rig.baseline_m:.4f} m, "
            f"HFOV {rig.hfov_deg:.1f} deg, yaw {head.mount.yaw_deg:+.0f} deg"
        )
    signed = ", signed" if config.mavlink.signing is not None else ""
    print(f"MAVLink {config.mavlink.link} as system {config.mavlink.system_id}{signed}")
    print(f"{args.config}: OK")
    return EXIT_OK


def _cmd_run(args: argparse.Namespace) -> int:
    from avoidd.daemon import Daemon

    config, calibrations = load_all(args.config)
    return asyncio.run(Daemon(config, calibrations).run())


def _cmd_replay(args: argparse.Namespace) -> int:
    from avoidd.replay import format_summary, replay, select_head

    config, calibrations = load_all(args.config)
    head = select_head(config, args.head)
    if args.input is not None and not args.input.exists():
        raise ConfigError([f"--input {args.input}: not found; give a folder or a video file"])
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with args.out.open("w", encoding="utf-8") as out:
        summary = replay(config, calibrations[head.name], head, out, args.input, args.max_frames)
    print(format_summary(summary))
    print(f"wrote {summary.frames} lines to {args.out}")
    return EXIT_OK


def _cmd_measure(args: argparse.Namespace) -> int:
    from avoidd.perception import commands as perception
    from avoidd.replay import select_head

    config, calibrations = load_all(args.config)
    head = select_head(config, args.head)
    pipeline, results = perception.process_frames(
        config, head, calibrations[head.name], args.input, args.frame, 1
    )
    result = results[0]
    geometry = perception.camera_geometry(pipeline, result)
    if args.pixel is not None:
        u, v = args.pixel
        print(f"head '{head.name}', frame {result.seq}, pixel given")
    else:
        found = perception.nearest_obstacle_pixel(pipeline, result)
        if found is None:
            print(f"head '{head.name}', frame {result.seq}: no obstacle in view")
            return EXIT_FAILURE
        u, v = found
        nearest = result.obstacles[0]
        print(
            f"head '{head.name}', frame {result.seq}: nearest obstacle "
            f"{nearest.distance_m:.2f} m at {nearest.bearing_deg:+.1f} deg, "
            f"its ground contact at pixel ({u}, {v})"
        )
    measurement = perception.measure_pixel(result.depth_m, pipeline.work_rig, geometry, u, v)
    print(perception.format_measurement(measurement, geometry))
    return EXIT_OK


def _cmd_calibrate_mount(args: argparse.Namespace) -> int:
    from avoidd.perception import commands as perception
    from avoidd.replay import select_head

    if args.height_m is not None or args.op_m is not None:
        if args.height_m is None or args.op_m is None:
            raise ConfigError(["--height-m and --op-m go together (camera height and OP)"])
        print(perception.format_manual_mount(args.height_m, args.op_m))
        return EXIT_OK
    if args.config is None:
        raise ConfigError(["give --config (fit flat ground) or --height-m and --op-m"])
    config, calibrations = load_all(args.config)
    head = select_head(config, args.head)
    pipeline, results = perception.process_frames(
        config, head, calibrations[head.name], args.input, 0, args.frames
    )
    rig = pipeline.work_rig
    # Within 0.1 f B one pixel of disparity is at most 10% of depth.
    fit = perception.fit_mount([r.depth_m for r in results], rig, 0.1 * rig.fx * rig.baseline_m)
    print(perception.format_mount_fit(fit, head.mount.position_m[2]))
    return EXIT_OK


def _cmd_eval_perception(args: argparse.Namespace) -> int:
    from avoidd.evaluation.scenes import contact_suite, run_suite, suite

    summary = run_suite(suite(args.scenes, args.seed) + contact_suite(args.contact_scenes))
    print(summary.format())
    return EXIT_OK


def _cmd_mock_autopilot(args: argparse.Namespace) -> int:
    from avoidd.mavlink.mock_autopilot import MockAutopilot, serve
    from avoidd.mavlink.signing import load_key

    streams: dict[str, float] = {}
    for item in args.stream:
        name, _, rate = item.partition("=")
        try:
            streams[name] = float(rate)
        except ValueError:
            raise ConfigError([f"--stream {item}: write NAME=HZ, e.g. ATTITUDE=50"]) from None
    try:
        autopilot = MockAutopilot(
            flavour=args.flavour,
            system_id=args.system_id,
            mode=args.mode or "",
            armed=args.armed,
            key=load_key(args.key_file, None) if args.key_file else None,
            fixed_streams=streams,
        )
    except (KeyError, ValueError) as exc:
        raise ConfigError([f"mock-autopilot: {exc}"]) from None
    asyncio.run(serve(autopilot, args.connection, args.duration))
    return EXIT_OK


def _cmd_eval(args: argparse.Namespace) -> int:
    import json

    from avoidd.evaluation.run import evaluate, format_runs

    runs = evaluate(args.path, args.matcher or ["sgbm"], args.max_scenes)
    print(format_runs(runs))
    if args.json is not None:
        payload = [run.as_json() for run in runs]
        document = payload[0] if len(payload) == 1 else payload
        args.json.write_text(json.dumps(document, indent=2) + "\n")
    return EXIT_OK


def _cmd_bench(args: argparse.Namespace) -> int:
    import json

    from avoidd.bench import (
        DISPARITIES,
        MATCHERS,
        RESOLUTIONS,
        euroc_frames,
        format_bench,
        run_bench,
    )

    resolutions = RESOLUTIONS[:2] if args.quick else RESOLUTIONS
    disparities = DISPARITIES[:1] if args.quick else DISPARITIES
    recorded = [euroc_frames(args.euroc, args.frames)] if args.euroc is not None else []
    records = run_bench(
        args.matcher or list(MATCHERS), resolutions, disparities, args.frames, recorded
    )
    print(format_bench(records))
    if args.json is not None:
        args.json.write_text(json.dumps(records, indent=2) + "\n")
    return EXIT_OK


def _cmd_bench_link(args: argparse.Namespace) -> int:
    from avoidd.mavlink.bench import format_report, run_bench

    report = asyncio.run(run_bench(args.rate, args.seconds))
    print(format_report(report))
    if args.json is not None:
        import json

        args.json.write_text(json.dumps(report, indent=2) + "\n")
    return EXIT_OK


def _cmd_calibrate(args: argparse.Namespace) -> int:
    from avoidd.calibrate.commands import make_board, run_calibrate

    board = make_board(args.pattern, args.squares, args.square_mm, args.marker_mm, args.dictionary)
    run_calibrate(args.folder, board, args.out)
    return EXIT_OK


def _cmd_render_board(args: argparse.Namespace) -> int:
    from avoidd.calibrate.commands import make_board
    from avoidd.calibrate.render import default_rig, write_pairs

    board = make_board(args.pattern, args.squares, args.square_mm, args.marker_mm, args.dictionary)
    write_pairs(args.folder, board, default_rig(), args.count, args.seed)
    print(f"wrote {args.count} pairs to {args.folder}/left and {args.folder}/right")
    return EXIT_OK


def _cmd_import_calibration(args: argparse.Namespace) -> int:
    from avoidd.calibrate.commands import run_import

    run_import(args.kind, args.files, args.out)
    return EXIT_OK


def _cmd_check_rectification(args: argparse.Namespace) -> int:
    import json

    from avoidd.calibrate.commands import run_check

    figures = run_check(args.calibration, args.folder, args.max_pairs)
    if args.json is not None:
        args.json.write_text(json.dumps(figures, indent=2) + "\n")
    return EXIT_OK


def _add_board_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--pattern", choices=["chessboard", "charuco"], default="chessboard")
    parser.add_argument(
        "--squares", default="10x7", help="squares across x down (a 10x7 board has 9x6 corners)"
    )
    parser.add_argument("--square-mm", type=float, default=25.0, help="side of one square, mm")
    parser.add_argument("--marker-mm", type=float, help="ChArUco marker side, mm")
    parser.add_argument("--dictionary", default="DICT_4X4_50", help="ChArUco ArUco dictionary")


def _add_calibration_commands(commands: argparse._SubParsersAction[Any]) -> None:
    cal = commands.add_parser(
        "calibrate", help="stereo calibration from left/ and right/ images of a board"
    )
    cal.add_argument("folder", type=Path, help="folder with left/ and right/ image pairs")
    _add_board_options(cal)
    cal.add_argument("--out", type=Path, required=True, help="calibration YAML to write")
    cal.set_defaults(handler=_cmd_calibrate)

    ren = commands.add_parser(
        "render-board", help="render board pairs through a virtual rig (to try calibrate)"
    )
    ren.add_argument("folder", type=Path, help="where left/ and right/ are written")
    _add_board_options(ren)
    ren.add_argument("--count", type=int, default=15, help="number of pairs")
    ren.add_argument("--seed", type=int, default=0)
    ren.set_defaults(handler=_cmd_render_board)

    imp = commands.add_parser(
        "import-calibration", help="convert a EuRoC sensor.yaml pair or a Middlebury calib.txt"
    )
    imp.add_argument("kind", choices=["euroc", "middlebury"])
    imp.add_argument("files", type=Path, nargs="+", help="cam0 and cam1 sensor.yaml, or calib.txt")
    imp.add_argument("--out", type=Path, required=True, help="calibration YAML to write")
    imp.set_defaults(handler=_cmd_import_calibration)

    chk = commands.add_parser(
        "check-rectification", help="|dy| of features matched across rectified real pairs"
    )
    chk.add_argument("--calibration", type=Path, required=True, help="calibration YAML")
    chk.add_argument("folder", type=Path, help="left/ + right/ folder, or a EuRoC mav0 folder")
    chk.add_argument("--max-pairs", type=int, default=20, help="pairs to sample")
    chk.add_argument("--json", type=Path, help="also write the figures as JSON")
    chk.set_defaults(handler=_cmd_check_rectification)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``avoidd`` command."""
    parser = argparse.ArgumentParser(
        prog="avoidd", description="Stereo-vision obstacle avoidance for ArduPilot and PX4."
    )
    parser.add_argument("--version", action="version", version=f"avoidd {__version__}")
    parser.add_argument(
        "--log-level", default="INFO", choices=["DEBUG", "INFO", "WARNING", "ERROR"]
    )
    commands = parser.add_subparsers(dest="command", required=True)

    run = commands.add_parser("run", help="run the daemon")
    run.add_argument("--config", type=Path, required=True, help="YAML configuration file")
    run.set_defaults(handler=_cmd_run)

    check = commands.add_parser("check-config", help="validate a configuration, touch nothing")
    check.add_argument("config", type=Path, help="YAML configuration file")
    check.set_defaults(handler=_cmd_check_config)

    rep = commands.add_parser("replay", help="process every frame offline into JSON lines")
    rep.add_argument("--config", type=Path, required=True, help="YAML configuration file")
    rep.add_argument("--input", type=Path, help="folder of left/right pairs or side-by-side video")
    rep.add_argument("--max-frames", type=int, help="stop after N frames")
    rep.add_argument("--head", help="head to replay (default: the first)")
    rep.add_argument("--out", type=Path, required=True, help="output .jsonl file")
    rep.set_defaults(handler=_cmd_replay)

    ev = commands.add_parser(
        "eval", help="score matchers on stereo data with ground truth (Middlebury, KITTI)"
    )
    ev.add_argument("path", type=Path, help="a scene folder, a dataset folder, or a folder of them")
    ev.add_argument(
        "--matcher",
        action="append",
        help="sgbm (default), sgbm-gated, sgbm-nopad, sad, sad-pad, census, segment, opencv-sgbm; "
        "repeat",
    )
    ev.add_argument("--max-scenes", type=int, help="stop after N scenes")
    ev.add_argument("--json", type=Path, help="also write the scores as JSON")
    ev.set_defaults(handler=_cmd_eval)

    mock = commands.add_parser(
        "mock-autopilot", help="run a mock ArduPilot/PX4 autopilot (for tests and sitl/)"
    )
    mock.add_argument(
        "connection", help="udpin:/udpout:/tcpin:/tcp:HOST:PORT, or pty:PATH for a serial line"
    )
    mock.add_argument("--flavour", choices=["ardupilot", "px4"], default="ardupilot")
    mock.add_argument("--system-id", type=int, default=1)
    mock.add_argument("--mode", help="flight mode name (default STABILIZE / POSCTL)")
    mock.add_argument("--armed", action="store_true")
    mock.add_argument("--key-file", type=Path, help="sign with this key; ignore unsigned input")
    mock.add_argument(
        "--stream", action="append", default=[], help="NAME=HZ: stream without being asked"
    )
    mock.add_argument("--duration", type=float, help="stop after this many seconds")
    mock.set_defaults(handler=_cmd_mock_autopilot)

    vb = commands.add_parser(
        "bench", help="per-stage milliseconds of each matcher next to bare OpenCV SGBM"
    )
    vb.add_argument(
        "--matcher",
        action="append",
        choices=["sgbm", "sad", "census", "segment"],
        help="time only this matcher (repeat for several; default: all four)",
    )
    vb.add_argument("--frames", type=int, default=5, help="frames per configuration")
    vb.add_argument("--quick", action="store_true", help="320x240 and 640x480, 64 disparities")
    vb.add_argument("--json", type=Path, help="also write the figures as JSON")
    vb.add_argument(
        "--euroc",
        type=Path,
        metavar="MAV0",
        help="also time a recorded EuRoC sequence (its mav0 folder) at its own size",
    )
    vb.set_defaults(handler=_cmd_bench)

    _add_calibration_commands(commands)

    mea = commands.add_parser(
        "measure",
        help="range a pixel (or the nearest obstacle) by stereo and by the ground-plane geometry",
    )
    mea.add_argument("--config", type=Path, required=True, help="YAML configuration file")
    mea.add_argument("--head", help="head name (default: the first)")
    mea.add_argument("--input", type=Path, help="read this folder or video instead")
    mea.add_argument("--frame", type=int, default=0, help="frame number (default 0)")
    mea.add_argument(
        "--pixel", type=int, nargs=2, metavar=("U", "V"), help="pixel (default: nearest obstacle)"
    )
    mea.set_defaults(handler=_cmd_measure)

    ep = commands.add_parser(
        "eval-perception",
        help="score obstacle perception on rendered scenes with exact truth",
    )
    ep.add_argument("--scenes", type=int, default=24, help="obstacle scenes (default 24)")
    ep.add_argument("--seed", type=int, default=2024, help="scene generator seed")
    ep.add_argument("--contact-scenes", type=int, default=12, help="roll-free contact scenes")
    ep.set_defaults(handler=_cmd_eval_perception)

    cm = commands.add_parser(
        "calibrate-mount",
        help="camera height and tilt from a view of flat ground, or from measured h and OP",
    )
    cm.add_argument("--config", type=Path, help="fit the ground seen by this config's head")
    cm.add_argument("--head", help="head name (default: the first)")
    cm.add_argument("--input", type=Path, help="read this folder or video instead")
    cm.add_argument("--frames", type=int, default=3, help="frames to fit (default 3)")
    cm.add_argument("--height-m", type=float, help="measured camera height h")
    cm.add_argument(
        "--op-m", type=float, help="measured distance OP to where the axis meets the ground"
    )
    cm.set_defaults(handler=_cmd_calibrate_mount)

    bench = commands.add_parser(
        "bench-link", help="measure CPU for decoding a stream of incoming MAVLink"
    )
    bench.add_argument("--rate", type=float, default=2000.0, help="messages per second")
    bench.add_argument("--seconds", type=float, default=5.0, help="measurement length")
    bench.add_argument("--json", type=Path, help="also write the figures as JSON")
    bench.set_defaults(handler=_cmd_bench_link)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``avoidd`` command.

    Args:
        argv: Arguments without the program name (default: ``sys.argv[1:]``).

    Returns:
        The exit code: 0 ok, 1 runtime failure, 2 configuration error.
    """
    args = build_parser().parse_args(argv)
    _setup_logging(args.log_level)
    try:
        code: int = args.handler(args)
    except ConfigError as exc:
        for line in exc.lines:
            print(line, file=sys.stderr)
        print("configuration invalid; nothing was started", file=sys.stderr)
        return EXIT_CONFIG
    except AvoiddError as exc:
        logger.error("%s", exc)
        return EXIT_FAILURE
    except KeyboardInterrupt:
        return EXIT_OK
    return code
