"""``avoidd sim run|batch|ardupilot|px4``: closed-loop scenarios in the simulator or a real SITL."""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import TYPE_CHECKING, Any

from avoidd.commands import EXIT_CONFIG, EXIT_FAILURE, EXIT_OK
from avoidd.errors import ConfigError

if TYPE_CHECKING:
    from avoidd.config.sim import ScenarioConfig
    from avoidd.sim.batch import BatchJob

_ARDUPILOT_DIR = Path("../shared/sitl/ardupilot")
"""ArduCopter SITL's folder when neither ``--binary-dir`` nor ``$AVOIDD_SITL_DIR`` says."""
_PX4_DIR = Path("../shared/sitl/px4")
"""PX4 SITL's folder when neither ``--binary-dir`` nor ``$AVOIDD_PX4_SITL_DIR`` says."""


def configure(name: str, parser: argparse.ArgumentParser) -> None:
    """Add ``sim run`` and ``sim batch``."""
    actions = parser.add_subparsers(dest="sim_action", metavar="ACTION", required=True)
    run = actions.add_parser("run", help="run one scenario and write its trace, summary, plot")
    run.add_argument("scenario", type=Path, help="scenario file (sitl/scenarios/*.yaml)")
    run.add_argument("--seed", type=int, help="replace the generator's (or world's) seed")
    run.add_argument("--out", type=Path, help="folder for trace.jsonl, summary.json, plot.png")
    run.add_argument(
        "--realtime",
        action="store_true",
        help="run avoidd's whole daemon in real time against the simulated vehicle as an "
        "autopilot on a loopback MAVLink link (not deterministic)",
    )
    run.set_defaults(handler=run_one)
    batch = actions.add_parser("batch", help="run many scenarios and seeds; print a table")
    batch.add_argument("scenarios", type=Path, nargs="+", help="scenario files")
    batch.add_argument(
        "--seeds", type=int, default=1, help="seeds per scenario: its own, then the next ones"
    )
    batch.add_argument("--workers", type=int, default=os.cpu_count() or 1, help="local processes")
    batch.add_argument("--json", type=Path, help="also write every summary as JSON")
    batch.add_argument(
        "--ray",
        metavar="ADDRESS",
        help="run the jobs as Ray tasks on the cluster at ADDRESS (auto, ray://HOST:10001), "
        "or 'local' to start a Ray instance here with --workers CPUs",
    )
    batch.add_argument(
        "--max-speed",
        type=float,
        help="top speed for every scenario, m/s (a speed sweep over the same batch)",
    )
    batch.set_defaults(handler=run_batch)
    sitl = actions.add_parser(
        "ardupilot", help="fly one scenario with a real ArduCopter SITL and avoidd's daemon"
    )
    sitl.add_argument("scenario", type=Path, help="scenario file (sitl/scenarios/*.yaml)")
    sitl.add_argument(
        "--binary-dir",
        type=Path,
        help="folder with arducopter and copter.parm (default: $AVOIDD_SITL_DIR, else "
        f"{_ARDUPILOT_DIR})",
    )
    sitl.add_argument(
        "--push",
        type=float,
        metavar="M_S",
        help="planner off: push the vehicle at the goal at this speed; ArduPilot's own "
        "avoidance must stop it on avoidd's data",
    )
    sitl.add_argument("--avoid-margin", type=float, help="ArduPilot's AVOID_MARGIN, 1 to 10 metres")
    sitl.add_argument("--json", type=Path, help="write the summary and every sample as JSON")
    sitl.set_defaults(handler=run_ardupilot)
    px4 = actions.add_parser(
        "px4", help="fly one scenario with a real PX4 SITL (SIH) and avoidd's daemon"
    )
    px4.add_argument("scenario", type=Path, help="scenario file (sitl/px4/*.yaml)")
    px4.add_argument(
        "--binary-dir",
        type=Path,
        help=f"folder with bin/px4 and etc/ (default: $AVOIDD_PX4_SITL_DIR, else {_PX4_DIR})",
    )
    px4.add_argument(
        "--push",
        action="store_true",
        help="planner off: full forward stick in Position mode; PX4's collision prevention "
        "must stop the vehicle on avoidd's data",
    )
    px4.add_argument("--cp-dist", type=float, help="PX4's CP_DIST, metres: more than 0, at most 15")
    px4.add_argument("--json", type=Path, help="write the summary and every sample as JSON")
    px4.set_defaults(handler=run_px4)


def run_one(args: argparse.Namespace) -> int:
    """Run one scenario; exit 0 when it passes its criteria, 1 when not."""
    from avoidd.sim.report import format_table
    from avoidd.sim.scenario import run_file, write_outputs

    if args.realtime:
        return _run_realtime(args)

    run, summary = run_file(args.scenario, args.seed)
    print(format_table([summary.as_json() | {"wall_time_s": round(summary.wall_time_s, 1)}]))
    if args.out is not None:
        for path in write_outputs(run, summary, args.out):
            print(f"wrote {path}")
    for failure in summary.failures:
        print(f"FAILED: {failure}")
    return EXIT_OK if summary.passed else EXIT_FAILURE


def _free_udp_port() -> int:
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


def _report(summary: Any, out_json: Path | None, report: dict[str, Any] | None = None) -> int:
    """Print an external or real-time run's summary (and write it with its samples)."""
    import dataclasses

    report = summary.as_json() if report is None else report
    print(json.dumps(report, indent=2))
    if out_json is not None:
        out_json.parent.mkdir(parents=True, exist_ok=True)
        samples = [dataclasses.asdict(sample) for sample in summary.samples]
        out_json.write_text(json.dumps(report | {"trace": samples}, indent=2) + "\n")
        print(f"wrote {out_json}")
    for failure in summary.failures:
        print(f"FAILED: {failure}")
    return EXIT_OK if summary.passed else EXIT_FAILURE


def _run_realtime(args: argparse.Namespace) -> int:
    """A real-time run: the batch table's line, and with ``--out`` the summary and the picture."""
    import asyncio
    import dataclasses
    import time

    from avoidd.sim.plot import plot_external
    from avoidd.sim.realtime import RealtimeRun
    from avoidd.sim.report import external_row, format_table

    problems = (
        [] if args.seed is None else ["--seed: a real-time run takes the scenario's own seed"]
    )
    run = RealtimeRun(_scenario_noting(args.scenario, problems, "a real-time run"))
    started = time.monotonic()
    summary = asyncio.run(run.run(_free_udp_port()))
    print(format_table([external_row(summary, time.monotonic() - started)]))
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        samples = [dataclasses.asdict(sample) for sample in summary.samples]
        summary_path = args.out / "summary.json"
        report = summary.as_json() | {"trace": samples}
        summary_path.write_text(json.dumps(report, indent=2) + "\n")
        plot_path = args.out / "plot.png"
        plot_external(run, summary, plot_path)
        for path in (summary_path, plot_path):
            print(f"wrote {path}")
    for failure in summary.failures:
        print(f"FAILED: {failure}")
    return EXIT_OK if summary.passed else EXIT_FAILURE


def run_ardupilot(args: argparse.Namespace) -> int:
    """Fly one scenario against ArduCopter SITL; exit 0 when it passes its criteria."""
    import asyncio

    from avoidd.sim.external import ExternalRun

    folder, problems = _sitl_folder(
        args.binary_dir,
        "AVOIDD_SITL_DIR",
        _ARDUPILOT_DIR,
        ("arducopter", "copter.parm"),
        "ArduCopter SITL",
    )
    if args.push is not None and not 0.1 <= args.push <= 10.0:
        problems.append(f"--push {args.push}: give 0.1 to 10 m/s")
    if args.avoid_margin is not None and not 1.0 <= args.avoid_margin <= 10.0:
        problems.append(
            f"--avoid-margin {args.avoid_margin}: give 1 to 10 m (ArduPilot's AVOID_MARGIN range)"
        )
    scenario = _scenario_noting(args.scenario, problems)
    run = ExternalRun(
        scenario,
        folder,
        mode="push" if args.push is not None else "planner",
        push_speed_m_s=args.push or 2.0,
        avoid_margin_m=args.avoid_margin,
    )
    summary = asyncio.run(run.run(_free_udp_port()))
    return _report(summary, args.json)


def _sitl_folder(
    given: Path | None, variable: str, fallback: Path, needs: tuple[str, ...], what: str
) -> tuple[Path, list[str]]:
    """The SITL folder to use, and what is missing from it (one line naming the remedy).

    Args:
        given: ``--binary-dir`` (None: not given).
        variable: The environment variable that sets the default.
        fallback: The default without that variable.
        needs: Paths inside the folder that must exist; the first is the binary (an
            executable file).
        what: The autopilot, for the message.

    Returns:
        The folder, and its problems (empty: none).
    """
    folder = given if given is not None else Path(os.environ.get(variable) or fallback)
    binary, *others = needs
    lacks = [] if _executable(folder / binary) else [f"{binary} (an executable file)"]
    lacks += [name for name in others if not (folder / name).exists()]
    if not lacks:
        return folder, []
    if given is not None:
        subject, remedy = f"--binary-dir {folder.absolute()}", "give --binary-dir"
    else:
        origin = f"${variable}" if os.environ.get(variable) else f"the default, ${variable} unset"
        subject = f"{folder.absolute()} ({origin})"
        remedy = f"give --binary-dir or set ${variable} to"
    return folder, [
        f"{subject}: no {what} here (missing {', '.join(lacks)}); {remedy} the folder holding "
        f"{' and '.join(needs)}"
    ]


def _executable(path: Path) -> bool:
    return path.is_file() and os.access(path, os.X_OK)


def _scenario_noting(path: Path, problems: list[str], run: str = "a SITL run") -> ScenarioConfig:
    """Load a scenario; with any problem (its own or earlier ones) raise them all at once.

    Args:
        path: The scenario file.
        problems: What is wrong already.
        run: What runs it, for what only the lockstep simulator plays.

    Raises:
        ConfigError: The scenario is invalid or asks what only the lockstep simulator plays,
            or ``problems`` is not empty.
    """
    from avoidd.config.sim import load_scenario
    from avoidd.sim.scenario import lockstep_only

    try:
        scenario = load_scenario(path)
    except ConfigError as exc:
        raise ConfigError(problems + exc.lines) from None
    problems = problems + lockstep_only(scenario, run)
    if problems:
        raise ConfigError(problems)
    return scenario


def run_px4(args: argparse.Namespace) -> int:
    """Fly one scenario against PX4 SITL; exit 0 when it passes its criteria."""
    import asyncio

    from avoidd.sim.px4_run import Px4Run

    folder, problems = _sitl_folder(
        args.binary_dir, "AVOIDD_PX4_SITL_DIR", _PX4_DIR, ("bin/px4", "etc"), "PX4 SITL"
    )
    if args.cp_dist is not None and not 0.0 < args.cp_dist <= 15.0:
        # PX4 takes -1 to 15; 0 or less switches collision prevention off.
        problems.append(
            f"--cp-dist {args.cp_dist}: give more than 0 and at most 15 m (PX4's CP_DIST; "
            "0 or less would switch its collision prevention off)"
        )
    scenario = _scenario_noting(args.scenario, problems)
    run = Px4Run(
        scenario,
        folder,
        mode="push" if args.push else "planner",
        cp_dist_m=args.cp_dist,
    )
    summary = asyncio.run(run.run())
    report = summary.as_json() | {
        "estimator_s": round(run.estimator_s, 1),
        "offboard_s": None if run.offboard_s is None else round(run.offboard_s, 2),
        "setpoints_after_release": run.setpoints_after_release,
    }
    return _report(summary, args.json, report)


class RayUnavailable(Exception):
    """``--ray`` was given but Ray is not installed or the cluster cannot be reached."""


def run_batch(args: argparse.Namespace) -> int:
    """Run every scenario with seeds 1..N in local processes or on Ray; exit 0 when all pass."""
    from avoidd.config.sim import load_scenario
    from avoidd.progress import Progress
    from avoidd.sim.batch import batch_jobs
    from avoidd.sim.report import format_table, format_totals

    # Every file valid (and read, with its world file) before anything runs.
    loaded = [(path, load_scenario(path)) for path in args.scenarios]
    if args.max_speed is not None and not 0.1 <= args.max_speed <= 20.0:
        raise ConfigError([f"--max-speed {args.max_speed}: give 0.1 to 20 m/s"])
    jobs = batch_jobs(loaded, args.seeds, args.max_speed)
    progress = Progress(len(jobs))
    results: list[dict[str, Any]] = []

    def finished(result: dict[str, Any]) -> None:
        results.append(result)
        progress.step(f"{result['name']} seed {result['seed']}")

    if args.ray is None:
        _run_local(jobs, max(1, args.workers), finished)
    else:
        try:
            _run_ray(jobs, args.ray, max(1, args.workers), finished)
        except RayUnavailable as exc:
            progress.close()
            print(f"--ray {args.ray}: {exc}", file=sys.stderr)
            return EXIT_CONFIG
    progress.close()
    results.sort(key=lambda r: (r["file"], r["seed"]))
    print(format_table(results))
    print(format_totals(results))
    if args.json is not None:
        args.json.write_text(json.dumps(results, indent=2) + "\n")
    return EXIT_OK if all(r["passed"] for r in results) else EXIT_FAILURE


def _run_local(
    jobs: list[BatchJob], workers: int, finished: Callable[[dict[str, Any]], None]
) -> None:
    """Run the jobs in local processes; hand each result over as it finishes."""
    from avoidd.sim.batch import run_job

    with ProcessPoolExecutor(max_workers=workers) as pool:
        for future in as_completed([pool.submit(run_job, job) for job in jobs]):
            finished(future.result())


_CANNOT_REACH = (
    "cannot reach the Ray cluster ({}); start one with 'ray start --head', give its address "
    "(auto, ray://HOST:10001), or use --ray local"
)


def _unreachable(address: str, timeout_s: float = 3.0) -> str | None:
    """Why a TCP connection to a ``[ray://]HOST:PORT`` address fails.

    None: it opens, or the address names no port (``auto``, ``local``).
    """
    import socket

    host, _, port = address.removeprefix("ray://").rpartition(":")
    if not host or not port.isdigit():
        return None
    try:
        with socket.create_connection((host, int(port)), timeout=timeout_s):
            return None
    except OSError as exc:
        return f"{host}:{port}: {exc.strerror or exc}"


def _auto_address() -> str | None:
    """Where ``auto`` points: ``RAY_ADDRESS``, or the last cluster started here (None: unknown).

    A stale record of a cluster that has stopped would make Ray retry for minutes.
    """
    try:
        from ray._private.services import get_ray_address_from_environment

        found = get_ray_address_from_environment("auto", None)
    except Exception:  # a private helper: without it, Ray's own search decides
        return None
    return found if isinstance(found, str) else None


def _run_ray(
    jobs: list[BatchJob], address: str, workers: int, finished: Callable[[dict[str, Any]], None]
) -> None:
    """Run the jobs as Ray tasks on the cluster at ``address``; hand each result on when done.

    ``local`` starts a private Ray instance on this machine with ``workers`` CPUs; any other
    address (``auto``, ``ray://host:10001``) joins a running cluster, whose workers get this
    driver's ``avoidd`` package (so every run is the same code as here) but must have its
    dependencies installed.

    Raises:
        RayUnavailable: Ray is not installed, or the cluster cannot be reached.
    """
    try:
        import ray
    except ImportError:
        raise RayUnavailable(
            "Ray is not installed; pip install 'avoidd[ray]' (or run without --ray)"
        ) from None
    import importlib.util
    import logging

    if address.startswith("ray://") and importlib.util.find_spec("grpc") is None:
        raise RayUnavailable("Ray Client is not installed; pip install 'avoidd[ray]'")
    if address == "local":
        options: dict[str, Any] = {"address": "local", "num_cpus": workers}
    else:
        import avoidd

        package = str(Path(avoidd.__file__).parent)
        options = {
            "address": address,
            "runtime_env": {"py_modules": [package], "excludes": ["__pycache__"]},
        }
    target = _auto_address() if address == "auto" else address
    unreachable = _unreachable(target or address)
    if unreachable is not None:  # Ray itself would retry for half a minute or more
        raise RayUnavailable(_CANNOT_REACH.format(unreachable))
    try:
        ray.init(**options, include_dashboard=False, logging_level=logging.WARNING)
    except ImportError as exc:  # ray:// needs the client's grpcio
        raise RayUnavailable(f"{exc}; pip install 'avoidd[ray]'") from None
    except (ConnectionError, TimeoutError, ValueError, RuntimeError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise RayUnavailable(_CANNOT_REACH.format(first)) from None
    from avoidd.sim.batch import run_job

    try:
        task = ray.remote(num_cpus=1)(run_job)
        pending = [task.remote(job) for job in jobs]
        while pending:  # whatever is done within a second, so that thousands of jobs stay cheap
            ready, pending = ray.wait(pending, num_returns=len(pending), timeout=1.0)
            for result in ray.get(ready):
                finished(result)
    finally:
        ray.shutdown()
