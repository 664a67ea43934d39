"""What surrounds the vehicle this cycle: one query of the memory, asked every question of a cycle.

A :class:`Surroundings` is built once per planning cycle from the obstacle memory (the
remembered points relative to the vehicle, and their distances) and the grid of what the
cameras have looked at; every stage of the cycle (direction, speed, corrections, search,
view) asks it how far each heading is free and which side what is near lies on.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from avoidd.planner.geometry import free_distance, wrap_rad
from avoidd.planner.memory import ObstacleMemory
from avoidd.planner.tuning import Tuning
from avoidd.planner.types import Pose
from avoidd.planner.visibility import VisibilityGrid

Array = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Surroundings:
    """The obstacles around the vehicle and what has been seen, from one pose.

    Attributes:
        pose: The vehicle's state.
        offsets: (N, 2) remembered obstacle points relative to the vehicle (north, east).
        ranges_m: (N,) their distances.
        clearance_m: Vehicle radius plus margin.
        radius_m: Vehicle radius.
        visibility: What the cameras have looked at; None when unknown ground counts free.
        look_m: How far ahead unseen ground matters (a stop from full speed and a metre).
        seen_since_ns: Ground looked at since then counts as seen.
        tuning: The planner's constants.
    """

    pose: Pose
    offsets: Array
    ranges_m: Array
    clearance_m: float
    radius_m: float
    visibility: VisibilityGrid | None
    look_m: float
    seen_since_ns: int
    tuning: Tuning

    @classmethod
    def around(
        cls,
        pose: Pose,
        memory: ObstacleMemory,
        visibility: VisibilityGrid | None,
        clearance_m: float,
        radius_m: float,
        look_m: float,
        memory_s: float,
        tuning: Tuning,
    ) -> Surroundings:
        """The surroundings of ``pose`` (one query of the memory)."""
        offsets, ranges_m = memory.near((pose.north_m, pose.east_m))
        since_ns = pose.t_ns - int(memory_s * 1e9)
        return cls(
            pose, offsets, ranges_m, clearance_m, radius_m, visibility, look_m, since_ns, tuning
        )

    @property
    def depth_inside_m(self) -> float:
        """How far the vehicle is inside the clearance of its nearest point (<= 0: outside)."""
        return self.clearance_m - float(np.min(self.ranges_m)) if self.offsets.size else 0.0

    def side_within(self, within_m: float) -> float | None:
        """The bearing (radians) of the side the points nearer than ``within_m`` are on.

        The points are weighted by how far in they are; None when none is that near, or when
        they surround the vehicle evenly (a corridor narrower than that).
        """
        ranges_m = self.ranges_m
        within = ranges_m < within_m
        if not within.any():
            return None
        depth = (within_m - ranges_m[within]) / ranges_m[within]
        push = (depth[:, None] * self.offsets[within]).sum(axis=0)
        if float(np.hypot(*push)) < self.tuning.one_sided * float(depth.sum() * np.min(ranges_m)):
            return None
        return math.atan2(float(push[1]), float(push[0]))

    def near_side_rad(self) -> float | None:
        """The bearing of the side remembered obstacles near the vehicle are on.

        Near: within the clearance plus ``drift_band_m``, all on one side (None when there
        are none, or they surround the vehicle as a narrow corridor's walls do).
        """
        if not self.offsets.size:
            return None
        return self.side_within(self.clearance_m + self.tuning.drift_band_m)

    def obstacle_free_m(self, headings_rad: Array, buffer_m: float | Array = 0.0) -> Array:
        """Free distance along each heading among the remembered obstacles only.

        Where the vehicle's disc (radius, margin and ``buffer_m``) would meet a remembered
        obstacle point.
        """
        offsets = self.offsets
        clearance = self.clearance_m + buffer_m
        if not offsets.size:
            return free_distance(offsets, headings_rad, clearance)
        # Already nearer than that to something (pushed by wind, stopped at a wall with the
        # overshoot of stereo, or the buffer is wider than the corridor): keep at least the
        # distance there is, so that the ways along or away from it stay open.
        nearest_m = float(np.min(self.ranges_m))
        inside = max(nearest_m - self.tuning.inside_slack_m, self.radius_m)
        free = free_distance(offsets, headings_rad, np.minimum(clearance, inside))
        # That alone lets the vehicle creep in a few centimetres a cycle along a slant (each
        # cycle's nearest point is the new limit): the ways toward what is within the
        # clearance close, toward the side it is on as a whole (a wall's points within the
        # clearance, weighted by how far in; none when they surround the vehicle evenly, as a
        # corridor narrower than the clearance does).
        toward = self.side_within(self.clearance_m)
        if toward is not None:
            closer = np.abs(wrap_rad(headings_rad - toward)) < math.radians(self.tuning.toward_deg)
            free = np.where(closer, 0.0, free)
        return free

    def free_m(self, headings_rad: Array, buffer_m: float | Array = 0.0) -> Array:
        """Free distance along each heading (``buffer_m``: one, or one each).

        The nearer of :meth:`obstacle_free_m` and, with unknown directions blocked, where the
        vehicle's corridor reaches ground the cameras have not looked at within the memory
        time (beside the vehicle the corridor is as wide as the vehicle, widening to the
        clearance ahead: see :mod:`avoidd.planner.visibility`).
        """
        free = self.obstacle_free_m(headings_rad, buffer_m)
        if self.visibility is not None:
            # The corridor must have been seen as wide as the vehicle keeps from obstacles (the
            # turning buffer is about following a path past known ones).
            pose = self.pose
            seen = self.visibility.seen_distance(
                (pose.north_m, pose.east_m),
                headings_rad,
                self.clearance_m,
                self.look_m,
                self.seen_since_ns,
                self.radius_m,
            )
            free = np.minimum(free, seen)
        return free
