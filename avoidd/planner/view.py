"""Where the cameras look: toward the way flown, turned toward the goal as far as the view allows.

A forward camera sees only where the vehicle points, so the heading is a choice: along the way
flown, turned toward the goal as far as keeps that way in view (a corridor's turn or a wall's
end is seen early), or, when the way to the goal is blocked only by what has not been seen,
toward that way first.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from avoidd.planner.geometry import wrap_rad
from avoidd.planner.surroundings import Surroundings
from avoidd.planner.tuning import Tuning
from avoidd.types import SECTOR_COUNT, SECTOR_WIDTH_DEG

Array = npt.NDArray[np.float64]


class View:
    """The heads' field of view (the bins they have measured) and the heading rules.

    Args:
        tuning: The planner's constants.
        margin_rad: The way flown stays this far inside the view when the cameras turn toward
            the goal (the corridor the vehicle sweeps, seen from a stop away, and one bin).
    """

    def __init__(self, tuning: Tuning, margin_rad: float) -> None:
        self.tuning = tuning
        self.margin_rad = margin_rad
        self.in_view = np.zeros(SECTOR_COUNT, dtype=np.bool_)
        """The body bins the heads cover (their mounts are fixed: once seen, always)."""

    def observe(self, distance_m: npt.NDArray[np.float32]) -> None:
        """Take a scan's covered bins into the view."""
        self.in_view |= ~np.isnan(distance_m)

    def offset_rad(self, wanted_rad: float) -> float:
        """How far the heading may turn from the way flown (``wanted_rad``, signed, clockwise).

        As far as keeps the way within the forward view (the bins the heads have measured,
        contiguous from straight ahead) less the view margin; none for a view all round
        (nothing to gain) or before any scan.
        """
        view = self.in_view
        if not view[0] or view.all():
            return 0.0
        width = math.radians(SECTOR_WIDTH_DEG)
        right = int(np.argmin(view)) - 1  # bins right of ahead (clockwise) in view
        left = int(np.argmin(view[:0:-1]))  # and left of it
        # The way must stay in view: turning right by x puts it x left of ahead.
        room_left = max(0.0, (left + 0.5) * width - self.margin_rad)
        room_right = max(0.0, (right + 0.5) * width - self.margin_rad)
        return max(-room_right, min(room_left, wanted_rad))

    def look_rad(
        self,
        around: Surroundings,
        directions: Array,
        goal_rad: float,
        chosen_rad: float,
        buffer_m: float,
        enter_m: float,
    ) -> float:
        """Where to point the cameras: the best way known obstacles leave open.

        That is the chosen way unless the way the planner would take, were unseen space free,
        differs: then the cameras turn to the first part of that way's corridor they have not
        seen (down the way when that is far ahead; at a corridor's turn the near side of the
        way on lies beside the vehicle, outside a view pointed along it). Going round
        something with the chosen way in view, they turn toward the goal as far as the view
        allows (:meth:`offset_rad`).
        """
        look = self._best_open_rad(around, directions, goal_rad, chosen_rad, buffer_m, enter_m)
        if abs(float(wrap_rad(look - chosen_rad))) <= math.radians(SECTOR_WIDTH_DEG):
            look = chosen_rad + self.offset_rad(float(wrap_rad(goal_rad - chosen_rad)))
        return look

    def _first_unseen(self, around: Surroundings, heading_rad: float) -> float | None:
        """The bearing of the first unseen part of a way known obstacles leave open, if any."""
        if around.visibility is None:
            return None
        pose = around.pose
        reach_m = min(around.look_m, float(around.obstacle_free_m(np.array([heading_rad]))[0]))
        unseen = around.visibility.first_unseen(
            (pose.north_m, pose.east_m),
            heading_rad,
            around.clearance_m,
            reach_m,
            around.seen_since_ns,
            around.radius_m,
        )
        if unseen is None:
            return None
        return math.atan2(unseen[1] - pose.east_m, unseen[0] - pose.north_m)

    def _best_open_rad(
        self,
        around: Surroundings,
        directions: Array,
        goal_rad: float,
        chosen_rad: float,
        buffer_m: float,
        enter_m: float,
    ) -> float:
        t, pose = self.tuning, around.pose
        if around.visibility is None:
            return chosen_rad
        free = around.obstacle_free_m(directions, buffer_m)
        open_ways = np.flatnonzero(free >= enter_m)
        if open_ways.size == 0:
            return chosen_rad
        headings = directions[open_ways]
        cost = t.mu_goal * np.abs(wrap_rad(headings - goal_rad))
        cost += t.mu_heading * np.abs(wrap_rad(headings - pose.yaw_rad))
        pick = int(np.argmin(cost))
        best = float(headings[pick])
        # Its first part not looked at: far ahead that is down the way itself, beside the
        # vehicle (a corridor's turn) it is the flank a view pointed along the way misses.
        unseen = self._first_unseen(around, best)
        return best if unseen is None else unseen

    def yaw_rate(self, error_rad: float, max_yaw_rate_deg_s: float) -> float:
        """The yaw rate toward a heading ``error_rad`` away, within the configured limit."""
        limit = math.radians(max_yaw_rate_deg_s)
        return max(-limit, min(limit, self.tuning.yaw_gain_per_s * error_rad))

    def speed_share(self, yaw_rad: float, chosen_rad: float) -> float:
        """The share of the speed kept while the heading differs from the way flown.

        Beyond the turn the view allows, the vehicle slows (the speed law counts only the
        part of the way the cameras looked at).
        """
        turned_rad = float(wrap_rad(yaw_rad - chosen_rad))
        off_rad = abs(turned_rad - self.offset_rad(turned_rad))
        return 0.5 + 0.5 * max(0.0, math.cos(off_rad))
