"""A scenario flown by a real ArduCopter SITL, with avoidd's camera rendered from its pose.

The autopilot simulates the vehicle; avoidd runs as the daemon does on a drone (its own UDP
link to the autopilot's SERIAL1, its pipeline, its outputs, its planner), with one head whose
frames are rendered from the pose the autopilot reports
(:class:`~avoidd.sim.pose_source.PoseRenderedSource`). A ground station on the autopilot's own
port flies the scenario: GUIDED, arm, take off, then either

- ``planner``: gives avoidd the scenario's goal (``DO_REPOSITION`` addressed to avoidd's
  component, routed by ArduPilot) and lets avoidd fly it there; or
- ``push``: with avoidd's planner off, pushes the vehicle towards the goal with velocity
  setpoints of its own, so that only ArduPilot's simple avoidance, fed by avoidd's
  OBSTACLE_DISTANCE, stops it (``AVOID_MARGIN``).

The ground station samples the vehicle's position throughout and measures it against the world:
collisions, clearance, the closest approach, the goal. The world's origin is the scenario's
start: the autopilot's home, where it takes off (its local origin), is the scenario's start,
heading as the scenario says; positions are shifted by the start to compare with the world.
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections.abc import Coroutine
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, Protocol

from avoidd.config import AppConfig
from avoidd.config.sim import GeneratedWorldConfig, ScenarioConfig, load_world
from avoidd.config.sources import SourceConfig
from avoidd.daemon import Daemon
from avoidd.errors import LinkError
from avoidd.mavlink import codec as mav
from avoidd.mavlink.geo import offset_lat_lon
from avoidd.sim.ardupilot import ArduPilotSitl
from avoidd.sim.gcs import GroundStation
from avoidd.sim.generators import generate
from avoidd.sim.lockstep import MAX_RANGE_M, RIGS
from avoidd.sim.perception import SIM_HEAD
from avoidd.sim.pose_source import PoseRenderedSource, vehicle_pose
from avoidd.sim.render_process import LentRenderer, RenderProcess
from avoidd.sim.world import World
from avoidd.sources.base import FrameSource
from avoidd.types import Mount, RectifiedRig
from avoidd.vision.calibration import Calibration

logger = logging.getLogger(__name__)

HOME = (-35.363261, 149.165230, 584.0)
"""Latitude, longitude and altitude (m AMSL) of the SITL's home (the scenario's start)."""

Mode = Literal["planner", "push"]

_NAV_TAKEOFF = 22
"""MAV_CMD_NAV_TAKEOFF (param 7: the altitude)."""
_SAID_KEPT = 12
"""The autopilot's last STATUSTEXTs kept in a run's summary."""
_VELOCITY_AND_YAW = 0x09C7
"""SET_POSITION_TARGET type mask: velocity and yaw angle (no position, acceleration, yaw rate).

The push holds the heading the scenario starts with: with velocity alone ArduPilot turns the
nose towards the direction of travel, so when its avoidance backs the vehicle away from the wall
the single forward camera turns away from it, the wall falls into bins nothing measures, and
the next push meets it unseen (observed)."""


async def fly_while_running(flight: Coroutine[Any, Any, None], daemon: asyncio.Task[int]) -> None:
    """Fly, unless avoidd stops first: then the flight ends at once.

    avoidd stops on SIGINT or SIGTERM (an operator's Ctrl-C reaches it first) or when it
    fails; a run flying on without it would only wait for data that never comes.

    Args:
        flight: The flight to fly.
        daemon: avoidd's task.

    Raises:
        LinkError: avoidd stopped before the flight ended.
    """
    flying = asyncio.ensure_future(flight)
    try:
        await asyncio.wait({flying, daemon}, return_when=asyncio.FIRST_COMPLETED)
    except BaseException:
        flying.cancel()
        await asyncio.gather(flying, return_exceptions=True)
        raise
    if flying.done():
        flying.result()  # the flight's own end: done, or its failure
        return
    flying.cancel()
    await asyncio.gather(flying, return_exceptions=True)
    if daemon.cancelled():
        how = "cancelled"
    elif daemon.exception() is not None:
        how = f"failed: {daemon.exception()!r}"
    else:
        how = f"exit code {daemon.result()}"
    raise LinkError(f"avoidd stopped during the run ({how}); the flight was ended")


@dataclass
class Sample:
    """One position report of the flight, measured against the world.

    Attributes:
        t_s: Seconds since the scenario's flight began (after take-off).
        north_m: Position north of the world's origin.
        east_m: Position east.
        altitude_m: Height above home.
        speed_m_s: Horizontal speed.
        clearance_m: Distance from the vehicle's edge to the nearest obstacle.
        velocity_ne_m_s: The vehicle's horizontal velocity (north, east).
        state: avoidd's planner state then (None without a planner decision).
        setpoint_ne_m_s: The planner's horizontal velocity setpoint then.
        free_m: The planner's free distance along its chosen direction then.
        track_ne_m_s: The velocity the autopilot's positions showed then, as the planner saw
            it (:mod:`avoidd.planner.track`; None: too few positions).
        near_side_deg: The bearing of the side remembered obstacles near the vehicle were
            on then (:meth:`avoidd.planner.core.Planner.near_side_rad`; None: none near).
    """

    t_s: float
    north_m: float
    east_m: float
    altitude_m: float
    speed_m_s: float
    clearance_m: float
    velocity_ne_m_s: tuple[float, float] = (0.0, 0.0)
    state: str | None = None
    setpoint_ne_m_s: tuple[float, float] | None = None
    free_m: float | None = None
    track_ne_m_s: tuple[float, float] | None = None
    near_side_deg: float | None = None

    def describe(self) -> str:
        """The sample in one line (for a failure's message)."""
        where = f"{self.t_s:5.1f} s N{self.north_m:6.2f} E{self.east_m:6.2f}"
        moving = "v {:+.2f} {:+.2f}".format(*self.velocity_ne_m_s)
        setpoint = (
            ""
            if self.setpoint_ne_m_s is None
            else " set {:+.2f} {:+.2f}".format(*self.setpoint_ne_m_s)
        )
        free = "" if self.free_m is None else f" free {self.free_m:.2f}"
        track = (
            "" if self.track_ne_m_s is None else " track {:+.2f} {:+.2f}".format(*self.track_ne_m_s)
        )
        side = "" if self.near_side_deg is None else f" near side {self.near_side_deg:.0f} deg"
        return (
            f"{where} edge {self.clearance_m:5.2f} {moving}{track}{setpoint} {self.state}{free}"
            f"{side}"
        )


def window_around_minimum(samples: list[Sample], seconds: float) -> list[Sample]:
    """The samples within ``seconds`` of the one with the least clearance, at most 5 a second.

    Args:
        samples: A flight's samples, in time order.
        seconds: How far before and after the minimum to keep.

    Returns:
        The thinned window (empty for no samples).
    """
    if not samples:
        return []
    nearest = min(samples, key=lambda s: s.clearance_m)
    kept: list[Sample] = []
    for sample in samples:
        if abs(sample.t_s - nearest.t_s) <= seconds and (
            not kept or sample.t_s - kept[-1].t_s >= 0.2 - 1e-6 or sample is nearest
        ):
            kept.append(sample)
    return kept


@dataclass
class ExternalSummary:
    """What a flight showed.

    Attributes:
        scenario: The scenario's name.
        mode: ``planner`` or ``push``.
        collided: The vehicle's edge touched an obstacle.
        min_clearance_m: The smallest edge clearance.
        reached_s: When the goal was reached (None: never).
        final_ne_m: Where the vehicle ended.
        flight_s: Seconds flown after take-off.
        samples: Position reports measured.
        passed: The scenario's criteria held.
        failures: Why not.
        states: avoidd's avoidance state changes, ``"<s> <state>"`` with seconds from the
            start of the flight (negative: before it).
        autopilot_said: The autopilot's last STATUSTEXTs to the ground station.
    """

    scenario: str
    mode: Mode
    collided: bool = False
    min_clearance_m: float = math.inf
    reached_s: float | None = None
    final_ne_m: tuple[float, float] = (0.0, 0.0)
    flight_s: float = 0.0
    samples: list[Sample] = field(default_factory=list)
    passed: bool = False
    failures: list[str] = field(default_factory=list)
    states: list[str] = field(default_factory=list)
    autopilot_said: list[str] = field(default_factory=list)

    def as_json(self) -> dict[str, Any]:
        """The summary without the samples, for printing."""
        return {
            "scenario": self.scenario,
            "mode": self.mode,
            "collided": self.collided,
            "min_clearance_m": round(self.min_clearance_m, 3),
            "reached_s": None if self.reached_s is None else round(self.reached_s, 1),
            "final_ne_m": [round(v, 2) for v in self.final_ne_m],
            "flight_s": round(self.flight_s, 1),
            "samples": len(self.samples),
            "passed": self.passed,
            "failures": self.failures,
            "states": self.states,
            "autopilot_said": self.autopilot_said,
        }


def scenario_world(scenario: ScenarioConfig) -> tuple[World, tuple[float, float, float]]:
    """The scenario's world and goal (north, east, altitude), generated if need be."""
    if isinstance(scenario.world, GeneratedWorldConfig):
        clearance_m = scenario.avoidance.vehicle_radius_m + scenario.avoidance.margin_m
        config, goal = generate(scenario.world, clearance_m)
        goal = scenario.goal or goal
    else:
        config = load_world(scenario.world)
        assert scenario.goal is not None  # required with a world file
        goal = scenario.goal
    return World.from_config(config), (goal.north_m, goal.east_m, goal.altitude_m)


def daemon_config(
    port: int,
    scenario: ScenarioConfig,
    planner: bool,
    goal: tuple[float, float, float] | None = None,
) -> AppConfig:
    """The daemon's configuration for the flight: one simulated head, ``udpin`` on ``port``.

    Args:
        port: avoidd's UDP port on 127.0.0.1.
        scenario: The scenario (its camera rate and planner settings).
        planner: Whether avoidd flies (``avoidance.enabled``).
        goal: A goal (north, east, altitude in the autopilot's local frame) from the start.
    """
    avoidance = scenario.avoidance.model_dump(exclude={"goal", "params_file"})
    avoidance["enabled"] = planner
    if goal is not None:
        avoidance["goal"] = {"north_m": goal[0], "east_m": goal[1], "altitude_m": goal[2]}
    return AppConfig.model_validate(
        {
            "version": 1,
            "heads": [SIM_HEAD | {"source": {"kind": "synthetic", "fps": scenario.fps}}],
            "mavlink": {
                "connection": f"udpin:127.0.0.1:{port}",
                "obstacle_distance": {"max_distance_cm": round(MAX_RANGE_M * 100)},
            },
            # One frame at a time on one thread (the least CPU): the SITL and the camera's
            # renderer share the machine, and at the scenarios' 8 fps overlapping the
            # stages buys no frame rate but two threads that contend for the cores (with two
            # busy processes beside it: frame age p99 250-290 ms against 300-400 ms).
            "pipeline": {"max_age_ms": 300, "log_interval_s": 5.0, "threads": 1},
            "avoidance": avoidance,
        }
    )


class Stoppable(Protocol):
    """A SITL process the run ends (ArduPilot's or PX4's)."""

    async def stop(self) -> None:
        """End the process and release what it holds."""


class ExternalRun:
    """One scenario against a real ArduCopter SITL.

    Args:
        scenario: The scenario (its world, start heading, goal, duration, pass criteria).
        binary_dir: Folder with ``arducopter`` and ``copter.parm``.
        mode: ``planner`` (avoidd flies) or ``push`` (the ground station pushes, ArduPilot
            avoids on avoidd's data).
        push_speed_m_s: Speed of the push.
        avoid_margin_m: ArduPilot's ``AVOID_MARGIN`` for the flight (None: the parameter
            file's).

    The autopilot runs in real time (speedup 1): avoidd takes a boot clock that falls behind
    its own for an autopilot reboot, as it must with a real one.
    """

    def __init__(
        self,
        scenario: ScenarioConfig,
        binary_dir: Path,
        mode: Mode = "planner",
        push_speed_m_s: float = 2.0,
        avoid_margin_m: float | None = None,
    ) -> None:
        self.scenario = scenario
        self.binary_dir = binary_dir
        self.mode = mode
        self.push_speed_m_s = push_speed_m_s
        self.avoid_margin_m = avoid_margin_m
        self.world, self.goal = scenario_world(scenario)
        self.offset_ne_m = (scenario.start.north_m, scenario.start.east_m)
        """The world position of the autopilot's local origin: the scenario's start, until a
        PX4 push moves the world to where PX4's estimate has the vehicle after lining up
        (:meth:`~avoidd.sim.px4_run.Px4Run._anchor_start`)."""
        self.rig: RectifiedRig = RIGS[scenario.resolution]
        self.radius_m = scenario.avoidance.vehicle_radius_m
        self.home_up_m = 0.0
        """Height of the ground under the start above the autopilot's local origin (PX4's
        origin can sit up to 2 m off the ground: its height drifts while it settles)."""
        self.daemon: Daemon | None = None
        self.gcs: GroundStation | None = None
        """The ground station of the run (what it heard stays readable after the run)."""
        self.summary = ExternalSummary(scenario.name, mode)
        self._t0_ns = 0
        self._renderer: RenderProcess | None = None
        """The camera's renderer: one process for the run, lent to every source the head
        opens (an unplugged camera comes back without a new process)."""

    async def run(self, port: int) -> ExternalSummary:
        """Start SITL and avoidd, fly the scenario, stop everything; the summary.

        Args:
            port: A free UDP port on 127.0.0.1 for avoidd's link.

        Raises:
            LinkError: SITL did not start, or the vehicle would not arm or take off.
        """
        start = self.scenario.start
        home = f"{HOME[0]},{HOME[1]},{HOME[2]},{start.yaw_deg % 360.0:g}"
        sitl = ArduPilotSitl(self.binary_dir, port, home=home)
        config = daemon_config(port, self.scenario, self.mode == "planner")
        rig = self.rig
        daemon = Daemon(
            config, {"front": Calibration(rig, None, Path("sim"))}, open_source=self._camera
        )
        self.daemon = daemon
        task: asyncio.Task[int] | None = None
        ended: BaseException | None = None
        try:
            gcs = await sitl.start(timeout_s=60.0)
            self.gcs = gcs
            task = asyncio.create_task(daemon.run(), name="avoidd")
            await fly_while_running(self._fly(gcs), task)
        except BaseException as exc:
            ended = exc
            raise
        finally:
            await self._end(daemon, task, sitl, ended)
        self._judge()
        return self.summary

    async def _end(
        self,
        daemon: Daemon,
        task: asyncio.Task[int] | None,
        sitl: Stoppable,
        ended: BaseException | None,
    ) -> None:
        """Stop avoidd, the camera's renderer and SITL, SITL whatever happens before.

        A stop that is cancelled (a test's timeout) or a wind-up that fails must not leave the
        SITL process running: it would keep the autopilot's ports from the next run.
        """
        try:
            try:
                if task is not None:
                    await daemon.stop_and_wait(task)
            finally:
                await asyncio.to_thread(self._close_renderer)
            self._wind_up(ended)
        finally:
            await sitl.stop()

    def _camera(
        self,
        config: SourceConfig,
        rig: RectifiedRig,
        head: str,
        paced: bool,
        input_path: Path | None = None,
    ) -> FrameSource:
        """The head's source (the daemon's ``open_source``): the world from the reported pose."""
        assert self.daemon is not None
        pose = vehicle_pose(self.daemon.vehicle, self.offset_ne_m)
        return PoseRenderedSource(self._lent_renderer(rig), pose, self.scenario.fps)

    def _lent_renderer(self, rig: RectifiedRig) -> LentRenderer:
        """The run's renderer, lent to a source; started on first use, and again when broken.

        A renderer that failed (its child gone or late) is replaced: the head reopens its
        camera after a loss, as it would a real one. One head per run: the rig is the first
        caller's.
        """
        if self._renderer is not None and self._renderer.broken:
            self._renderer.close()
            self._renderer = None
        if self._renderer is None:
            self._renderer = RenderProcess(self.world, rig, Mount(), seed=self.world.seed)
        return LentRenderer(self._renderer)

    def _close_renderer(self) -> None:
        """Stop the run's renderer process, if one started."""
        renderer, self._renderer = self._renderer, None
        if renderer is not None:
            renderer.close()

    async def _fly(self, gcs: GroundStation) -> None:
        await gcs.request_message_interval("LOCAL_POSITION_NED", 10.0)
        if self.avoid_margin_m is not None:
            await gcs.set_param("AVOID_MARGIN", self.avoid_margin_m)
        altitude_m = self.goal[2]
        await self._wait_ready(90.0)
        if await gcs.set_mode("ardupilot", "GUIDED") != mav.MAV_RESULT_ACCEPTED:
            raise LinkError("SITL refused GUIDED")
        if not await gcs.arm(retry_s=90.0):
            raise LinkError("SITL would not arm within 90 s")
        await self._take_off(gcs, altitude_m)
        await self._wait_altitude(gcs, altitude_m - 0.3, 30.0)
        self._t0_ns = time.monotonic_ns()
        if self.mode == "planner":
            await self._give_goal(gcs)
            await self._watch(gcs, self.scenario.duration_s, push=False)
        else:
            await self._watch(gcs, self.scenario.duration_s, push=True)

    async def _wait_ready(self, timeout_s: float) -> None:
        """Until the autopilot has a position and avoidd sends fresh proximity data.

        ArduPilot refuses to arm with "PRX1: No Data" until OBSTACLE_DISTANCE flows, and avoidd
        sends it only once its camera sees (here: once the autopilot reports a pose).
        """
        daemon = self.daemon
        assert daemon is not None
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            sent = daemon.sent["OBSTACLE_DISTANCE"]
            await asyncio.sleep(1.0)
            if daemon.vehicle.origin is not None and daemon.sent["OBSTACLE_DISTANCE"] >= sent + 5:
                return
        raise LinkError(f"avoidd sent no proximity data within {timeout_s:.0f} s")

    async def _take_off(self, gcs: GroundStation, altitude_m: float) -> None:
        """NAV_TAKEOFF until accepted (just after arming it may be refused for a moment)."""
        deadline = time.monotonic() + 20.0
        result: int | None = None
        while time.monotonic() < deadline:
            result = await gcs.command(_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, altitude_m)
            if result == mav.MAV_RESULT_ACCEPTED:
                return
            await asyncio.sleep(1.0)
        said = [m.text for m in gcs.of_type("STATUSTEXT")][-5:]
        raise LinkError(f"SITL refused to take off (MAV_RESULT {result}; it said {said})")

    async def _wait_altitude(self, gcs: GroundStation, altitude_m: float, timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            position = await gcs.next_message(lambda m: m.get_type() == "LOCAL_POSITION_NED", 1.0)
            if position is not None and -position.z >= altitude_m:
                return
        raise LinkError(f"SITL did not climb to {altitude_m:.1f} m within {timeout_s:.0f} s")

    async def _give_goal(self, gcs: GroundStation) -> None:
        """DO_REPOSITION to avoidd's component, through ArduPilot's routing, until accepted."""
        daemon = self.daemon
        assert daemon is not None
        deadline = time.monotonic() + 60.0
        while daemon.vehicle.origin is None:  # avoidd asks for it until it has it
            if time.monotonic() > deadline:
                raise LinkError("avoidd never heard the autopilot's origin")
            await asyncio.sleep(0.5)
        origin = daemon.vehicle.origin
        north_m, east_m, altitude_m = self.goal
        lat_deg, lon_deg = offset_lat_lon(
            origin, north_m - self.offset_ne_m[0], east_m - self.offset_ne_m[1]
        )
        frame = mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
        for _ in range(10):
            ack = asyncio.ensure_future(
                gcs.next_message(
                    lambda m: (
                        m.get_type() == "COMMAND_ACK"
                        and m.get_srcComponent() == mav.MAV_COMP_ID_OBSTACLE_AVOIDANCE
                        and m.command == mav.MAV_CMD_DO_REPOSITION
                    ),
                    1.0,
                )
            )
            await asyncio.sleep(0)
            to = (daemon.vehicle.system_id, mav.MAV_COMP_ID_OBSTACLE_AVOIDANCE)
            where = (round(lat_deg * 1e7), round(lon_deg * 1e7), altitude_m)
            command = (frame, mav.MAV_CMD_DO_REPOSITION, 0, 0, -1.0, 0, 0, math.nan, *where)
            gcs.send(gcs.codec.build("COMMAND_INT", *to, *command))
            answer = await ack
            if answer is not None and answer.result == mav.MAV_RESULT_ACCEPTED:
                logger.info("avoidd took the goal N%.1f E%.1f", north_m, east_m)
                return
            logger.warning(
                "goal not taken: %s",
                "no answer" if answer is None else f"refused (MAV_RESULT {answer.result})",
            )
            await asyncio.sleep(1.0)
        raise LinkError("avoidd did not accept the goal")

    async def _watch(self, gcs: GroundStation, duration_s: float, push: bool) -> None:
        """Sample the flight until the duration ends (pushing towards the goal if asked)."""
        deadline_ns = self._t0_ns + int(duration_s * 1e9)
        north_goal, east_goal, _ = self.goal
        while time.monotonic_ns() < deadline_ns:
            position = await gcs.next_message(lambda m: m.get_type() == "LOCAL_POSITION_NED", 1.0)
            if position is None:
                continue
            sample = self._measure(position)
            if push:
                self._push(gcs, sample, north_goal, east_goal)

    def _measure(self, position: Any) -> Sample:
        north_m = float(position.x) + self.offset_ne_m[0]
        east_m = float(position.y) + self.offset_ne_m[1]
        altitude_m = -float(position.z) - self.home_up_m
        edge_m = self.world.edge_clearance_m(north_m, east_m, altitude_m, self.radius_m)
        loop = self.daemon.avoidance if self.daemon is not None else None
        decision = loop.last_decision if loop is not None else None
        pose = loop.last_pose if loop is not None else None
        track = None if pose is None else pose.track_ne_m_s
        side_rad = None if pose is None or loop is None else loop.planner.near_side_rad(pose)
        sample = Sample(
            (time.monotonic_ns() - self._t0_ns) / 1e9,
            north_m,
            east_m,
            altitude_m,
            math.hypot(float(position.vx), float(position.vy)),
            edge_m,
            (float(position.vx), float(position.vy)),
            None if decision is None else decision.state,
            None if decision is None else decision.velocity_ned[:2],
            None if decision is None else decision.free_m,
            None if track is None else (round(track[0], 3), round(track[1], 3)),
            None if side_rad is None else round(math.degrees(side_rad), 1),
        )
        summary = self.summary
        summary.samples.append(sample)
        summary.min_clearance_m = min(summary.min_clearance_m, edge_m)
        summary.collided = summary.collided or edge_m <= 0.0
        summary.final_ne_m = (north_m, east_m)
        summary.flight_s = sample.t_s
        north_goal, east_goal, _ = self.goal
        near_goal = math.hypot(north_goal - north_m, east_goal - east_m)
        if summary.reached_s is None and near_goal <= self.scenario.avoidance.acceptance_radius_m:
            summary.reached_s = sample.t_s
        return sample

    def _push(
        self, gcs: GroundStation, sample: Sample, north_goal: float, east_goal: float
    ) -> None:
        """A velocity setpoint towards the goal at the push speed, heading held."""
        dn, de = north_goal - sample.north_m, east_goal - sample.east_m
        distance = math.hypot(dn, de)
        speed = min(self.push_speed_m_s, distance)
        vn, ve = (dn / distance * speed, de / distance * speed) if distance > 0.1 else (0.0, 0.0)
        assert self.daemon is not None
        yaw_rad = math.radians(self.scenario.start.yaw_deg)
        velocity = (vn, ve, 0.0, 0.0, 0.0, 0.0, yaw_rad, 0.0)
        target = (0, self.daemon.vehicle.system_id, 1, mav.MAV_FRAME_LOCAL_NED, _VELOCITY_AND_YAW)
        gcs.send(gcs.codec.build("SET_POSITION_TARGET_LOCAL_NED", *target, 0, 0, 0, *velocity))

    def _record_what_was_said(self) -> None:
        """Keep avoidd's state changes and the autopilot's last words, for a failure's message."""
        summary = self.summary
        loop = self.daemon.avoidance if self.daemon is not None else None
        if loop is not None:
            summary.states = [
                f"{(t_ns - self._t0_ns) / 1e9:.1f} {state}" if self._t0_ns else state
                for t_ns, state in loop.history
            ]
        if self.gcs is not None:
            said = self.gcs.of_type("STATUSTEXT")[-_SAID_KEPT:]
            summary.autopilot_said = [str(m.text) for m in said]

    def _wind_up(self, ended: BaseException | None) -> None:
        """Keep what was said; for a run that raised, also log it (its summary is not read)."""
        self._record_what_was_said()
        if ended is not None:
            logger.warning(
                "the run ended early (%s); avoidd's states %s; the autopilot said %s",
                ended,
                self.summary.states,
                self.summary.autopilot_said,
            )

    def _judge(self) -> None:
        summary = self.summary
        criteria = self.scenario.passing
        if not summary.samples:
            summary.failures.append("no position reports after take-off")
        if criteria.no_collision and summary.collided:
            summary.failures.append(f"collision (min clearance {summary.min_clearance_m:.2f} m)")
        if criteria.min_clearance_m is not None and summary.samples:
            edges = sorted(s.clearance_m for s in summary.samples)
            p1 = edges[int(0.01 * (len(edges) - 1))]
            if p1 < criteria.min_clearance_m:
                summary.failures.append(
                    f"clearance {p1:.2f} m below {criteria.min_clearance_m:.2f} m"
                )
        if criteria.reach_goal_s is not None and (
            summary.reached_s is None or summary.reached_s > criteria.reach_goal_s
        ):
            summary.failures.append(f"goal not reached within {criteria.reach_goal_s:.0f} s")
        if criteria.closest_approach_m is not None and summary.samples:
            low, high = criteria.closest_approach_m
            if not low <= summary.min_clearance_m <= high:
                summary.failures.append(
                    f"closest approach {summary.min_clearance_m:.2f} m outside {low}..{high} m"
                )
        summary.passed = not summary.failures
