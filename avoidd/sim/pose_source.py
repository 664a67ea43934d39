"""A head's camera in an external simulation: the world rendered from the autopilot's pose.

A SITL autopilot (ArduPilot, PX4) simulates its own vehicle; avoidd hears its pose as
LOCAL_POSITION_NED and ATTITUDE like any autopilot's. :class:`PoseRenderedSource` is a frame
source that renders what a head would see from that pose, in real time, so the daemon runs
unchanged (its own link, pipeline and outputs) with a simulated camera in place of a real one.
The pose comes from a callable (the daemon's :class:`~avoidd.mavlink.vehicle.Vehicle` in
practice), so the source itself knows nothing of MAVLink.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

from avoidd.config.sim import load_world
from avoidd.config.sources import SimSourceConfig
from avoidd.errors import BrokenFrame, SourceError
from avoidd.mavlink.vehicle import Vehicle
from avoidd.sim.render_process import PairRenderer, RenderProcess
from avoidd.sim.world import World
from avoidd.sources.base import FrameSource, Pacer
from avoidd.types import FramePose, Mount, RectifiedRig, StereoFrame


@dataclass(frozen=True)
class VehiclePose:
    """Where the vehicle is, in the world's frame (local NED, metres; attitude as ATTITUDE).

    Attributes:
        north_m: Position north of the world's origin.
        east_m: Position east of it.
        down_m: Position down (negative in the air).
        yaw_rad: Heading, clockwise from north.
        roll_rad: Roll, right side down positive.
        pitch_rad: Pitch, nose up positive.
    """

    north_m: float
    east_m: float
    down_m: float
    yaw_rad: float
    roll_rad: float
    pitch_rad: float


PoseNow = Callable[[int], VehiclePose | None]
"""The vehicle's pose at a monotonic time in ns, or None when it is not known."""


def vehicle_pose(
    vehicle: Vehicle,
    offset_ne_m: tuple[float, float] = (0.0, 0.0),
    max_age_ns: int = 500_000_000,
) -> PoseNow:
    """A pose callable over what the daemon hears from the autopilot: its newest reports.

    The newest ATTITUDE and LOCAL_POSITION_NED, not the ones at the frame's time on the
    autopilot's clock: a SITL's boot clock does not keep pace with the wall clock while it starts
    (its simulation waits for a ground station), so mapped times lag for a while, and what an
    external simulation's camera sees is the vehicle's latest state anyway.

    Args:
        vehicle: The daemon's view of the autopilot (LOCAL_POSITION_NED and ATTITUDE).
        offset_ne_m: The world position of the autopilot's local origin (a scenario that
            starts elsewhere than the world's origin).
        max_age_ns: A position received longer ago than this is not a pose (the autopilot
            went quiet).

    Returns:
        The callable; None until both a position and an attitude have been heard.
    """

    def pose_at(t_ns: int) -> VehiclePose | None:
        position = vehicle.position
        attitude = vehicle.attitude.newest()
        if position is None or attitude is None:
            return None
        age_ns = t_ns - vehicle.position_received_ns
        if age_ns > max_age_ns:
            return None
        # Carry the position forward to the frame's time with the reported velocity.
        dt_s = max(0.0, age_ns / 1e9)
        return VehiclePose(
            position.north_m + position.vn_m_s * dt_s + offset_ne_m[0],
            position.east_m + position.ve_m_s * dt_s + offset_ne_m[1],
            position.down_m + position.vd_m_s * dt_s,
            attitude.yaw_rad,
            attitude.roll_rad,
            attitude.pitch_rad,
        )

    return pose_at


class PoseRenderedSource:
    """Frames rendered from the vehicle's reported pose, paced at ``fps``.

    Args:
        renderer: The head's renderer (its world, rig, mount and noise), in a process of its
            own in practice (:class:`~avoidd.sim.render_process.RenderProcess`); closed with
            the source.
        pose_at: The vehicle's pose at a time.
        fps: Frames per second.
        wait_s: How long a read waits for a pose before it gives up on that frame (no pose:
            nothing to render, and an image from a made-up pose would be a lie).
    """

    def __init__(
        self,
        renderer: PairRenderer,
        pose_at: PoseNow,
        fps: float,
        wait_s: float = 0.5,
    ) -> None:
        self._renderer = renderer
        self._pose_at = pose_at
        self._pacer = Pacer(fps)
        self._wait_ns = int(wait_s * 1e9)
        self._seq = 0

    @property
    def description(self) -> str:
        """What the source renders, for logs."""
        return "the simulated world from the autopilot's pose"

    def read(self) -> StereoFrame:
        """Render the next frame from the pose at its capture time.

        Raises:
            BrokenFrame: No pose came within ``wait_s`` (the autopilot is silent or has no
                position yet): this frame is dropped and counted, as an unreadable one is, and
                a run of them is a lost camera.
        """
        t_capture_ns = self._pacer.wait()
        deadline_ns = t_capture_ns + self._wait_ns
        pose = self._pose_at(t_capture_ns)
        while pose is None:
            if time.monotonic_ns() > deadline_ns:
                raise BrokenFrame("no pose from the autopilot (LOCAL_POSITION_NED and ATTITUDE)")
            time.sleep(0.05)
            t_capture_ns = time.monotonic_ns()
            pose = self._pose_at(t_capture_ns)
        left, right = self._renderer.render_pair(
            (
                pose.north_m,
                pose.east_m,
                pose.down_m,
                pose.yaw_rad,
                math.degrees(pose.roll_rad),
                math.degrees(pose.pitch_rad),
            )
        )
        # Like a real camera's, the frame carries no attitude: the daemon takes the autopilot's
        # at the capture time. It carries the height it was rendered at, which the daemon
        # prefers to a rangefinder: a SITL's rangefinder measures its physics' truth, and the
        # autopilot's estimate (the rendered pose) drifts from that truth (PX4 SIH: by 0.5 to
        # 1.5 m in 15 s; the rendered ground then stood above the rangefinder's ground plane,
        # an obstacle 2 m ahead, and PX4's collision prevention would not let the vehicle fly).
        height = FramePose(math.nan, math.nan, max(-pose.down_m, 0.0), "mavlink", "simulator")
        frame = StereoFrame(self._seq, t_capture_ns, left, right, None, height)
        self._seq += 1
        return frame

    def close(self) -> None:
        """Stop the renderer."""
        self._renderer.close()


def open_sim_source(
    config: SimSourceConfig, rig: RectifiedRig, mount: Mount, vehicle: Vehicle
) -> PoseRenderedSource:
    """A head's ``kind: sim`` source: its world rendered from the autopilot's reported pose.

    Args:
        config: The head's source section.
        rig: The head's rectified rig (``doffs`` 0: the renderer's model).
        mount: The head's mount.
        vehicle: The daemon's view of the autopilot.

    Raises:
        SourceError: The rig has a ``doffs`` the renderer cannot draw.
    """
    if rig.doffs_px != 0.0:
        raise SourceError("a sim source renders rigs with doffs 0; use a rectified calibration")
    world = World.from_config(load_world(config.world))
    renderer = RenderProcess(world, rig, mount, config.noise_std, seed=world.seed)
    pose_at = vehicle_pose(vehicle, config.origin_ne_m)
    return PoseRenderedSource(renderer, pose_at, config.fps)


class UnpluggableSource:
    """A frame source that fails while a scenario has the camera unplugged.

    Args:
        source: The camera.
        plugged: One flag, shared with the scenario's timeline (False: unplugged).
    """

    def __init__(self, source: FrameSource, plugged: list[bool]) -> None:
        self._source = source
        self._plugged = plugged

    @property
    def description(self) -> str:
        """The camera's description."""
        return self._source.description

    def read(self) -> StereoFrame:
        """The camera's next frame; SourceError while unplugged."""
        if not self._plugged[0]:
            time.sleep(0.1)
            raise SourceError("camera unplugged (scenario timeline)")
        return self._source.read()

    def close(self) -> None:
        """Close the camera."""
        self._source.close()
