"""Where the cameras have looked lately: a grid of last-seen times in the local frame.

A direction is only as free as what was seen along it. Each scan marks the cells its measured
bins looked through (up to the reading, or to the maximum range when clear) with the scan's
capture time. The corridor the vehicle would sweep along a heading (as wide as radius plus
margin on each side) is free only as far as every cell of it was seen within the memory time:
beside the vehicle that is what it saw on its way there, ahead it is what the cameras see now.
A forward camera thus cannot send the vehicle sideways into what it never looked at.

Right beside the vehicle a forward camera cannot have seen the corridor's full width (at 1 m
ahead, 1.5 m to the side lies 56 degrees off its axis): there the corridor may be narrower, as
wide as the vehicle itself (its radius) where it stands, then a wedge of :data:`NEAR_TAPER`
per metre ahead (30 degrees each side) out to the full clearance. So the margin is kept from
what was seen, the radius from everything; without that, a vehicle that has just taken off saw
no way at all until it had turned to look beside itself.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from avoidd.types import SECTOR_WIDTH_DEG

Array = npt.NDArray[np.float64]

_RAYS_PER_BIN = 7
NEAR_TAPER = 0.58
"""Beside the vehicle the corridor is the wedge of this half-width per metre ahead (tan 30
degrees: inside any forward view of 60 degrees or more), at least the vehicle's radius, at
most its clearance."""
_NEVER = np.iinfo(np.int64).min // 2


class VisibilityGrid:
    """Last-seen time of every cell of a square around a centre that follows the vehicle.

    Args:
        cell_m: Cell size.
        half_size_m: Half the side of the square.
    """

    def __init__(self, cell_m: float = 0.25, half_size_m: float = 40.0) -> None:
        self.cell_m = cell_m
        self.cells = round(2 * half_size_m / cell_m)
        self.seen_ns = np.full((self.cells, self.cells), _NEVER, dtype=np.int64)
        self.centre = np.zeros(2)
        self._half = half_size_m
        self._version = 0
        self._seen_key: tuple[int, int] | None = None
        self._seen = np.zeros(0, dtype=np.bool_)
        self._corridors: dict[
            tuple[float, float, float | None], tuple[Array, Array, npt.NDArray[np.bool_]]
        ] = {}

    def clear(self) -> None:
        """Forget everything."""
        self.seen_ns[:] = _NEVER
        self._version += 1

    def _follow(self, north_east: Array) -> None:
        """Shift the grid so that a position stays well inside it."""
        offset = north_east - self.centre
        if np.all(np.abs(offset) < self._half / 2):
            return
        shift = np.round(offset / self.cell_m).astype(np.int64)
        moved = np.full_like(self.seen_ns, _NEVER)
        n, e = int(shift[0]), int(shift[1])
        size = self.cells
        src_n = slice(max(n, 0), size + min(n, 0))
        dst_n = slice(max(-n, 0), size + min(-n, 0))
        src_e = slice(max(e, 0), size + min(e, 0))
        dst_e = slice(max(-e, 0), size + min(-e, 0))
        if abs(n) < size and abs(e) < size:
            moved[dst_n, dst_e] = self.seen_ns[src_n, src_e]
        self.seen_ns = moved
        self.centre = self.centre + shift * self.cell_m
        self._version += 1

    def _index(
        self, points: Array
    ) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64], npt.NDArray[np.bool_]]:
        cell = np.floor((points - self.centre) / self.cell_m + self.cells / 2).astype(np.int64)
        inside = np.all((cell >= 0) & (cell < self.cells), axis=-1)
        cell = np.clip(cell, 0, self.cells - 1)
        return cell[..., 0], cell[..., 1], inside

    def mark(
        self,
        north_east_m: tuple[float, float],
        yaw_rad: float,
        distance_m: npt.NDArray[np.floating],
        t_ns: int,
        max_range_m: float,
    ) -> None:
        """Mark what one scan (72 body bins) looked through, from where it was taken."""
        origin = np.asarray(north_east_m, dtype=np.float64)
        self._follow(origin)
        distance = np.asarray(distance_m, dtype=np.float64)
        measured = np.flatnonzero(~np.isnan(distance))
        if measured.size == 0:
            return
        reach = np.where(np.isposinf(distance[measured]), max_range_m, distance[measured])
        # Up to the surface hit: its cell was seen too (what lies behind it was not).
        reach = np.minimum(reach, max_range_m)
        spread = (np.arange(_RAYS_PER_BIN) + 0.5) / _RAYS_PER_BIN - 0.5
        bearing = (
            yaw_rad + np.radians((measured[:, None] + spread[None, :]) * SECTOR_WIDTH_DEG).ravel()
        )
        reach = np.repeat(reach, _RAYS_PER_BIN)
        steps = np.arange(0.0, max_range_m, self.cell_m * 0.7)
        along = steps[None, :]
        keep = along <= reach[:, None]
        points = origin + np.stack(
            [along * np.cos(bearing)[:, None], along * np.sin(bearing)[:, None]], axis=-1
        )
        rows, columns, inside = self._index(points[keep])
        rows, columns = rows[inside], columns[inside]
        self.seen_ns[rows, columns] = np.maximum(self.seen_ns[rows, columns], t_ns)
        self._version += 1

    def _corridor(
        self, clearance_m: float, look_m: float, near_half_m: float | None
    ) -> tuple[Array, Array, npt.NDArray[np.bool_]]:
        """The corridor's sample offsets: along (S,), lateral (S, L), outside the own disc."""
        key = (clearance_m, look_m, near_half_m)
        cached = self._corridors.get(key)
        if cached is not None:
            return cached
        along = np.arange(0.0, look_m + clearance_m, self.cell_m)
        half = np.full(along.shape, clearance_m)
        if near_half_m is not None:
            half = np.minimum(half, np.maximum(near_half_m, NEAR_TAPER * along))
        lateral = half[:, None] * np.linspace(-1.0, 1.0, 5)[None, :]  # (S, L)
        # The vehicle's own disc (within the clearance of where it stands) is where it is.
        beyond = (along[:, None] ** 2 + lateral**2) > clearance_m**2
        if len(self._corridors) > 16:
            self._corridors.clear()
        self._corridors[key] = (along, lateral, beyond)
        return along, lateral, beyond

    def _seen_since(self, since_ns: int) -> npt.NDArray[np.bool_]:
        """Which cells were looked at since ``since_ns``, flattened (kept until a change)."""
        key = (since_ns, self._version)
        if self._seen_key != key:
            self._seen = (self.seen_ns >= since_ns).ravel()
            self._seen_key = key
        return self._seen

    def _unseen(
        self,
        north_east_m: tuple[float, float],
        headings_rad: Array,
        clearance_m: float,
        look_m: float,
        since_ns: int,
        near_half_m: float | None = None,
    ) -> tuple[Array, Array, npt.NDArray[np.bool_]]:
        """The swept corridors' sample offsets and which samples are unseen, (K, S, L).

        Returns:
            ``(along, lateral, unseen)``: (S,) and (S, L) offsets along and across the
            heading, and (K, S, L) whether each sample lies on a cell not seen since
            ``since_ns`` (or off the grid) outside the vehicle's own disc.
        """
        origin = np.asarray(north_east_m, dtype=np.float64)
        self._follow(origin)
        along, lateral, beyond = self._corridor(clearance_m, look_m, near_half_m)
        # In cells from the grid's corner: origin + along * unit + lateral * normal, where
        # the normal of (cos h, sin h) is (-sin h, cos h).
        base = (origin - self.centre) / self.cell_m + self.cells / 2
        cos_h = np.cos(headings_rad)[:, None, None] / self.cell_m
        sin_h = np.sin(headings_rad)[:, None, None] / self.cell_m
        ahead, across = along[None, :, None], lateral[None, :, :]
        rows = np.floor(base[0] + ahead * cos_h - across * sin_h).astype(np.int64)
        columns = np.floor(base[1] + ahead * sin_h + across * cos_h).astype(np.int64)
        size = self.cells
        inside = (rows >= 0) & (rows < size) & (columns >= 0) & (columns < size)
        flat = np.clip(rows, 0, size - 1) * size + np.clip(columns, 0, size - 1)
        unseen = ~(self._seen_since(since_ns)[flat] & inside)
        unseen &= beyond[None, :, :]
        return along, lateral, unseen

    def seen_at(self, points_ne: Array, since_ns: int) -> npt.NDArray[np.bool_]:
        """Whether each point (N, 2: north, east) was looked at since ``since_ns``."""
        rows, columns, inside = self._index(np.asarray(points_ne, dtype=np.float64))
        return np.asarray(inside & (self.seen_ns[rows, columns] >= since_ns))

    def seen_distance(
        self,
        north_east_m: tuple[float, float],
        headings_rad: Array,
        clearance_m: float,
        look_m: float,
        since_ns: int,
        near_half_m: float | None = None,
    ) -> Array:
        """How far along each heading the swept corridor was all seen since ``since_ns``.

        Args:
            north_east_m: The vehicle's position.
            headings_rad: (K,) headings.
            clearance_m: Half-width of the corridor (radius plus margin).
            look_m: How far to look (beyond it: ``inf``).
            since_ns: Cells seen before this are unknown.
            near_half_m: The corridor's half-width where the vehicle stands (its radius),
                then the wedge of :data:`NEAR_TAPER` per metre, up to ``clearance_m``; None:
                the full clearance throughout.

        Returns:
            (K,) distances the vehicle can go before its disc reaches an unseen cell.
        """
        along, _, unseen = self._unseen(
            north_east_m, headings_rad, clearance_m, look_m, since_ns, near_half_m
        )
        first = np.argmax(unseen.any(axis=2), axis=1)
        blocked = unseen.any(axis=(1, 2))
        distance = np.where(blocked, np.maximum(along[first] - clearance_m, 0.0), np.inf)
        return np.asarray(distance, dtype=np.float64)

    def first_unseen(
        self,
        north_east_m: tuple[float, float],
        heading_rad: float,
        clearance_m: float,
        look_m: float,
        since_ns: int,
        near_half_m: float | None = None,
    ) -> tuple[float, float] | None:
        """Where the swept corridor along one heading first reaches an unseen cell.

        Beside a forward camera's view that is often right next to the vehicle (the near
        side of a corridor's turn): the cameras look there to open the way.

        Returns:
            The north and east of the middle of the nearest unseen samples, or None when the
            corridor was all seen.
        """
        along, lateral, unseen = self._unseen(
            north_east_m, np.array([heading_rad]), clearance_m, look_m, since_ns, near_half_m
        )
        row = unseen[0].any(axis=1)
        if not row.any():
            return None
        step = int(np.argmax(row))
        across = float(lateral[step][unseen[0, step]].mean())
        cos_h, sin_h = math.cos(heading_rad), math.sin(heading_rad)
        ahead = float(along[step])
        return (
            north_east_m[0] + ahead * cos_h - across * sin_h,
            north_east_m[1] + ahead * sin_h + across * cos_h,
        )
