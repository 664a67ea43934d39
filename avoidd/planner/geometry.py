"""Free distance along a direction for a round vehicle among obstacle points (local NED)."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

Array = npt.NDArray[np.float64]

DIRECTION_COUNT = 72
DIRECTION_STEP_DEG = 5.0


def directions_rad() -> Array:
    """The planner's 72 world directions: bearing 5 k degrees from north, clockwise."""
    return np.asarray(np.radians(np.arange(DIRECTION_COUNT) * DIRECTION_STEP_DEG), np.float64)


def wrap_rad(angle: Array | float) -> Array:
    """Angles wrapped into (-pi, pi]."""
    return np.asarray(-(np.remainder(-np.asarray(angle) + math.pi, 2 * math.pi) - math.pi))


def free_distance(offsets_ne: Array, headings_rad: Array, clearance_m: float | Array) -> Array:
    """How far the vehicle can go along each heading before it is ``clearance_m`` from a point.

    This is the VFH+ enlargement, exact for a disc: a point at distance ``d`` blocks the
    headings within ``asin(clearance / d)`` of its bearing.

    Args:
        offsets_ne: (N, 2) obstacle points relative to the vehicle, north and east (metres).
        headings_rad: (K,) headings, radians from north, clockwise.
        clearance_m: Vehicle radius plus margin: one for all headings, or (K,) one each.

    Returns:
        (K,) distances; 0 toward a point already within the clearance, ``inf`` when nothing
        is in the way.
    """
    if offsets_ne.size == 0:
        return np.full(headings_rad.shape, np.inf)
    unit = np.stack([np.cos(headings_rad), np.sin(headings_rad)], axis=1)  # (K, 2)
    along = unit @ offsets_ne.T  # (K, N)
    across = unit[:, 0:1] * offsets_ne[:, 1] - unit[:, 1:2] * offsets_ne[:, 0]
    clearance = np.broadcast_to(np.asarray(clearance_m, dtype=np.float64), headings_rad.shape)
    reach = clearance[:, None] ** 2 - across * across
    with np.errstate(invalid="ignore"):
        contact = along - np.sqrt(np.maximum(reach, 0.0))
    # Only points the swept disc meets ahead block a heading; one already within the
    # clearance blocks the headings toward it (free 0), never those away from it.
    blocking = (reach > 0) & (along > 0)
    distance = np.where(blocking, np.maximum(contact, 0.0), np.inf)
    return np.asarray(distance.min(axis=1))


def gap_headings(offsets_ne: Array, clearance_m: float, within_m: float, most: int = 12) -> Array:
    """Headings through the middle of the gaps between obstacle points.

    The 72 directions are 5 degrees apart, so from a few metres out the one line through a gap
    barely wider than the vehicle's clearance may fall between two of them. Sorted by bearing,
    two neighbouring points at least ``2 * clearance_m`` apart leave a gap the vehicle fits
    through (:func:`gap_edges`); its middle is a heading worth trying.

    Args:
        offsets_ne: (N, 2) obstacle points relative to the vehicle, north and east (metres).
        clearance_m: Vehicle radius plus margin (and any buffer).
        within_m: Only gaps whose nearer side is this close count (farther ones can wait).
        most: At most this many gaps, the nearest first.

    Returns:
        (K,) headings in radians, K <= ``most``.
    """
    first, second = gap_edges(offsets_ne, clearance_m, within_m, most)
    if not first.shape[0]:
        return np.zeros(0)
    middle = (first + second) / 2.0
    return np.asarray(np.arctan2(middle[:, 1], middle[:, 0]), np.float64)


def gap_edges(
    offsets_ne: Array, clearance_m: float, within_m: float, most: int = 12
) -> tuple[Array, Array]:
    """The two edges of each gap between obstacle points the vehicle's disc fits through.

    As :func:`gap_headings`: neighbours by bearing at least ``2 * clearance_m`` apart, the
    nearer side within ``within_m``, the nearest first.

    Args:
        offsets_ne: (N, 2) obstacle points relative to the vehicle, north and east (metres).
        clearance_m: Vehicle radius plus margin.
        within_m: Only gaps whose nearer side is this close count.
        most: At most this many gaps.

    Returns:
        ``(first, second)``: (K, 2) each, the edge points in bearing order (clockwise).
    """
    empty = np.zeros((0, 2))
    if offsets_ne.shape[0] < 2:
        return empty, empty
    ranges = np.hypot(offsets_ne[:, 0], offsets_ne[:, 1])
    near = offsets_ne[ranges <= within_m]
    if near.shape[0] < 2:
        return empty, empty
    points = near[np.argsort(np.arctan2(near[:, 1], near[:, 0]))]
    following = np.roll(points, -1, axis=0)
    width = np.hypot(*(following - points).T)
    # Neighbours by bearing with room between them (the wrap-around pair included); a gap
    # wider than a half turn is open space, not a gap.
    cross = points[:, 0] * following[:, 1] - points[:, 1] * following[:, 0]
    fits = (width >= 2.0 * clearance_m) & (cross > 0)
    if not fits.any():
        return empty, empty
    nearer = np.minimum(np.hypot(*points.T), np.hypot(*following.T))[fits]
    order = np.argsort(nearer)[:most]
    return points[fits][order], following[fits][order]
