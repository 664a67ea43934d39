"""Through a gap: when the line to the goal is blocked, line up on a gap's axis and fly through it.

A gap only a little wider than twice the clearance (2.2 x radius plus margin leaves 0.15 m to
spare each side) is passable only along its axis: flown at from the side, the width the disc
sees shrinks with the cosine of the angle, and a turning buffer closes it at once. So when
something seen blocks the line to the goal and a gap leads to the goal's side, the planner's
goal for the cycle becomes a point on that gap's axis (pure pursuit: a point ahead of the
vehicle's projection on the axis, nearer as the gap comes nearer; once lined up, one beyond
the gap), reached without a turning buffer (the vehicle flies straight along the axis; the
clearance itself is kept). The gap followed is kept from cycle to cycle while it stays there,
so the vehicle does not dither between two, and given up when lining up fails.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from avoidd.planner.geometry import gap_edges
from avoidd.planner.surroundings import Surroundings
from avoidd.planner.visibility import VisibilityGrid

Array = npt.NDArray[np.float64]

_LOOKAHEAD_MIN_M = 2.5
"""The pursuit point is at least this far along the axis ahead of the vehicle's projection."""
_LINE_UP_M = 2.5
"""The vehicle is on the axis this far before the gap's line."""
_LOOKAHEAD_NEAR_M = 0.8
"""Nearer the gap than that and not lined up, the pursuit point is this close (slow, and
straight for the axis)."""
_BEYOND_M = 3.0
"""Once lined up, the pursuit point lies this far past the gap's line."""
_LINED_UP_SLACK_M = 0.5
"""Once lined up, the vehicle counts as lined up while this much farther off the axis than
the room there is (no switching back and forth across the axis; whether the disc fits is the
free distance's to say)."""
_THROUGH_M = np.array([0.0, 0.5, 1.0])
"""Points along the axis from the gap's middle that must have been seen through it."""
_SEARCH_M = 20.0
"""Remembered points within this range are searched for gaps."""
_KEEP_WITHIN_M = 1.0
"""The gap followed is the same gap next cycle when its middle moved less than this."""
_BARRIER_BAND_M = 0.5
"""A barrier's points lie within this of the gap's line."""
_BARRIER_REACH_M = (1.5, 4.0)
"""And continue it, somewhere between this far beyond an edge and this far: a gap in a wall
or beside its end, not the space between two poles or boxes (the direction stage goes round
those, faster than lining up between them)."""
_DETOUR_M = 30.0
"""A gap whose route to the goal is longer than the straight line by more than this is not
taken (the way round the obstacle's end is left to the direction stage)."""


@dataclass(frozen=True)
class Gap:
    """A gap, relative to the vehicle.

    Attributes:
        middle: (2,) its middle, north and east.
        axis: (2,) unit normal of its line, pointing away from the vehicle.
        half_width_m: Half its width.
    """

    middle: Array
    axis: Array
    half_width_m: float

    @property
    def distance_m(self) -> float:
        """How far the gap's line is ahead along the axis."""
        return float(self.axis @ self.middle)

    @property
    def lateral_m(self) -> float:
        """How far off the axis the vehicle is (unsigned)."""
        along_line = np.array([-self.axis[1], self.axis[0]])
        return abs(float(along_line @ self.middle))


@dataclass(frozen=True)
class SubGoal:
    """Where to fly this cycle instead of the goal.

    Attributes:
        heading_rad: The direction to the pursuit point.
        distance_m: The distance to it.
        gap: The gap followed.
        stop_m: Until it is lined up, the vehicle flies no faster than it can stop within
            this: how far it is along the axis from the line-up point (``_LINE_UP_M`` before
            the gap) plus how far off the axis, so that it arrives there slowly enough to line
            up within the few centimetres a narrow gap leaves; ``inf`` once lined up.
    """

    heading_rad: float
    distance_m: float
    gap: Gap
    stop_m: float = math.inf


def find_gaps(
    around: Surroundings,
    within_m: float,
    seen: VisibilityGrid | None = None,
    narrower_m: float = math.inf,
) -> list[Gap]:
    """The gaps in a barrier the vehicle's disc fits through, among the points within range.

    A gap is two neighbouring points by bearing at least twice the clearance apart
    (:func:`~avoidd.planner.geometry.gap_edges`) whose line the remembered points continue
    (a wall with an opening, or beside a wall's end; not the space between two poles), and,
    with ``seen``, through which the cameras looked (not a stretch of wall between two
    views' edges). Only gaps narrower than ``narrower_m`` are checked and returned.
    """
    first, second = gap_edges(around.offsets, around.clearance_m, within_m)
    gaps = []
    for a, b in zip(first, second, strict=True):
        middle = (a + b) / 2.0
        line = b - a
        width = float(np.hypot(*line))
        if width >= narrower_m:
            continue
        axis = np.array([line[1], -line[0]]) / width
        if float(axis @ middle) < 0.0:
            axis = -axis
        gap = Gap(middle, axis, width / 2.0)
        if _in_a_barrier(gap, around.offsets) and _looked_through(gap, around, seen):
            gaps.append(gap)
    return gaps


def _looked_through(gap: Gap, around: Surroundings, seen: VisibilityGrid | None) -> bool:
    """Whether the cameras looked through the gap (its middle and just beyond it were seen)."""
    if seen is None:
        return True
    pose = around.pose
    here = np.array([pose.north_m, pose.east_m])
    points = here + gap.middle + np.outer(_THROUGH_M, gap.axis)
    return bool(seen.seen_at(points, around.seen_since_ns).all())


def _in_a_barrier(gap: Gap, offsets: Array) -> bool:
    """Whether remembered points continue the gap's line beyond one of its edges.

    One is enough: the other side may still lie outside the view.
    """
    relative = offsets - gap.middle
    across = relative @ gap.axis
    along = relative @ np.array([-gap.axis[1], gap.axis[0]])
    on_line = np.abs(across) <= _BARRIER_BAND_M
    near, far = _BARRIER_REACH_M
    beyond = np.abs(along) - gap.half_width_m
    continued = on_line & (beyond >= near) & (beyond <= far)
    return bool(np.any(continued))


def _crossing_along_m(gap: Gap, goal: Array) -> float | None:
    """Where the line to the goal crosses the gap's line, along it from the gap's middle.

    None when the goal is not beyond the gap's line.
    """
    goal_across = float(gap.axis @ goal)
    if goal_across <= max(gap.distance_m, 0.0):
        return None
    crossing = goal * (max(gap.distance_m, 0.0) / goal_across)
    along_line = np.array([-gap.axis[1], gap.axis[0]])
    return float(along_line @ (crossing - gap.middle))


def _on_the_way(gap: Gap, goal: Array, offsets: Array) -> bool:
    """Whether the line to the goal crosses the gap's barrier: through the gap, or the barrier.

    The goal lies beyond the gap's line, but a line through two obstacles reaches far past
    them: two boxes the vehicle has already passed, on a slant, leave a "gap" whose line the
    way to the goal crosses metres beyond the second box, where nothing stands. Lining up on
    that gap turns the vehicle back. The barrier must stand where the line to the goal
    crosses it (remembered points there, within ``_BARRIER_REACH_M[0]``), or the line must
    run through the gap itself.
    """
    crossing_along = _crossing_along_m(gap, goal)
    if crossing_along is None:
        return False
    along_line = np.array([-gap.axis[1], gap.axis[0]])
    reach_m = _BARRIER_REACH_M[0]
    if abs(crossing_along) <= gap.half_width_m + reach_m:
        return True
    relative = offsets - gap.middle
    on_line = np.abs(relative @ gap.axis) <= _BARRIER_BAND_M
    near_crossing = np.abs(relative @ along_line - crossing_along) <= reach_m
    return bool(np.any(on_line & near_crossing))


class GapFollower:
    """Chooses the gap to fly through, keeps it while it is there, and gives it up if it fails.

    Args:
        within_m: Gaps whose line is at most this far ahead, plus how far the vehicle is off
            their axis, are considered (the planner uses two stops from full speed; a gap
            farther ahead is left to the direction stage until then).
        give_up_s: A gap followed this long without being passed is given up for
            ``forget_s`` (lining up failed: the direction stage takes over).
        forget_s: How long a given-up gap is left alone.
    """

    def __init__(self, within_m: float, give_up_s: float = 10.0, forget_s: float = 10.0) -> None:
        self.within_m = within_m
        self.give_up_ns = int(give_up_s * 1e9)
        self.forget_ns = int(forget_s * 1e9)
        self._followed_ne: tuple[float, float] | None = None
        """The middle of the gap followed, in the local frame."""
        self._since_ns = 0
        self._given_up: list[tuple[tuple[float, float], int]] = []
        """Gaps given up (middle in the local frame) and until when."""
        self._lined_up = False

    def reset(self) -> None:
        """Follow no gap (a new goal)."""
        self._followed_ne = None
        self._given_up = []

    def subgoal(
        self,
        around: Surroundings,
        goal_ne: tuple[float, float],
        blocked: bool,
        wide_m: float,
        seen: VisibilityGrid | None = None,
    ) -> SubGoal | None:
        """The point to fly to this cycle, on a gap's axis; None: fly to the goal.

        Args:
            around: The vehicle's surroundings.
            goal_ne: The goal relative to the vehicle (north, east).
            blocked: Something remembered blocks the line to the goal.
            wide_m: A gap at least this wide is left to the direction stage (it is wide
                enough for the turning buffer at full speed: no lining up needed).
            seen: What the cameras looked at (a gap must have been looked through).
        """
        now_ns = around.pose.t_ns
        self._given_up = [(ne, until) for ne, until in self._given_up if until > now_ns]
        gap = self._choose(around, goal_ne, wide_m, seen) if blocked else None
        if gap is None:
            self._followed_ne = None
            return None
        pose = around.pose
        middle_ne = (pose.north_m + float(gap.middle[0]), pose.east_m + float(gap.middle[1]))
        if not self._same(middle_ne, self._followed_ne):
            self._since_ns = now_ns
            self._lined_up = False
        elif now_ns - self._since_ns > self.give_up_ns:
            self._given_up.append((middle_ne, now_ns + self.forget_ns))
            self._followed_ne = None
            return None
        self._followed_ne = middle_ne
        room_m = max(gap.half_width_m - around.clearance_m, 0.0)
        slack_m = _LINED_UP_SLACK_M if self._lined_up else 0.0
        self._lined_up = gap.lateral_m <= room_m + slack_m or gap.distance_m <= 0.0
        return _pursuit(gap, self._lined_up)

    def _choose(
        self,
        around: Surroundings,
        goal_ne: tuple[float, float],
        wide_m: float,
        seen: VisibilityGrid | None,
    ) -> Gap | None:
        """The gap to follow: the one followed if it is still there, else the shortest route."""
        pose = around.pose
        goal = np.asarray(goal_ne, dtype=np.float64)
        best: tuple[float, Gap] | None = None
        for gap in find_gaps(around, _SEARCH_M, seen, wide_m):
            # Lining up takes room: a gap farther off the vehicle's way is taken from farther.
            if 2.0 * gap.half_width_m >= wide_m or gap.distance_m > self.within_m + gap.lateral_m:
                continue
            if gap.distance_m <= -around.clearance_m or float(gap.axis @ goal) <= gap.distance_m:
                continue  # behind the vehicle, or the goal is not beyond it
            if not _on_the_way(gap, goal, around.offsets):
                continue  # its barrier is not what stands between the vehicle and the goal
            route = float(np.hypot(*gap.middle) + np.hypot(*(goal - gap.middle)))
            if route > float(np.hypot(*goal)) + _DETOUR_M:
                continue
            middle_ne = (pose.north_m + float(gap.middle[0]), pose.east_m + float(gap.middle[1]))
            if any(self._same(middle_ne, ne) for ne, _ in self._given_up):
                continue
            if self._same(middle_ne, self._followed_ne):
                route = -1.0  # the gap already followed wins
            if best is None or route < best[0]:
                best = (route, gap)
        return None if best is None else best[1]

    @staticmethod
    def _same(a: tuple[float, float], b: tuple[float, float] | None) -> bool:
        return b is not None and math.dist(a, b) < _KEEP_WITHIN_M


def _pursuit(gap: Gap, lined_up: bool) -> SubGoal:
    """The pursuit point on the gap's axis for the vehicle at the origin.

    Lined up: through, ``_BEYOND_M`` past the gap. Else a point on the axis ahead of the
    vehicle's projection: ``_LINE_UP_M`` short of the gap, at least ``_LOOKAHEAD_MIN_M``
    ahead, so the vehicle converges on the axis the more firmly the nearer the gap is.
    """
    distance = gap.distance_m
    if lined_up:
        ahead_m = distance + _BEYOND_M
    elif distance > _LINE_UP_M:
        ahead_m = max(_LOOKAHEAD_MIN_M, distance - _LINE_UP_M)
    else:
        ahead_m = _LOOKAHEAD_NEAR_M  # at the gap, slow: straight for the axis

    projection = gap.middle - gap.axis * distance
    point = projection + gap.axis * ahead_m
    # Not lined up: able to stop where the line-up point is along the axis.
    stop_m = math.inf if lined_up else max(distance - _LINE_UP_M, 0.0) + gap.lateral_m
    return SubGoal(
        math.atan2(float(point[1]), float(point[0])), float(np.hypot(*point)), gap, stop_m
    )
