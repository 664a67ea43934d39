"""The vehicle's newest position and velocity reports, kept for the planner's track velocity."""

from __future__ import annotations

from collections import deque

from avoidd.types import TrackPoint

REPORTS_KEPT = 64
"""Reports kept (over a second at PX4's 50 Hz LOCAL_POSITION_NED)."""


class TrackHistory:
    """The newest reports in time order, on the clock they were measured with.

    Attributes:
        reports: The reports, oldest first (at most :data:`REPORTS_KEPT`).
    """

    def __init__(self, kept: int = REPORTS_KEPT) -> None:
        self.reports: deque[TrackPoint] = deque(maxlen=kept)

    def add(
        self, t_ns: int, north_m: float, east_m: float, north_m_s: float, east_m_s: float
    ) -> None:
        """Keep a report: a repeat is skipped, and a clock that went back starts over.

        Args:
            t_ns: When it was measured (the autopilot's boot clock, or the simulation's).
            north_m: Position north.
            east_m: Position east.
            north_m_s: Reported velocity north.
            east_m_s: Reported velocity east.
        """
        if self.reports and t_ns < self.reports[-1][0]:
            self.reports.clear()  # the clock went back (a reboot)
        if not self.reports or t_ns > self.reports[-1][0]:
            self.reports.append(
                (t_ns, float(north_m), float(east_m), float(north_m_s), float(east_m_s))
            )

    def clear(self) -> None:
        """Forget every report (the vehicle is gone)."""
        self.reports.clear()

    def __len__(self) -> int:
        return len(self.reports)
