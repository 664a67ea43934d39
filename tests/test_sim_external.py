"""The external-SITL runners: a failed flight's window, the renderer they lend, their clean-up."""

from __future__ import annotations

import asyncio
import itertools
import os
import signal
from pathlib import Path
from typing import ClassVar

import pytest

from avoidd.config.sim import load_scenario
from avoidd.daemon import Daemon
from avoidd.errors import LinkError, SourceError
from avoidd.sim.external import (
    ExternalRun,
    Sample,
    fly_while_running,
    window_around_minimum,
)
from avoidd.sim.lockstep import RIGS
from avoidd.sim.px4_run import Px4Run
from tests.helpers import REPO, free_udp_port


def _flight() -> list[Sample]:
    # 20 Hz for 20 s; the edge comes nearest (0.3 m) at 12 s.
    samples = []
    for i in range(400):
        t_s = i / 20.0
        samples.append(
            Sample(t_s, t_s, 0.0, 2.5, 1.0, 0.3 + abs(t_s - 12.0), (1.0, 0.0), "moving", (1.2, 0.0))
        )
    return samples


def test_the_window_holds_the_closest_approach_and_its_seconds_around_thinned() -> None:
    window = window_around_minimum(_flight(), 2.0)
    times = [s.t_s for s in window]
    assert min(window, key=lambda s: s.clearance_m).clearance_m == 0.3
    assert 12.0 in times
    assert times[0] >= 10.0 and times[-1] <= 14.0
    assert times[0] <= 10.2 and times[-1] >= 13.8  # the whole 4 s, not a part
    assert all(b - a >= 0.2 - 1e-9 for a, b in itertools.pairwise(times) if b != 12.0)
    assert 18 <= len(window) <= 22  # 5 a second, not 20
    assert window_around_minimum([], 2.0) == []


def test_a_sample_describes_where_how_fast_and_what_the_planner_wanted() -> None:
    line = _flight()[240].describe()
    assert "12.0 s" in line and "edge  0.30" in line
    assert "v +1.00 +0.00" in line and "set +1.20 +0.00" in line and "moving" in line
    bare = Sample(1.0, 0.0, 0.0, 2.5, 0.0, 3.0).describe()
    assert "set" not in bare and "None" in bare
    assert "track" not in bare and "side" not in bare
    seen = Sample(
        1.0, 0.0, 0.0, 2.5, 0.0, 0.6, (0.0, 0.3), "stale", (-0.3, 0.0), None, (0.42, 0.31), -4.4
    ).describe()
    assert "track +0.42 +0.31" in seen and "near side -4 deg" in seen


async def _daemon(stop_after_s: float, code: int = 0) -> int:
    await asyncio.sleep(stop_after_s)
    return code


async def test_a_flight_ends_at_once_when_avoidd_stops_and_says_so() -> None:
    ended: list[str] = []

    async def flight() -> None:
        try:
            await asyncio.sleep(30.0)  # waiting for data that would never come
        except asyncio.CancelledError:
            ended.append("cancelled")
            raise

    daemon = asyncio.create_task(_daemon(0.05, code=0))
    with pytest.raises(LinkError, match="avoidd stopped during the run \\(exit code 0\\)"):
        await asyncio.wait_for(fly_while_running(flight(), daemon), 5.0)
    assert ended == ["cancelled"]


async def test_a_flight_that_ends_first_returns_or_raises_its_own_failure() -> None:
    daemon = asyncio.create_task(_daemon(30.0))
    try:
        await fly_while_running(asyncio.sleep(0.01), daemon)
        assert not daemon.done()  # avoidd is left running: the run stops it

        async def failing() -> None:
            raise LinkError("SITL refused GUIDED")

        with pytest.raises(LinkError, match="refused GUIDED"):
            await fly_while_running(failing(), daemon)
    finally:
        daemon.cancel()
        await asyncio.gather(daemon, return_exceptions=True)


def test_a_run_lends_one_renderer_and_replaces_it_once_broken(tmp_path: Path) -> None:
    run = ExternalRun(load_scenario(REPO / "sitl" / "ardupilot" / "wall-around.yaml"), tmp_path)
    rig = RIGS["320x240"]
    try:
        first = run._lent_renderer(rig)
        left, _ = first.render_pair((0.0, 0.0, -2.0, 0.0, 0.0, 0.0))
        assert left.shape == (240, 320)
        renderer = run._renderer
        assert renderer is not None
        first.close()  # a source closed (the camera unplugged): the renderer runs on
        again = run._lent_renderer(rig)
        assert run._renderer is renderer and not renderer.broken
        os.kill(renderer.pid, signal.SIGKILL)  # the child died
        with pytest.raises(SourceError):
            again.render_pair((0.0, 0.0, -2.0, 0.0, 0.0, 0.0))
        # The head reopens its camera after the loss: a new renderer.
        run._lent_renderer(rig).render_pair((1.0, 0.0, -2.0, 0.0, 0.0, 0.0))
        assert run._renderer is not None and run._renderer.pid != renderer.pid
        replacement = run._renderer
    finally:
        run._close_renderer()
    assert run._renderer is None and replacement.broken


class _Sitl:
    """The autopilot's edge: a SITL that starts at once and counts its stops."""

    made: ClassVar[list[_Sitl]] = []

    def __init__(self, *args: object, **kwargs: object) -> None:
        self.stops = 0
        _Sitl.made.append(self)

    async def start(self, timeout_s: float = 30.0) -> _Gcs:
        return _Gcs()

    async def stop(self) -> None:
        self.stops += 1


class _Gcs:
    sent = 0
    longest_gap_s = 0.0

    def sticks(self, *args: object, **kwargs: object) -> _Gcs:
        return self

    def stop(self) -> None:
        pass


@pytest.mark.parametrize("autopilot", ["ardupilot", "px4"])
async def test_sitl_stops_even_when_the_daemons_stop_is_cancelled(
    autopilot: str, monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """A flight fails and the daemon's stop is then cancelled (a test's timeout): the camera's
    renderer and the SITL process still stop, so no process keeps the autopilot's ports."""
    real_stop = Daemon.stop_and_wait

    async def stop_then_cancelled(
        self: Daemon, task: asyncio.Task[int], timeout_s: float = 30.0
    ) -> int | None:
        await real_stop(self, task, timeout_s)
        raise asyncio.CancelledError

    async def flight_fails(*args: object) -> None:
        raise LinkError("the vehicle would not arm")

    monkeypatch.setattr(Daemon, "stop_and_wait", stop_then_cancelled)
    _Sitl.made.clear()
    run: ExternalRun
    if autopilot == "px4":
        monkeypatch.setattr("avoidd.sim.px4_run.Px4Sitl", _Sitl)
        run = Px4Run(load_scenario(REPO / "sitl" / "px4" / "wall-around.yaml"), tmp_path)
        monkeypatch.setattr(run, "_fly_px4", flight_fails)
    else:
        monkeypatch.setattr("avoidd.sim.external.ArduPilotSitl", _Sitl)
        run = ExternalRun(load_scenario(REPO / "sitl" / "ardupilot" / "wall-around.yaml"), tmp_path)
        monkeypatch.setattr(run, "_fly", flight_fails)
    run._lent_renderer(RIGS["320x240"])  # the camera's renderer is running
    with pytest.raises(asyncio.CancelledError):
        await run.run(free_udp_port() if autopilot == "ardupilot" else 14540)
    assert [sitl.stops for sitl in _Sitl.made] == [1]
    assert run._renderer is None
