"""Which way to fly: VFH+ over 72 world directions, the goal's and the middles of gaps.

Every candidate heading gets the distance it is free for (obstacles enlarged by the radius,
the margin and a turning buffer that grows with speed; unseen ground blocked unless unknown
is configured free). A binary histogram with two thresholds (hysteresis) says which are
admissible; among them the cheapest wins, ``mu_goal |goal delta| + mu_heading |heading
delta| + mu_previous |previous delta|`` plus a cost for ways blocked farther on, and once the
vehicle has turned to one side of the goal direction to pass an obstacle, the other side costs
extra until the goal direction is admissible again.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from avoidd.planner.geometry import directions_rad, gap_headings, wrap_rad
from avoidd.planner.surroundings import Surroundings
from avoidd.planner.tuning import Tuning

Array = npt.NDArray[np.float64]

_DEAD_END_GOAL_SIDE_RAD = 1.6
"""While turning to look, only a way within this of the goal's direction ends the search."""


@dataclass(frozen=True)
class Ways:
    """The ways open this cycle.

    Attributes:
        headings: Admissible headings (radians from north) after the cycle's restrictions.
        free_m: How far each is free (turning buffer included).
        goal_rad: The goal's direction.
        goal_free_m: How far the goal's direction is free.
        goal_open: The goal's direction is free far enough to go (to the goal, or to enter).
        buffer_m: The turning buffer used.
        along_rad: The direction of the vehicle's velocity.
    """

    headings: Array
    free_m: Array
    goal_rad: float
    goal_free_m: float
    goal_open: bool
    buffer_m: float
    along_rad: float


@dataclass
class Direction:
    """The direction stage and what it keeps between cycles.

    Args:
        tuning: The planner's constants.
        enter_m: A way becomes admissible once free this far.
    """

    tuning: Tuning
    enter_m: float
    previous_rad: float | None = None
    side: int = 0
    """The side of the goal direction the vehicle is committed to (+1 right, -1 left)."""
    side_changes: int = 0
    _directions: Array = field(default_factory=directions_rad)
    _admissible: npt.NDArray[np.bool_] = field(init=False)

    def __post_init__(self) -> None:
        self._admissible = np.zeros(self._directions.size, dtype=np.bool_)

    def clear_admissible(self) -> None:
        """Forget which ways were admissible (the hysteresis starts again)."""
        self._admissible[:] = False

    def reset(self) -> None:
        """Start over for a new goal."""
        self._admissible[:] = False
        self.previous_rad = None
        self.side = 0
        self.side_changes = 0

    @property
    def directions(self) -> Array:
        """The 72 world directions (read-only)."""
        return self._directions

    def ways(
        self,
        around: Surroundings,
        goal_rad: float,
        goal_m: float,
        searching: bool,
        goal_buffer_m: float | None = None,
    ) -> Ways:
        """The admissible ways this cycle (the hysteresis is updated here).

        Args:
            around: The vehicle's surroundings.
            goal_rad: The goal's direction (or the cycle's point on a gap's axis).
            goal_m: The goal's distance.
            searching: The vehicle is turning to look for a way: only a way toward the goal's
                side ends the search.
            goal_buffer_m: The turning buffer of the goal's direction (None: as any other
                way's; 0 along a gap's axis, which is flown straight).
        """
        t, pose = self.tuning, around.pose
        # Directions are chosen with room to spare for the turn the vehicle takes to follow
        # them (it lags its setpoint by a few tenths of a second): more at speed.
        buffer = t.buffer_at_m(math.hypot(pose.north_m_s, pose.east_m_s))
        # One pass over the memory and the seen grid for every heading this cycle looks at:
        # the 72 directions, the goal's, and the middles of gaps the grid may step over.
        gaps = gap_headings(around.offsets, around.clearance_m + buffer, around.look_m)
        candidates = np.concatenate([self._directions, [goal_rad], gaps])
        # Flying on the way it already flies, the vehicle does not turn: no turning room is
        # kept there, so a corridor wide enough at walking pace stays open at speed.
        along = math.atan2(pose.east_m_s, pose.north_m_s)
        straight = np.abs(wrap_rad(candidates - along)) <= math.radians(t.straight_deg)
        buffers = np.where(straight, min(buffer, t.straight_buffer_m), buffer)
        if goal_buffer_m is not None:
            buffers[self._directions.size] = goal_buffer_m
        looked = around.free_m(candidates, buffers)
        count = self._directions.size
        free, goal_free = looked[:count], float(looked[count])
        gaps_free = looked[count + 1 :]
        enter = self.enter_m
        self._admissible = np.where(
            free >= enter, True, np.where(free < t.leave_m, False, self._admissible)
        )
        headings = self._directions[self._admissible]
        headings_free = free[self._admissible]
        if gaps.size:
            headings = np.concatenate([headings, gaps[gaps_free >= enter]])
            headings_free = np.concatenate([headings_free, gaps_free[gaps_free >= enter]])
        goal_open = goal_free >= min(goal_m, enter)
        if goal_buffer_m is not None and goal_open:
            # A point on a gap's axis: its own direction is a way (no grid direction need
            # run through a gap barely wider than the clearance).
            headings = np.concatenate([headings, [goal_rad]])
            headings_free = np.concatenate([headings_free, [goal_free]])
        keep = np.ones(headings.size, dtype=np.bool_)
        if searching:
            keep &= np.abs(wrap_rad(headings - goal_rad)) < _DEAD_END_GOAL_SIDE_RAD
        if goal_open:
            self.side = 0
            self.side_changes = 0
        elif self.side and self.side_changes >= t.max_side_changes:
            # Both sides were tried: only the side it is on now, or straight back out.
            delta_all = wrap_rad(headings - goal_rad)
            keep &= (np.sign(delta_all) != -self.side) | (
                np.abs(delta_all) >= math.radians(t.back_deg)
            )
        return Ways(
            headings[keep], headings_free[keep], goal_rad, goal_free, goal_open, buffer, along
        )

    def choose(self, ways: Ways, yaw_rad: float, horizon_m: float) -> tuple[float, float]:
        """The cheapest admissible way and how far it is free (there is at least one)."""
        t = self.tuning
        headings, free = ways.headings, ways.free_m
        goal_delta = wrap_rad(headings - ways.goal_rad)
        cost = t.mu_goal * np.abs(goal_delta)
        cost += t.mu_heading * np.abs(wrap_rad(headings - yaw_rad))
        if self.previous_rad is not None:
            cost += t.mu_previous * np.abs(wrap_rad(headings - self.previous_rad))
        if self.side and not ways.goal_open:
            cost += np.where(np.sign(goal_delta) == -self.side, t.commitment_cost, 0.0)
        # A way blocked farther on costs more than one that runs clear.
        cost += t.mu_obstructed * np.clip(1.0 - free / horizon_m, 0.0, 1.0)
        best = int(np.argmin(cost))
        return float(headings[best]), float(free[best])

    def snapped(self, chosen_rad: float, ways: Ways) -> float:
        """The goal's own direction for a chosen way within a step of it, when it is open."""
        snap = math.radians(self.tuning.goal_snap_deg)
        if ways.goal_open and abs(float(wrap_rad(chosen_rad - ways.goal_rad))) <= snap:
            return ways.goal_rad
        return chosen_rad

    def commit(self, chosen_rad: float, ways: Ways) -> None:
        """Take the side of the goal direction an onward way goes round on.

        Backing out for a moment (the way on was blocked for a cycle, a pocket) leaves the
        commitment as it was, so the vehicle goes on where it was going once that way opens.
        """
        delta = float(wrap_rad(chosen_rad - ways.goal_rad))
        onward = math.radians(self.tuning.onward_deg)
        if not ways.goal_open and math.radians(2.5) < abs(delta) <= onward:
            side = 1 if delta > 0 else -1
            if self.side and side != self.side:
                self.side_changes += 1
            self.side = side

    def slower_opens(
        self,
        around: Surroundings,
        ways: Ways,
        clear_m: float,
        chosen: tuple[float, float],
    ) -> float:
        """A speed limit that lets a way through open: ``inf`` when none is needed.

        The turning buffer grows with speed, so a gap that is wide enough at walking pace is
        closed to a vehicle flying at it. Slow to a walking pace (``slow_for_gap_m_s``, the
        faster first) when, with that pace's buffer, on the side the vehicle is committed to,
        a way would open that

        - runs clear (to the goal, as far as the sensors see, or a stop from full speed past
          where the chosen way ends) while the chosen way ends within a stop from full speed,
          at most 30 degrees farther from the goal's direction than the chosen one (the way
          round the end of a wall, into a gap ahead); or
        - leads at least a stop from full speed toward the goal, at least ``passing_deg``
          nearer the goal's direction than the chosen way, while the vehicle goes round
          something (a gap in the wall it is flying along).

        Args:
            around: The vehicle's surroundings.
            ways: This cycle's ways.
            clear_m: A way that runs this far runs clear (the goal, or the sensors' range).
            chosen: The way chosen and how far it is free.
        """
        t = self.tuning
        chosen_rad, chosen_free_m = chosen
        buffer_m = ways.buffer_m
        if buffer_m <= t.buffer_at_m(t.slow_for_gap_m_s[-1]):
            return math.inf
        chosen_off = abs(float(wrap_rad(chosen_rad - ways.goal_rad)))
        passing = math.radians(t.passing_deg)
        ending = chosen_free_m < min(clear_m, around.look_m)
        if not ending and chosen_off < 2.0 * passing:
            return math.inf
        gaps = gap_headings(around.offsets, around.clearance_m + t.buffer_m, around.look_m)
        headings = np.concatenate([self._directions, gaps])
        goal_delta = wrap_rad(headings - ways.goal_rad)
        if ending:
            worth = np.abs(goal_delta) <= chosen_off + math.radians(30.0)
            needed_m = min(clear_m, chosen_free_m + around.look_m)
        else:
            worth = np.abs(goal_delta) <= chosen_off - passing
            needed_m = min(clear_m, around.look_m)
        if self.side:
            worth &= np.sign(goal_delta) != -self.side
        if not worth.any():
            return math.inf
        # Now and every pace slower in one pass: the same ways, each pace's buffer. Only ways
        # that are closed now count (one open now was passed over for a cheaper one).
        paces = [v for v in t.slow_for_gap_m_s if buffer_m > t.buffer_at_m(v)]
        candidates = headings[worth]
        buffers = np.repeat([buffer_m] + [t.buffer_at_m(v) for v in paces], candidates.size)
        free = around.free_m(np.tile(candidates, len(paces) + 1), buffers)
        clear = (free >= needed_m).reshape(len(paces) + 1, candidates.size)
        for pace, opens in zip(paces, clear[1:], strict=True):
            if (opens & ~clear[0]).any():
                return pace
        return math.inf
