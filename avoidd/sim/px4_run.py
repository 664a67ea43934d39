"""A scenario flown by a real PX4 SITL (SIH physics), with avoidd's camera rendered from its pose.

The same flight as :class:`~avoidd.sim.external.ExternalRun` does with ArduPilot, the PX4 way.
A ground station on PX4's GCS link keeps neutral sticks (MANUAL_CONTROL at 20 Hz from a thread
of its own, as a pilot's joystick: PX4's Position mode needs manual control), waits for the
estimator, arms and takes off (``MAV_CMD_NAV_TAKEOFF`` to ``MIS_TAKEOFF_ALT``), then either

- ``planner``: gives avoidd the goal (``DO_REPOSITION`` addressed to avoidd's component 196:
  PX4 routes it to the onboard link and avoidd's COMMAND_ACK back), waits for avoidd's
  hold-here prestream, switches to OFFBOARD and lets avoidd fly there; at the end it switches
  to Position mode (the pilot takes over) and counts the setpoints avoidd still sends; or
- ``push``: with avoidd's planner off, switches to Position mode and pushes full forward stick
  (``x = 1000``), so that only PX4's collision prevention (``CP_DIST``, fed by avoidd's
  OBSTACLE_DISTANCE) stops the vehicle short of the wall (its guidance off: ``CP_GUIDE_ANG``
  0, so the stick's direction is kept).

PX4's SIH vehicle starts at its local origin facing north: scenarios must start at heading 0.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import logging
import math
import time
from pathlib import Path

from avoidd.config.sim import ScenarioConfig
from avoidd.config.sources import SourceConfig
from avoidd.daemon import Daemon
from avoidd.errors import LinkError
from avoidd.mavlink import codec as mav
from avoidd.sim.external import (
    ExternalRun,
    ExternalSummary,
    Mode,
    daemon_config,
    fly_while_running,
)
from avoidd.sim.gcs import GroundStation, StickStream
from avoidd.sim.pose_source import (
    PoseRenderedSource,
    UnpluggableSource,
    VehiclePose,
    vehicle_pose,
)
from avoidd.sim.px4 import ONBOARD_PORT, Px4Sitl
from avoidd.sources.base import FrameSource
from avoidd.types import RectifiedRig
from avoidd.vision.calibration import Calibration

logger = logging.getLogger(__name__)

_STICK_RATE_HZ = 20.0
_TAKEN_OFF = 0.8
"""Share of the take-off height (MIS_TAKEOFF_ALT, the goal's) that counts as taken off."""
_FACING_DEG = 3.0
"""Push: the nose is north within this many degrees before the stick goes forward."""
_YAW_STICK_DEAD = 120.0
"""Yaw stick just past PX4's dead zone (``MPC_HOLD_DZ`` 0.1 of full stick: 100)."""
_YAW_STICK_MAX = 300.0


class Px4Run(ExternalRun):
    """One scenario against a real PX4 SITL.

    Args:
        scenario: The scenario (its world, goal, duration, pass criteria; heading 0).
        binary_dir: Folder with ``bin/px4`` and ``etc/``.
        mode: ``planner`` (avoidd flies in OFFBOARD) or ``push`` (full stick in Position mode,
            PX4's collision prevention stops the vehicle on avoidd's data).
        cp_dist_m: PX4's ``CP_DIST`` for the flight (None: avoidd.params').
        params: Further PX4 parameters set at boot.
        release_s: Planner: seconds after the goal is reached (or the duration ends) before the
            ground station switches to Position mode; None: no switch.
    """

    def __init__(
        self,
        scenario: ScenarioConfig,
        binary_dir: Path,
        mode: Mode = "planner",
        cp_dist_m: float | None = None,
        params: dict[str, float] | None = None,
        release_s: float | None = 2.0,
    ) -> None:
        super().__init__(scenario, binary_dir, mode=mode)
        if abs(self.scenario.start.yaw_deg) > 1e-6:
            raise LinkError(
                f"scenario {self.scenario.name}: PX4's SIH vehicle starts facing north; "
                "give start.yaw_deg 0"
            )
        self.params = dict(params or {})
        if cp_dist_m is not None:
            self.params["CP_DIST"] = cp_dist_m
        self.params.setdefault("MIS_TAKEOFF_ALT", self.goal[2])
        if mode == "push":
            # The push measures the stop: PX4's guidance (CP_GUIDE_ANG, 30 degrees by default)
            # steers the stick's direction up to that far toward freer bins, and a push that
            # began 0.6 m east of the wall's middle saw past its end 28 degrees right, slid
            # along it and flew round (a loaded CI run). Straight at the wall, as a pilot
            # holding the stick expects to be stopped.
            self.params.setdefault("CP_GUIDE_ANG", 0.0)
        self.release_s = release_s
        self._stick_x = 0
        self.sticks: StickStream | None = None
        """The ground station's stick stream while a run is on."""
        self.offboard_s: float | None = None
        """Seconds from the OFFBOARD request until avoidd saw OFFBOARD (planner)."""
        self.setpoints_after_release: int | None = None
        """Setpoints avoidd sent from one cycle after it saw Position mode until 2 s later."""
        self.estimator_s = 0.0
        self.heading_before_push_deg: float | None = None
        """Push: the vehicle's heading before it was turned north (degrees)."""
        self.start_moved_m: float | None = None
        """Push: how far from the start PX4's estimate had the vehicle before the push."""
        self._plugged = [True]
        unsupported = [a.action for a in scenario.timeline if not a.action.startswith("camera_")]
        if unsupported:
            raise LinkError(
                f"scenario {scenario.name}: a PX4 run plays camera_unplug and camera_replug "
                f"from its timeline, not {', '.join(sorted(set(unsupported)))}; remove them"
            )

    async def run(self, port: int = ONBOARD_PORT) -> ExternalSummary:
        """Start PX4 and avoidd, fly the scenario, stop everything; the summary.

        Args:
            port: Ignored: PX4's onboard link sends to UDP 14540, avoidd listens there.

        Raises:
            LinkError: PX4 did not start, or would not arm, take off or engage OFFBOARD.
        """
        sitl = Px4Sitl(self.binary_dir, extra_params=self.params)
        config = daemon_config(ONBOARD_PORT, self.scenario, self.mode == "planner")
        daemon = Daemon(
            config, {"front": Calibration(self.rig, None, Path("sim"))}, open_source=self._camera
        )
        self.daemon = daemon
        task: asyncio.Task[int] | None = None
        ended: BaseException | None = None
        try:
            gcs = await sitl.start(timeout_s=30.0)
            self.gcs = gcs
            task = asyncio.create_task(daemon.run(), name="avoidd")
            self.sticks = gcs.sticks(_STICK_RATE_HZ, forward=self._stick_x)
            await fly_while_running(self._fly_px4(gcs, sitl), task)
        except BaseException as exc:
            ended = exc
            raise
        finally:
            try:
                if self.sticks is not None:
                    self.sticks.stop()
                    logger.info(
                        "sticks: %d MANUAL_CONTROL sent, longest gap %.2f s",
                        self.sticks.sent,
                        self.sticks.longest_gap_s,
                    )
            finally:
                await self._end(daemon, task, sitl, ended)
        self._judge()
        return self.summary

    def _camera(
        self,
        config: SourceConfig,
        rig: RectifiedRig,
        head: str,
        paced: bool,
        input_path: Path | None = None,
    ) -> FrameSource:
        """The head's source: the world from the reported pose, heights above home.

        PX4's local origin is where its estimator started, up to 2 m above or below the ground
        here; HOME_POSITION (set at arming, on the ground) says where the ground is.
        """
        daemon = self.daemon
        assert daemon is not None
        renderer = self._lent_renderer(rig)
        local = vehicle_pose(daemon.vehicle)

        def pose(t_ns: int) -> VehiclePose | None:
            found = local(t_ns)
            if found is None:
                return None
            # The offset as it stands now (read once: a push moves the world to where the
            # vehicle is, and one frame must not mix the old and the new).
            offset_north_m, offset_east_m = self.offset_ne_m
            north_m = found.north_m + offset_north_m
            east_m = found.east_m + offset_east_m
            down_m = found.down_m + (daemon.vehicle.home_up_m or 0.0)
            return dataclasses.replace(found, north_m=north_m, east_m=east_m, down_m=down_m)

        camera = PoseRenderedSource(renderer, pose, self.scenario.fps)
        return UnpluggableSource(camera, self._plugged)

    @property
    def stick_x(self) -> int:
        """Forward stick the ground station sends (-1000..1000), throttle centred."""
        return self._stick_x

    @stick_x.setter
    def stick_x(self, value: int) -> None:
        self._stick_x = value
        if self.sticks is not None:
            self.sticks.forward = value

    async def _fly_px4(self, gcs: GroundStation, sitl: Px4Sitl) -> None:
        self.estimator_s = await sitl.wait_estimator(120.0)
        await self._wait_ready(60.0)
        # Taken off: most of the way to MIS_TAKEOFF_ALT above home. Not LOCAL_POSITION_NED's
        # height: the estimator's origin sits up to 2 m off the ground here (its height drifts
        # while it settles).
        await sitl.take_off(_TAKEN_OFF * float(self.params["MIS_TAKEOFF_ALT"]))
        assert self.daemon is not None
        self.home_up_m = self.daemon.vehicle.home_up_m or 0.0
        if self.mode == "planner":
            await self._give_goal(gcs)
            await self._engage_offboard(gcs)
            self._t0_ns = time.monotonic_ns()
            await self._watch_until_goal(gcs, self.scenario.duration_s)
            if self.release_s is not None:
                await self._watch(gcs, self.release_s, push=False, reset=False)
                await self._release(gcs)
        else:
            # PX4's merged obstacle map, as it streams it back (36 bins of 10 degrees).
            await gcs.request_message_interval("OBSTACLE_DISTANCE", 5.0)
            if await gcs.set_mode("px4", "POSCTL") != mav.MAV_RESULT_ACCEPTED:
                raise LinkError("PX4 refused Position mode")
            await self._wait_mode("POSCTL", 10.0)
            await self._face_north(20.0)
            await self._anchor_start()
            self._t0_ns = time.monotonic_ns()
            self.stick_x = 1000
            timeline = asyncio.create_task(self._camera_timeline(), name="timeline")
            try:
                await self._watch(gcs, self.scenario.duration_s, push=False)
            finally:
                timeline.cancel()
            self.stick_x = 0

    async def _face_north(self, timeout_s: float) -> None:
        """Turn with the yaw stick until the nose points north, where the push goes.

        The vehicle starts facing north, but has been seen facing 45 degrees off by the push
        (on a loaded machine: full stick then flew past the wall's end). A pilot lines up first.
        """
        daemon = self.daemon
        sticks = self.sticks
        assert daemon is not None and sticks is not None
        deadline = time.monotonic() + timeout_s
        steady_since: float | None = None
        yaw_deg = math.nan
        try:
            while time.monotonic() < deadline:
                attitude = daemon.vehicle.attitude.newest()
                if attitude is None:
                    await asyncio.sleep(0.1)
                    continue
                yaw_deg = math.degrees(attitude.yaw_rad)
                if self.heading_before_push_deg is None:
                    self.heading_before_push_deg = yaw_deg
                    logger.info("push: heading %.1f degrees before lining up", yaw_deg)
                if abs(yaw_deg) <= _FACING_DEG:
                    steady_since = steady_since or time.monotonic()
                    if time.monotonic() - steady_since >= 0.5:
                        return
                else:
                    steady_since = None
                # Past PX4's stick dead zone (MPC_HOLD_DZ, 10 % of the stick) and then
                # proportional, at most 30 %; centred within the band: PX4 holds the heading.
                if abs(yaw_deg) <= _FACING_DEG:
                    sticks.yaw = 0
                else:
                    deflection = min(_YAW_STICK_MAX, _YAW_STICK_DEAD + 10.0 * abs(yaw_deg))
                    sticks.yaw = round(-math.copysign(deflection, yaw_deg))
                await asyncio.sleep(0.05)
        finally:
            sticks.yaw = 0
        raise LinkError(f"PX4 did not turn north within {timeout_s:.0f} s (heading {yaw_deg:.0f})")

    async def _anchor_start(self) -> None:
        """Put the scenario's start where PX4's estimate has the vehicle now, before a push.

        The world is placed in PX4's own frame (its estimate: what it flies on and reports),
        with its local origin at the scenario's start. On a loaded machine the estimate
        wandered while the vehicle took off and hovered (the push began 5.9 m west of the
        wall's centre and flew past its end): a push straight ahead must start in front of
        the wall, as a pilot lines up before pushing. The camera renders the moved world from
        the next frame on; one second of frames lets avoidd's readings catch up.
        """
        daemon = self.daemon
        assert daemon is not None
        position = daemon.vehicle.position
        if position is None:
            raise LinkError("no LOCAL_POSITION_NED from PX4 before the push")
        start = self.scenario.start
        moved_m = math.hypot(
            position.north_m + self.offset_ne_m[0] - start.north_m,
            position.east_m + self.offset_ne_m[1] - start.east_m,
        )
        self.offset_ne_m = (start.north_m - position.north_m, start.east_m - position.east_m)
        self.start_moved_m = moved_m
        logger.info(
            "push: PX4's estimate has the vehicle %.2f m from the start; the world moves there",
            moved_m,
        )
        await asyncio.sleep(1.0)

    async def _camera_timeline(self) -> None:
        """The scenario's camera actions, at their times from the start of the push."""
        for action in sorted(self.scenario.timeline, key=lambda a: a.time_s):
            wait_s = action.time_s - (time.monotonic_ns() - self._t0_ns) / 1e9
            if wait_s > 0:
                await asyncio.sleep(wait_s)
            self._plugged[0] = action.action == "camera_replug"
            logger.info("scenario: %s at %.1f s", action.action.replace("_", " "), action.t_s)

    async def _wait_ready(self, timeout_s: float) -> None:
        """Until avoidd sends fresh proximity data (its camera needs the pose PX4 reports)."""
        daemon = self.daemon
        assert daemon is not None
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            sent = daemon.sent["OBSTACLE_DISTANCE"]
            await asyncio.sleep(1.0)
            if daemon.sent["OBSTACLE_DISTANCE"] >= sent + 5:
                return
        raise LinkError(f"avoidd sent no proximity data within {timeout_s:.0f} s")

    async def _wait_mode(self, name: str, timeout_s: float) -> float:
        """Until avoidd's link decodes PX4's mode as ``name``; seconds waited."""
        daemon = self.daemon
        assert daemon is not None
        start = time.monotonic()
        while time.monotonic() - start < timeout_s:
            mode = daemon.vehicle.mode
            if mode is not None and mode.name == name:
                return time.monotonic() - start
            await asyncio.sleep(0.02)
        mode = daemon.vehicle.mode
        raise LinkError(f"PX4 not in {name} within {timeout_s:.0f} s (in {mode and mode.name})")

    async def _engage_offboard(self, gcs: GroundStation) -> None:
        """Wait for avoidd's prestream (> 1 s of it), then ask for OFFBOARD until PX4 is in it."""
        daemon = self.daemon
        assert daemon is not None
        loop = daemon.avoidance
        assert loop is not None
        deadline = time.monotonic() + 20.0
        while loop.state != "prestream":
            if time.monotonic() > deadline:
                raise LinkError(f"avoidd did not prestream (state {loop.state})")
            await asyncio.sleep(0.1)
        await asyncio.sleep(1.5)
        start = time.monotonic()
        for _ in range(5):
            result = await gcs.set_mode("px4", "OFFBOARD")
            if result == mav.MAV_RESULT_ACCEPTED:
                with contextlib.suppress(LinkError):
                    await self._wait_mode("OFFBOARD", 5.0)
                    self.offboard_s = time.monotonic() - start
                    return
            await asyncio.sleep(1.0)
        said = [m.text for m in gcs.of_type("STATUSTEXT")][-5:]
        raise LinkError(f"PX4 did not engage OFFBOARD (it said {said})")

    async def _watch_until_goal(self, gcs: GroundStation, duration_s: float) -> None:
        """Sample until the goal is reached or the duration ends."""
        deadline_ns = self._t0_ns + int(duration_s * 1e9)
        while time.monotonic_ns() < deadline_ns and self.summary.reached_s is None:
            position = await gcs.next_message(lambda m: m.get_type() == "LOCAL_POSITION_NED", 1.0)
            if position is not None and gcs.from_autopilot(position):
                self._measure(position)

    async def _watch(
        self, gcs: GroundStation, duration_s: float, push: bool, reset: bool = True
    ) -> None:
        """Sample for ``duration_s`` (from the flight's start, or from now with ``reset`` off)."""
        if reset:
            await super()._watch(gcs, duration_s, push)
            return
        deadline_ns = time.monotonic_ns() + int(duration_s * 1e9)
        while time.monotonic_ns() < deadline_ns:
            position = await gcs.next_message(lambda m: m.get_type() == "LOCAL_POSITION_NED", 1.0)
            if position is not None and gcs.from_autopilot(position):
                self._measure(position)

    async def _release(self, gcs: GroundStation) -> None:
        """The pilot takes over: Position mode; count avoidd's setpoints after one cycle."""
        daemon = self.daemon
        assert daemon is not None
        if await gcs.set_mode("px4", "POSCTL") != mav.MAV_RESULT_ACCEPTED:
            self.summary.failures.append("PX4 refused Position mode after the flight")
            return
        await self._wait_mode("POSCTL", 5.0)
        loop = daemon.avoidance
        assert loop is not None
        await asyncio.sleep(1.5 / loop.config.setpoint_rate_hz)  # the cycle under way may send
        before = loop.sent
        await asyncio.sleep(2.0)
        self.setpoints_after_release = loop.sent - before
