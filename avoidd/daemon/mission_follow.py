"""Flying the autopilot's mission: its NAV_WAYPOINT items, in order, as avoidd's goals.

The mission itself is downloaded by :class:`avoidd.mavlink.mission.MissionClient`; this module
turns each new download into a list of waypoints and walks it. ArduPilot's item 0 is its home
position, not a waypoint, and is skipped. Waypoints are named by their item number, as a ground
station shows them.
"""

from __future__ import annotations

import logging

from avoidd.daemon.goals import Frame, Refusal, mission_goal
from avoidd.mavlink import codec as mav
from avoidd.mavlink.mission import MissionClient, MissionItem
from avoidd.planner.core import Goal

logger = logging.getLogger(__name__)


class MissionFollower:
    """Which waypoint of the current mission avoidd flies to.

    Args:
        client: The mission download (its ``version`` says when the mission changed).
    """

    def __init__(self, client: MissionClient) -> None:
        self.client = client
        self.waypoints: list[MissionItem] = []
        self.index = 0
        self._version = 0

    def new_mission(self, ardupilot: bool) -> bool:
        """Whether a new mission was downloaded since the last call (then it starts over)."""
        if self.client.version == self._version or self.client.items is None:
            return False
        self._version = self.client.version
        first = 1 if ardupilot else 0
        self.waypoints = [
            item
            for item in self.client.items
            if item.command == mav.MAV_CMD_NAV_WAYPOINT and item.seq >= first
        ]
        self.index = 0
        logger.info("mission: %d waypoints to fly", len(self.waypoints))
        return True

    def goal(self, frame: Frame) -> Goal | Refusal | None:
        """The current waypoint as a goal; None when the mission is done or empty.

        Waypoints that can never be flown (an unsupported frame, below 0.5 m) are skipped with
        a warning; a refusal that may pass (no origin yet) is returned for the caller to retry.
        """
        while self.index < len(self.waypoints):
            item = self.waypoints[self.index]
            goal = mission_goal(item, item.seq, frame)
            if isinstance(goal, Goal) or goal.result == mav.MAV_RESULT_TEMPORARILY_REJECTED:
                return goal
            logger.warning("mission: waypoint %d skipped: %s", item.seq, goal.reason)
            self.index += 1
        return None

    def advance(self) -> None:
        """The current waypoint was reached: on to the next."""
        self.index += 1
