"""The systemd service: the unit verifies and is hardened; the notify protocol on a real socket.

The daemon talks to a real ``AF_UNIX`` datagram socket given as ``NOTIFY_SOCKET`` (a path, or an
abstract name with ``@``), as systemd's would be. Bounds are generous (another process may keep
both cores busy): the assertions are about what arrives and in which order, not how fast.
"""

from __future__ import annotations

import asyncio
import configparser
import contextlib
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from avoidd.config import ServiceConfig
from avoidd.config.connection import STANDARD_BAUDS, parse_connection
from avoidd.daemon import Daemon
from avoidd.daemon.notify import Notifier, watchdog_interval_s
from avoidd.daemon.systemd import HeadProgress, ProgressMonitor, waiting_for
from avoidd.errors import SourceError
from avoidd.loading import load_all
from avoidd.sources import open_source as real_open_source
from avoidd.types import StereoFrame
from tests.helpers import REPO, free_udp_port, open_udp_peer, synthetic_config, wait_for

UNIT = REPO / "systemd" / "avoidd.service"
SIGNING = REPO / "systemd" / "avoidd-signing.conf"
RECORD = REPO / "systemd" / "avoidd-record.conf"
ROUTER = REPO / "systemd" / "mavlink-router.conf"
ANALYZE = shutil.which("systemd-analyze")
needs_analyze = pytest.mark.skipif(ANALYZE is None, reason="systemd-analyze is not installed")


# --- the unit file ---------------------------------------------------------------------------


def unit_settings(path: Path = UNIT) -> dict[str, list[str]]:
    """Every ``Key=value`` of a unit file, by key, in order."""
    settings: dict[str, list[str]] = {}
    for line in path.read_text().splitlines():
        if "=" in line and not line.startswith(("#", ";", "[")):
            key, _, value = line.partition("=")
            settings.setdefault(key.strip(), []).append(value.strip())
    return settings


def seconds(value: str) -> float:
    """A systemd time span written as ``10s``, ``1min`` or ``500ms``."""
    match = re.fullmatch(r"(\d+(?:\.\d+)?)(ms|s|min)?", value)
    assert match, f"unexpected time span {value!r}"
    scale = {"ms": 0.001, "s": 1.0, "min": 60.0, None: 1.0}[match.group(2)]
    return float(match.group(1)) * scale


def installed_copy(tmp_path: Path, drop_in: Path | None = None) -> Path:
    """The unit with ExecStart pointing at this environment's avoidd (verify needs it to exist).

    With ``drop_in``, its ``[Service]`` lines are added to the copy, as systemd would merge them.
    """
    executable = Path(sys.executable).parent / "avoidd"
    if not executable.is_file():
        pytest.skip(f"{executable} not installed (pip install -e .)")
    text = UNIT.read_text()
    assert "ExecStart=/opt/avoidd/venv/bin/avoidd " in text
    text = text.replace("/opt/avoidd/venv/bin/avoidd", str(executable))
    if drop_in is not None:
        extra = drop_in.read_text().partition("[Service]\n")[2]
        extra = extra.replace("/opt/avoidd/venv/bin/avoidd", str(executable))
        text = text.replace("[Install]", extra + "\n[Install]")
    copy = tmp_path / "avoidd.service"
    copy.write_text(text)
    return copy


@needs_analyze
@pytest.mark.parametrize(
    "drop_in",
    [None, SIGNING, RECORD],
    ids=["unit", "with signing drop-in", "with recording drop-in"],
)
def test_the_unit_passes_systemd_analyze_verify(tmp_path: Path, drop_in: Path | None) -> None:
    assert ANALYZE is not None
    result = subprocess.run(
        [ANALYZE, "verify", "--man=no", str(installed_copy(tmp_path, drop_in))],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout + result.stderr == "", "verify printed warnings"


@needs_analyze
def test_the_unit_exposure_is_at_most_3(tmp_path: Path) -> None:
    assert ANALYZE is not None
    result = subprocess.run(
        [ANALYZE, "security", "--offline=true", "--no-pager", str(installed_copy(tmp_path))],
        capture_output=True,
        text=True,
        timeout=60,
    )
    match = re.search(r"Overall exposure level for \S+: (\d+\.\d+)", result.stdout)
    assert match, result.stdout[-2000:] + result.stderr
    assert float(match.group(1)) <= 3.0, result.stdout


def test_the_unit_agrees_with_the_daemon() -> None:
    settings = unit_settings()
    assert settings["Type"] == ["notify"]
    assert settings["Restart"] == ["on-failure"]
    # A configuration error (exit 2) will not mend itself: no restart loop for it.
    assert settings["RestartPreventExitStatus"] == ["2"]
    # READY goes out after service.ready_timeout_s at the latest: before systemd gives up.
    assert ServiceConfig().ready_timeout_s < seconds(settings["TimeoutStartSec"][0])
    assert seconds(settings["WatchdogSec"][0]) >= 2 * ServiceConfig().status_interval_s
    assert "LoadCredential" not in settings  # a missing key file would stop the unit starting
    assert settings["StateDirectory"] == ["avoidd"]
    assert "char-video4linux rw" in settings["DeviceAllow"]
    assert settings["DevicePolicy"] == ["closed"]


def test_the_signing_drop_in_hands_over_the_credential_the_config_names() -> None:
    [credential] = unit_settings(SIGNING)["LoadCredential"]
    name, _, source = credential.partition(":")
    assert source == "/etc/avoidd/signing.key"
    assert f"key_credential: {name}" in SIGNING.read_text()
    assert f"key_credential: {name}" in (REPO / "systemd" / "README.md").read_text()


def test_the_recording_drop_in_records_where_the_unit_may_write(tmp_path: Path) -> None:
    # The unit's file system is read-only but for its state folder: the drop-in's --record
    # must lie there, its command line must be one `avoidd run` takes, and its folder pattern
    # must give a new name per start.
    from avoidd.cli import build_parser
    from avoidd.record import expand_folder

    reset, command = unit_settings(RECORD)["ExecStart"]
    assert reset == ""  # the unit's own ExecStart= is replaced, not added to (Type=notify)
    argv = command.replace("%%", "%").split()
    assert argv[0] == unit_settings()["ExecStart"][0].split()[0]
    args = build_parser("run").parse_args(argv[1:])
    state = Path("/var/lib") / unit_settings()["StateDirectory"][0]
    assert Path(args.record).is_relative_to(state), args.record
    assert args.record_max_gb is not None and args.record_max_gb > 0
    assert str(args.config) == unit_settings()["ExecStart"][0].split()[-1]
    first = expand_folder(tmp_path / Path(args.record).name)
    assert "%" not in first.name and first.name != Path(args.record).name
    assert "avoidd-record.conf" in (REPO / "systemd" / "README.md").read_text()


def test_the_mavlink_router_example_feeds_an_avoidd_udpin_link() -> None:
    router = configparser.ConfigParser()
    router.read(ROUTER)
    endpoint = router["UdpEndpoint avoidd"]
    assert endpoint["Mode"] == "Normal"  # the router sends to avoidd, which listens
    connection = f"udpin:{endpoint['Address']}:{endpoint['Port']}"
    assert parse_connection(connection).kind == "udpin"
    assert f"connection: {connection}" in ROUTER.read_text()
    assert int(router["UartEndpoint autopilot"]["Baud"]) in STANDARD_BAUDS
    assert router["UdpEndpoint gcs"]["Port"] != endpoint["Port"]


# --- the notify client and the rules ---------------------------------------------------------


def test_watchdog_interval_comes_from_the_environment() -> None:
    assert watchdog_interval_s({}) is None
    assert watchdog_interval_s({"WATCHDOG_USEC": "0"}) is None
    assert watchdog_interval_s({"WATCHDOG_USEC": "x"}) is None
    assert watchdog_interval_s({"WATCHDOG_USEC": "4000000"}) == 4.0
    assert watchdog_interval_s({"WATCHDOG_USEC": "4000000", "WATCHDOG_PID": "12"}, pid=12) == 4.0
    assert watchdog_interval_s({"WATCHDOG_USEC": "4000000", "WATCHDOG_PID": "13"}, pid=12) is None


def test_notify_socket_addresses() -> None:
    assert Notifier.from_environment({}) is None
    assert Notifier.from_environment({"NOTIFY_SOCKET": "relative/path"}) is None
    for address in ("/run/systemd/notify", "@abstract"):
        notifier = Notifier.from_environment({"NOTIFY_SOCKET": address})
        assert notifier is not None and notifier.address == address
        notifier.close()


def test_a_missing_manager_is_no_error(tmp_path: Path) -> None:
    notifier = Notifier(str(tmp_path / "nobody-listens"))
    assert not notifier.notify(READY="1")
    assert not notifier.notify(WATCHDOG="1")
    assert notifier.dropped == 2
    notifier.close()


def test_values_stay_on_one_line(tmp_path: Path) -> None:
    with NotifySocket(str(tmp_path / "notify")) as listener:
        notifier = Notifier(listener.address)
        assert notifier.notify(READY="1", STATUS="two\nlines")
        notifier.close()
        assert listener.sock.recv(4096) == b"READY=1\nSTATUS=two lines"


def _head(
    captured: int, processed: int, reading_since_ns: int | None = None, broken: int = 0
) -> HeadProgress:
    return HeadProgress("front", captured, processed, processed + broken, reading_since_ns)


def test_a_head_is_stuck_when_frames_wait_and_no_result_comes() -> None:
    s = 1_000_000_000
    monitor = ProgressMonitor(stall_ns=2 * s, started_ns=0)
    assert monitor.update([_head(5, 4)], 1 * s) == {}
    assert monitor.update([_head(20, 4)], 2 * s) == {}  # a slow frame is not a stall
    assert "no result for 2 s" in monitor.update([_head(40, 4)], 3 * s)["front"]
    assert monitor.update([_head(41, 5)], 4 * s) == {}  # it came back
    # Frames dropped as broken are finished too: the compute is alive (and reports them).
    assert monitor.update([_head(90, 5, broken=30)], 9 * s) == {}


def test_a_missing_camera_is_not_stuck_but_a_read_that_never_returns_is() -> None:
    s = 1_000_000_000
    monitor = ProgressMonitor(stall_ns=2 * s, started_ns=0)
    # Opens fail and are retried: nothing delivered, nothing to compute, no read hanging.
    assert monitor.update([_head(0, 0)], 60 * s) == {}
    assert waiting_for([_head(0, 0)]) == {"front": "no frame yet"}
    assert waiting_for([_head(3, 0)]) == {"front": "no result yet"}
    assert waiting_for([_head(3, 1)]) == {}
    # A read that started 3 s ago and has not returned: a wedged driver.
    assert "read blocked for 3 s" in monitor.update([_head(0, 0, 57 * s)], 60 * s)["front"]


# --- the daemon on a real notify socket ------------------------------------------------------


class NotifySocket:
    """A service manager's notification socket: a bound AF_UNIX datagram socket.

    ``address`` is a file path, or ``@name`` for an abstract socket.
    """

    def __init__(self, address: str) -> None:
        self.address = address
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind("\0" + address[1:] if address.startswith("@") else address)
        self.messages: list[dict[str, str]] = []

    def __enter__(self) -> NotifySocket:
        return self

    def __exit__(self, *exc: object) -> None:
        self.sock.close()

    def record(self, data: bytes) -> None:
        lines = data.decode().split("\n")
        self.messages.append(dict(line.split("=", 1) for line in lines))

    async def collect(self) -> None:
        """Receive in the running loop until cancelled."""
        self.sock.setblocking(False)
        loop = asyncio.get_running_loop()
        while True:
            self.record(await loop.sock_recv(self.sock, 65536))

    def collect_for(self, duration_s: float, until: Callable[[], bool] = lambda: False) -> None:
        """Receive (blocking) for ``duration_s`` or until ``until()``."""
        self.sock.settimeout(0.2)
        deadline = time.monotonic() + duration_s
        while time.monotonic() < deadline and not until():
            with contextlib.suppress(TimeoutError):
                self.record(self.sock.recv(65536))

    def index(self, key: str, value: str | None = None, start: int = 0) -> int | None:
        """Index of the first message from ``start`` with ``key`` (and ``value`` in it)."""
        for i, message in enumerate(self.messages[start:], start):
            if key in message and (value is None or value in message[key]):
                return i
        return None

    def count(self, key: str, start: int = 0, end: int | None = None) -> int:
        return sum(key in message for message in self.messages[start:end])


@pytest.fixture
def notify_socket(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Any:
    with NotifySocket(str(tmp_path / "notify")) as listener:
        monkeypatch.setenv("NOTIFY_SOCKET", listener.address)
        monkeypatch.setenv("WATCHDOG_USEC", "1000000")  # a ping every 0.5 s
        monkeypatch.setenv("WATCHDOG_PID", str(os.getpid()))
        yield listener


SERVICE = {"ready_timeout_s": 20.0, "status_interval_s": 0.5, "stall_s": 1.5}


async def run_with_notify(
    tmp_path: Path,
    listener: NotifySocket,
    scenario: Callable[[Daemon], Any],
    open_source: Any = None,
    service: dict[str, Any] | None = None,
) -> None:
    """Run a daemon on a synthetic camera while ``scenario(daemon)`` runs, then stop it."""
    peer = await open_udp_peer()
    path = synthetic_config(
        tmp_path, f"udpout:127.0.0.1:{peer.port}", sections={"service": service or SERVICE}
    )
    config, calibrations = load_all(path)
    daemon = Daemon(config, calibrations, open_source=open_source)
    collector = asyncio.create_task(listener.collect())
    task = asyncio.create_task(daemon.run())
    try:
        await scenario(daemon)
    finally:
        daemon.stop()
        assert await asyncio.wait_for(task, timeout=30.0) == 0
        await asyncio.sleep(0.1)
        collector.cancel()
        peer.close()
    assert listener.messages[-1] == {"STOPPING": "1", "STATUS": "stopping"}


async def test_ready_after_the_first_results_then_status_and_watchdog(
    tmp_path: Path, notify_socket: NotifySocket
) -> None:
    listener = notify_socket
    processed_at_ready: list[int] = []

    async def scenario(daemon: Daemon) -> None:
        assert await wait_for(lambda: listener.index("READY") is not None, 20.0)
        processed_at_ready.append(daemon.heads[0].stats.processed)
        assert await wait_for(lambda: listener.count("WATCHDOG") >= 3, 10.0)
        assert await wait_for(lambda: listener.count("STATUS") >= 3, 10.0)

    await run_with_notify(tmp_path, listener, scenario)
    ready = listener.index("READY")
    assert ready is not None and listener.messages[ready]["READY"] == "1"
    assert processed_at_ready[0] >= 1
    assert listener.count("WATCHDOG", end=ready) == 0, "pinged before READY"
    assert listener.count("READY") == 1
    statuses = [m["STATUS"] for m in listener.messages if "STATUS" in m]
    assert any(re.match(r"front \d+\.\d fps; no autopilot heard; ok$", s) for s in statuses)
    assert all(m["WATCHDOG"] == "1" for m in listener.messages if "WATCHDOG" in m)


async def test_a_stalled_matcher_stops_the_watchdog_until_it_recovers(
    tmp_path: Path, notify_socket: NotifySocket
) -> None:
    listener = notify_socket
    release = threading.Event()
    marks: dict[str, int] = {}

    async def scenario(daemon: Daemon) -> None:
        assert await wait_for(lambda: listener.count("WATCHDOG") >= 2, 20.0)
        head = daemon.heads[0]
        match = head.pipeline.match

        def stalled(*args: Any) -> Any:
            release.wait(30.0)
            return match(*args)

        head.pipeline.match = stalled
        # (A loaded machine may have said STUCK once at start, before the first result.)
        stalled_at = len(listener.messages)
        try:
            assert await wait_for(
                lambda: listener.index("STATUS", "STUCK front", stalled_at) is not None, 10
            )
            marks["stuck"] = listener.index("STATUS", "STUCK front", stalled_at) or 0
            await asyncio.sleep(1.5)  # three ping periods
            marks["release"] = len(listener.messages)
        finally:
            head.pipeline.match = match
            release.set()
        assert await wait_for(lambda: listener.count("WATCHDOG", start=marks["release"]) >= 2, 10.0)

    await run_with_notify(tmp_path, listener, scenario)
    stuck = listener.messages[marks["stuck"]]["STATUS"]
    assert "STUCK front: no result for" in stuck and "watchdog withheld" in stuck
    assert listener.count("WATCHDOG", marks["stuck"], marks["release"]) == 0
    assert listener.count("WATCHDOG", start=marks["release"]) >= 2
    last_status = [m["STATUS"] for m in listener.messages[marks["release"] :] if "STATUS" in m][-2]
    assert "STUCK" not in last_status  # (the last is "stopping")


class WedgedCamera:
    """A real source whose read stops returning after a few frames, until released."""

    def __init__(self, inner: Any, release: threading.Event) -> None:
        self._inner = inner
        self._release = release
        self.reads = 0

    @property
    def description(self) -> str:
        return "wedged camera"

    def read(self) -> StereoFrame:
        self.reads += 1
        if self.reads == 20:
            self._release.wait(30.0)
        frame: StereoFrame = self._inner.read()
        return frame

    def close(self) -> None:
        self._inner.close()


async def test_a_source_read_that_never_returns_stops_the_watchdog(
    tmp_path: Path, notify_socket: NotifySocket
) -> None:
    listener = notify_socket
    release = threading.Event()
    cameras: list[WedgedCamera] = []
    marks: dict[str, int] = {}

    def wedging_open(*args: Any, **kwargs: Any) -> Any:
        cameras.append(WedgedCamera(real_open_source(*args, **kwargs), release))
        return cameras[-1]

    async def scenario(daemon: Daemon) -> None:
        try:
            found = await wait_for(
                lambda: listener.index("STATUS", "source read blocked") is not None, 20.0
            )
            assert found, listener.messages
            marks["stuck"] = listener.index("STATUS", "source read blocked") or 0
            await asyncio.sleep(1.5)  # three ping periods
            marks["release"] = len(listener.messages)
        finally:
            release.set()
        assert await wait_for(lambda: listener.count("WATCHDOG", start=marks["release"]) >= 2, 10.0)

    await run_with_notify(tmp_path, listener, scenario, open_source=wedging_open)
    assert listener.index("READY") is not None
    assert listener.count("WATCHDOG", marks["stuck"], marks["release"]) == 0
    assert len(cameras) == 1  # the camera was not reopened: it recovered by itself


async def test_a_missing_camera_still_gets_ready_and_pings_after_the_timeout(
    tmp_path: Path, notify_socket: NotifySocket
) -> None:
    listener = notify_socket

    def no_camera(*args: Any, **kwargs: Any) -> Any:
        raise SourceError("camera 'front': /dev/video0 does not exist; is it plugged in?")

    async def scenario(daemon: Daemon) -> None:
        assert await wait_for(lambda: listener.count("WATCHDOG") >= 2, 20.0)

    service = SERVICE | {"ready_timeout_s": 1.0}
    await run_with_notify(tmp_path, listener, scenario, open_source=no_camera, service=service)
    ready = listener.index("READY")
    assert ready is not None
    assert "waiting for front (no frame yet)" in listener.messages[ready]["STATUS"]


def test_the_demo_daemon_as_a_process_on_an_abstract_socket(tmp_path: Path) -> None:
    config = tmp_path / "demo.yaml"
    calibration = REPO / "config" / "calibration" / "synthetic-640x480.yaml"
    config.write_text(
        (REPO / "config" / "demo.yaml")
        .read_text()
        .replace("calibration: calibration/synthetic-640x480.yaml", f"calibration: {calibration}")
        .replace("udpout:127.0.0.1:14550", f"udpout:127.0.0.1:{free_udp_port()}")
    )
    address = f"@avoidd-test-{uuid.uuid4().hex}"
    env = dict(os.environ, NOTIFY_SOCKET=address, WATCHDOG_USEC="1000000")
    env.pop("WATCHDOG_PID", None)
    with NotifySocket(address) as listener:
        log = (tmp_path / "daemon.log").open("w")
        daemon = subprocess.Popen(
            [sys.executable, "-m", "avoidd", "run", "--config", str(config)],
            cwd=REPO,
            env=env,
            stdout=log,
            stderr=subprocess.STDOUT,
        )
        try:
            listener.collect_for(30.0, lambda: listener.count("WATCHDOG") >= 2)
        finally:
            daemon.send_signal(signal.SIGTERM)
            code = daemon.wait(timeout=30)
        listener.collect_for(2.0, lambda: listener.index("STOPPING") is not None)
    output = (tmp_path / "daemon.log").read_text()
    assert code == 0, output[-2000:]
    ready = listener.index("READY")
    assert ready is not None, output[-2000:]
    assert listener.count("WATCHDOG", start=ready) >= 2
    assert listener.messages[-1] == {"STOPPING": "1", "STATUS": "stopping"}
    assert "ready after" in output and "Traceback" not in output
