"""The vehicle's velocity as its reported positions move: what changes its distance to obstacles.

An autopilot reports a velocity estimate beside its position estimate, and the two need not
agree: in PX4 SITL (SIH) the position moved 10-25 degrees off the reported velocity, and up to
30 % faster or slower, for seconds at a time. Obstacles are remembered, and clearance judged, in
the position's frame, so the planner checks the way the vehicle drifts toward them with the
velocity the positions show.

A slope fitted to positions lags (by half its window): alone it would see a braking vehicle as
faster than it is. So what is fitted is the disagreement itself: the positions less the
reported velocity integrated over the same reports. Its slope is how much faster (and which
way) the positions move than the reports say, and the newest reported velocity plus that is
the positions' velocity now, without lag.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from avoidd.types import TrackPoint

TRACK_WINDOW_S = 0.5
"""Positions from this far back are fitted (long enough to average out the estimate's noise,
short enough to follow how the estimates disagree as it changes)."""
_MIN_SPAN_S = 0.3
"""A fit needs positions spanning at least this long."""
_MIN_POSITIONS = 3


def track_velocity_ne(
    reports: Sequence[TrackPoint], window_s: float = TRACK_WINDOW_S
) -> tuple[float, float] | None:
    """The horizontal velocity the positions show now.

    Args:
        reports: Reported positions and velocities in time order, times on the clock the
            positions were measured with (the autopilot's own).
        window_s: How far back from the newest report to fit.

    Returns:
        ``(north_m_s, east_m_s)``: the newest reported velocity plus the slope of the
        positions less the integrated reported velocity over the window; None when the window
        holds too few reports or too short a span for a fit.
    """
    if len(reports) < _MIN_POSITIONS:
        return None
    since_ns = reports[-1][0] - int(window_s * 1e9)
    recent = [r for r in reports if r[0] >= since_ns]
    if len(recent) < _MIN_POSITIONS:
        return None
    data = np.array(recent, dtype=np.float64)
    t_s = (data[:, 0] - data[0, 0]) / 1e9
    if t_s[-1] < _MIN_SPAN_S:
        return None
    # The reported velocity integrated (trapezoids) from the first report: where the reports
    # say the vehicle went.
    steps = np.diff(t_s)[:, None] * (data[1:, 3:5] + data[:-1, 3:5]) / 2.0
    said = np.vstack([np.zeros((1, 2)), np.cumsum(steps, axis=0)])
    apart = data[:, 1:3] - said
    t_s -= t_s.mean()
    drift = (t_s @ (apart - apart.mean(axis=0))) / float(t_s @ t_s)
    north, east = (data[-1, 3:5] + drift).tolist()
    return (float(north), float(east))
