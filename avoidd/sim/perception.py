"""Simulated perception: what avoidd's own head pipeline makes of the rendered views.

Each frame is rendered from the vehicle's state at its capture time
(:class:`~avoidd.sim.render.StereoRenderer`), run through :class:`~avoidd.pipeline.HeadPipeline`
with the frame's attitude and height, and through the head's temporal
:class:`~avoidd.perception.temporal.SectorFilter`: the scan the planner gets is the one the
daemon would send.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from avoidd.config import HeadConfig, PerceptionConfig
from avoidd.perception.temporal import SectorFilter
from avoidd.pipeline import HeadPipeline
from avoidd.sim.render import StereoRenderer
from avoidd.sim.vehicle import VehicleState
from avoidd.sim.world import World
from avoidd.types import FramePose, Mount, RectifiedRig, SectorScan, StereoFrame
from avoidd.vision.calibration import Calibration

SIM_HEAD: dict[str, Any] = {
    "name": "front",
    # Validated as an existing file, never read: the simulator hands the rig over.
    "calibration": __file__,
    "source": {"kind": "synthetic"},
    "matcher": {"kind": "sgbm", "num_disparities": 32, "block_size": 5, "mode": "sgbm_3way"},
    "postprocess": {"subpixel_refine": False, "median_size": 5},
    "sectors": {"min_pixels": 20},
}
"""The simulated head: the demo configuration's matcher and filters."""


class StereoPerception:
    """Renders a head's views from the vehicle state and runs the daemon's pipeline on them.

    Args:
        world: The world.
        rig: The head's rectified rig.
        mount: The head's mount.
        max_range_m: Readings beyond this are clear.
        seed: Seed of the sensor noise.
        perception: Perception settings (default: the daemon's defaults).
    """

    def __init__(
        self,
        world: World,
        rig: RectifiedRig,
        mount: Mount,
        max_range_m: float,
        seed: int,
        perception: PerceptionConfig | None = None,
    ) -> None:
        head = HeadConfig.model_validate(
            SIM_HEAD
            | {
                "mount": {
                    "yaw_deg": mount.yaw_deg,
                    "pitch_deg": mount.pitch_deg,
                    "roll_deg": mount.roll_deg,
                    "position_m": list(mount.position_m),
                }
            }
        )
        self.perception = perception or PerceptionConfig()
        self.renderer = StereoRenderer(world, rig, mount)
        self.pipeline = HeadPipeline(
            head, Calibration(rig, None, Path("sim")), max_range_m, self.perception
        )
        self.filter = SectorFilter(self.perception.temporal)
        self._rng = np.random.default_rng(seed)
        self._seq = 0

    def __call__(self, state: VehicleState, t_capture_ns: int) -> SectorScan:
        """The head's filtered scan of a frame captured now from this state."""
        north, east, down = (float(v) for v in state.position_m)
        roll_rad, pitch_rad = state.roll_pitch_rad()
        roll_deg, pitch_deg = math.degrees(roll_rad), math.degrees(pitch_rad)
        pair = self.renderer.render(
            north, east, down, state.yaw_rad, roll_deg, pitch_deg, self._rng, t_capture_ns / 1e9
        )
        pose = FramePose(roll_deg, pitch_deg, max(-down, 0.0), "simulator", "simulator")
        frame = StereoFrame(self._seq, t_capture_ns, pair.left, pair.right, None, pose)
        self._seq += 1
        result = self.pipeline.process(frame, pose)
        return self.filter.update(result.scan)
