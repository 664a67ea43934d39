"""Obstacle memory in the local frame: what the cameras saw, kept while it is out of view.

Each fresh scan adds its readings as points in the autopilot's local frame (north, east), placed
with the vehicle's position and yaw at the scan's capture time, each at the bearing of the
point its bin measured when the scan carries one (else where in the bin the neighbours say,
:func:`surface_shift_rad`). A reading that later sees past
a remembered point (a nearer measurement, or clear, in the same direction) removes it; points
older than the memory time are dropped. Free space is never remembered: a direction nobody
measured now is unknown, whatever it was.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from avoidd.planner.geometry import wrap_rad
from avoidd.types import SECTOR_COUNT, SECTOR_WIDTH_DEG

Array = npt.NDArray[np.float64]

_CELL_M = 0.1
"""Remembered points are kept one per cell of this size."""
_SEE_PAST_M = 0.3
"""A remembered point is gone only when a new reading sees this far beyond it."""
_HALF_BIN_RAD = float(np.radians(SECTOR_WIDTH_DEG / 2.0))
_SURFACE_RATIO = 2.0
"""Readings of neighbouring bins at most this far apart (as a ratio) may be one surface."""


@dataclass
class ObstacleMemory:
    """Remembered obstacle points.

    Args:
        memory_s: How long a point is kept after it was last measured.
        max_points: At most this many points (the oldest go first).
    """

    memory_s: float
    max_points: int = 4000
    north_east: Array = field(default_factory=lambda: np.empty((0, 2)))
    t_ns: npt.NDArray[np.int64] = field(default_factory=lambda: np.empty(0, dtype=np.int64))
    _near: tuple[Array, tuple[float, float], Array, Array] | None = field(
        default=None, init=False, repr=False, compare=False
    )

    def clear(self) -> None:
        """Forget everything."""
        self.north_east = np.empty((0, 2))
        self.t_ns = np.empty(0, dtype=np.int64)

    def add_scan(
        self,
        distance_m: npt.NDArray[np.floating],
        t_capture_ns: int,
        north_east_m: tuple[float, float],
        yaw_rad: float,
        max_range_m: float,
        points_frd_m: npt.NDArray[np.floating] | None = None,
    ) -> None:
        """Take one scan (body bins: 72 distances, NaN unknown, ``inf`` clear).

        Args:
            distance_m: The scan's distances.
            t_capture_ns: Its capture time.
            north_east_m: Vehicle position at capture.
            yaw_rad: Vehicle yaw at capture.
            max_range_m: Range that counts as seen through for a clear bin.
            points_frd_m: (72, 3) the body point each finite bin measured (NaN elsewhere), or
                None. A bin's reading is placed at its point's bearing: a bin is 5 degrees
                wide, 0.65 m at 15 m, and a wall's end placed in the middle of the bin that
                holds it narrows the gap beside it by that much (a 3.3 m gap looked 2.9 m
                wide, too narrow to fly, and the edge stays out of a forward view on the way
                in, so nothing corrected it).
        """
        origin = np.asarray(north_east_m, dtype=np.float64)
        distance = np.asarray(distance_m, dtype=np.float64)
        bearing = yaw_rad + np.radians(np.arange(SECTOR_COUNT) * SECTOR_WIDTH_DEG)
        measured = ~np.isnan(distance)
        seen_to = np.where(np.isposinf(distance), max_range_m, distance)
        if self.t_ns.size:
            offset = self.north_east - origin
            at = np.hypot(offset[:, 0], offset[:, 1])
            heading = np.arctan2(offset[:, 1], offset[:, 0])
            # Seen past only when every bin within half a bin of it looks beyond it: a point is
            # placed up to half a bin off where it was (a bin's reading lies somewhere across
            # it), so a point near a bin's edge (the end of a wall beside a gap) is not cleared
            # by the bin that looks through the gap next to it.
            past = measured & (seen_to > 0)
            seen_past = np.ones(heading.size, dtype=np.bool_)
            for side in (-1.0, 1.0):
                near = bearing_bins(heading + side * _HALF_BIN_RAD, yaw_rad)
                seen_past &= past[near] & (seen_to[near] > at + _SEE_PAST_M)
            keep = ~seen_past
            self.north_east, self.t_ns = self.north_east[keep], self.t_ns[keep]
        finite = np.isfinite(distance)
        bearing = bearing + in_bin_rad(distance, points_frd_m)
        if finite.any():
            new = origin + np.stack(
                [
                    distance[finite] * np.cos(bearing[finite]),
                    distance[finite] * np.sin(bearing[finite]),
                ],
                axis=1,
            )
            self.north_east = np.concatenate([self.north_east, new])
            self.t_ns = np.concatenate(
                [self.t_ns, np.full(int(finite.sum()), t_capture_ns, dtype=np.int64)]
            )
        if finite.any():
            # One point per cell (the newest): an obstacle in view for seconds stays one set
            # of points, so the cap drops what is out of view only after the memory time.
            keys = np.floor(self.north_east / _CELL_M).astype(np.int64)
            key = keys[:, 0] * 1_000_003 + keys[:, 1]
            _, last = np.unique(key[::-1], return_index=True)
            keep = np.sort(key.size - 1 - last)
            self.north_east, self.t_ns = self.north_east[keep], self.t_ns[keep]
        if self.t_ns.size > self.max_points:
            self.north_east = self.north_east[-self.max_points :]
            self.t_ns = self.t_ns[-self.max_points :]

    def expire(self, now_ns: int) -> None:
        """Drop points older than the memory time."""
        keep = now_ns - self.t_ns <= int(self.memory_s * 1e9)
        self.north_east, self.t_ns = self.north_east[keep], self.t_ns[keep]

    def offsets(self, north_east_m: tuple[float, float]) -> Array:
        """The remembered points relative to a position, (N, 2) north and east (read-only)."""
        return self.near(north_east_m)[0]

    def near(self, north_east_m: tuple[float, float]) -> tuple[Array, Array]:
        """The remembered points relative to a position and their distances from it.

        One decision asks for them several times from the same position: they are computed
        once per set of points and position. Every change to the points assigns a new
        ``north_east`` array; writing into it in place would leave these stale.

        Args:
            north_east_m: The position.

        Returns:
            ``(offsets, ranges_m)``: (N, 2) north and east, and (N,) distances; read-only.
        """
        at = (float(north_east_m[0]), float(north_east_m[1]))
        points, cached = self.north_east, self._near
        if cached is not None and cached[0] is points and cached[1] == at:
            return cached[2], cached[3]
        offsets = points - np.asarray(at, dtype=np.float64)
        ranges_m = np.hypot(offsets[:, 0], offsets[:, 1])
        offsets.flags.writeable = False
        ranges_m.flags.writeable = False
        self._near = (points, at, offsets, ranges_m)
        return offsets, ranges_m


def in_bin_rad(distance_m: Array, points_frd_m: npt.NDArray[np.floating] | None) -> Array:
    """Where in its bin each reading lies: its measured point's bearing, else the neighbours'.

    Args:
        distance_m: The scan's 72 distances (NaN unknown, ``inf`` clear), bin 0 ahead.
        points_frd_m: (72, 3) body points of the finite bins, or None.

    Returns:
        (72,) radians to add to each bin's bearing, within half a bin.
    """
    shift = surface_shift_rad(distance_m)
    if points_frd_m is None:
        return shift
    points = np.asarray(points_frd_m, dtype=np.float64)
    measured = np.isfinite(points[:, 0]) & np.isfinite(points[:, 1])
    measured &= np.hypot(points[:, 0], points[:, 1]) > 0.0
    body = np.arctan2(points[:, 1], points[:, 0])
    middle = np.radians(np.arange(SECTOR_COUNT) * SECTOR_WIDTH_DEG)
    offset = np.clip(wrap_rad(body - middle), -_HALF_BIN_RAD, _HALF_BIN_RAD)
    return np.where(measured, offset, shift)


def surface_shift_rad(distance_m: Array) -> Array:
    """Where in its bin each reading lies, as an angle from the bin's middle.

    A bin's reading is its nearest point, somewhere across the bin's 5 degrees. Where the
    readings fall steadily from one neighbour through this bin to the other (a surface seen at
    a slant: the side wall of a corridor), that point is on the edge toward the nearer
    neighbour; placed in the middle it would sit up to a few tenths of a metre in front of the
    wall, and a corridor wide enough to fly would look closed a few metres ahead. The same at
    the edge of the view, where the surface runs on out of sight. Anywhere else (a nearest bin,
    the last bin before a gap, where the surface ends somewhere inside the bin) the reading
    stays in the middle.

    Args:
        distance_m: The scan's 72 distances (NaN unknown, ``inf`` clear), bin 0 ahead.

    Returns:
        (72,) radians to add to each bin's bearing: 0 or half a bin either way.
    """
    before = np.roll(distance_m, 1)
    after = np.roll(distance_m, -1)
    reach = _SURFACE_RATIO * distance_m
    with np.errstate(invalid="ignore"):
        # Nearer toward the bin before (or the surface runs on out of view there), and the bin
        # after not much farther (not a gap).
        toward_before = (before < distance_m) | np.isnan(before)
        toward_after = (after < distance_m) | np.isnan(after)
        rising = toward_before & (distance_m < after) & (after <= reach)
        falling = toward_after & (distance_m < before) & (before <= reach)
    return np.where(falling, _HALF_BIN_RAD, np.where(rising, -_HALF_BIN_RAD, 0.0))


def bearing_bins(heading_rad: Array, yaw_rad: float) -> npt.NDArray[np.int64]:
    """The body bin (5 degrees, bin 0 ahead) that each world heading falls in at a yaw."""
    body = wrap_rad(heading_rad - yaw_rad)
    return np.asarray(
        np.floor(np.remainder(np.degrees(body) / SECTOR_WIDTH_DEG + 0.5, SECTOR_COUNT)).astype(
            np.int64
        )
        % SECTOR_COUNT
    )
