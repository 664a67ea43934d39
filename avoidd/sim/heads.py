"""The simulated stereo heads of a lockstep run: each its mount, rig, scans in flight, latest.

A scenario's ``cameras`` become heads. Each captures at the scenario's frame rate (rendered
and run through the daemon's pipeline, or measured exactly with ``oracle`` perception), its
scan reaching avoidd a fixed latency later; a head can be unplugged and plugged back on its
own. What avoidd has each cycle is the daemon's merge (:func:`~avoidd.perception.sectors.
merge_scans`) of the heads whose newest scan is fresh: the nearest reading per bin, unknown
where no fresh head sees.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from avoidd.config.sim import CameraConfig
from avoidd.perception.sectors import covered_bins, merge_scans
from avoidd.sim.vehicle import VehicleState
from avoidd.types import Mount, RectifiedRig, SectorScan

Perceive = Callable[[VehicleState, int], SectorScan]
"""Produces a head's (filtered) scan for the vehicle's state at a capture time."""

RIGS = {
    "320x240": RectifiedRig(320, 240, 200.0, 200.0, 159.5, 119.5, 0.12),
    "640x480": RectifiedRig(640, 480, 400.0, 400.0, 319.5, 239.5, 0.12),
}
"""The simulated head's rectified rig (a 77 degree field of view, 12 cm baseline)."""


def rig_for(resolution: str, hfov_deg: float | None) -> RectifiedRig:
    """The rig of a resolution, with the focal length for a field of view (None: the rig's)."""
    rig = RIGS[resolution]
    if hfov_deg is None:
        return rig
    focal_px = rig.cx / math.tan(math.radians(hfov_deg) / 2.0)
    return RectifiedRig(rig.width, rig.height, focal_px, focal_px, rig.cx, rig.cy, rig.baseline_m)


def mount_of(camera: CameraConfig) -> Mount:
    """Where a camera sits and looks."""
    return Mount(camera.yaw_deg, camera.pitch_deg, camera.roll_deg, camera.position_m)


@dataclass
class SimHead:
    """One head in the loop.

    Attributes:
        name: Its name.
        rig: Its rectified rig.
        mount: Its mount.
        perceive: Makes its scan.
        on: Plugged in (it captures).
        pending: Scans captured, with the time they reach avoidd and the yaw at capture.
        latest: The newest scan avoidd has from it, with the yaw at its capture.
    """

    name: str
    rig: RectifiedRig
    mount: Mount
    perceive: Perceive
    on: bool = True
    pending: list[tuple[int, SectorScan, float]] = field(default_factory=list)
    latest: tuple[SectorScan, float] | None = None

    covered: npt.NDArray[np.bool_] = field(init=False)
    """The bins it sees."""

    def __post_init__(self) -> None:
        self.covered = covered_bins(self.rig, self.mount)

    def capture(self, state: VehicleState, now_ns: int, latency_ns: int) -> None:
        """A frame now, if plugged in: its scan reaches avoidd ``latency_ns`` later."""
        if self.on:
            self.pending.append((now_ns + latency_ns, self.perceive(state, now_ns), state.yaw_rad))

    def deliver(self, now_ns: int) -> None:
        """The scans that have reached avoidd by now (the newest one is kept)."""
        while self.pending and self.pending[0][0] <= now_ns:
            _, scan, yaw_then = self.pending.pop(0)
            self.latest = (scan, yaw_then)


def fresh_merged(
    heads: list[SimHead], now_ns: int, max_age_ns: int
) -> tuple[SectorScan, float] | None:
    """The fresh heads' newest scans merged, with the yaw at the newest capture (None: none)."""
    fresh = [
        head.latest
        for head in heads
        if head.latest is not None and now_ns - head.latest[0].t_capture_ns <= max_age_ns
    ]
    if not fresh:
        return None
    newest = max(fresh, key=lambda latest: latest[0].t_capture_ns)
    return merge_scans([scan for scan, _ in fresh]), newest[1]
