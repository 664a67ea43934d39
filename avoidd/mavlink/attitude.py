"""A short, time-indexed history of the vehicle attitude, interpolated at a frame's capture time."""

from __future__ import annotations

import bisect
import math
from collections import deque
from dataclasses import dataclass


@dataclass(frozen=True)
class Attitude:
    """Vehicle attitude (ATTITUDE message convention: radians, NED, right-handed).

    Attributes:
        t_ns: When it held, on avoidd's monotonic clock.
        roll_rad: Roll, positive right wing down.
        pitch_rad: Pitch, positive nose up.
        yaw_rad: Yaw, positive clockwise from north seen from above, in (-pi, pi].
    """

    t_ns: int
    roll_rad: float
    pitch_rad: float
    yaw_rad: float


def _lerp_angle_rad(a: float, b: float, w: float) -> float:
    """Interpolate from angle a to b by weight w along the shorter way round."""
    delta = math.remainder(b - a, math.tau)
    return math.remainder(a + w * delta, math.tau)


class AttitudeHistory:
    """The last seconds of attitude samples, kept in time order.

    Args:
        span_ns: How much history to keep.
        max_gap_ns: Interpolation refuses to bridge samples further apart than this, and
            extrapolation to go further than this beyond the newest sample.
    """

    def __init__(self, span_ns: int = 2_000_000_000, max_gap_ns: int = 200_000_000) -> None:
        self._span_ns = span_ns
        self._max_gap_ns = max_gap_ns
        self._times: deque[int] = deque()
        self._samples: deque[Attitude] = deque()

    def __len__(self) -> int:
        return len(self._samples)

    def clear(self) -> None:
        """Forget every sample (the autopilot rebooted or the link clock jumped)."""
        self._times.clear()
        self._samples.clear()

    def add(self, sample: Attitude) -> None:
        """Add a sample; out-of-order samples are put in place, duplicates replace."""
        if self._samples and sample.t_ns <= self._times[-1]:
            index = bisect.bisect_left(self._times, sample.t_ns)
            if index < len(self._times) and self._times[index] == sample.t_ns:
                self._samples[index] = sample
                return
            self._times.insert(index, sample.t_ns)
            self._samples.insert(index, sample)
        else:
            self._times.append(sample.t_ns)
            self._samples.append(sample)
        newest = self._times[-1]
        while self._times and newest - self._times[0] > self._span_ns:
            self._times.popleft()
            self._samples.popleft()

    def newest(self) -> Attitude | None:
        """The newest sample, or None before the first."""
        return self._samples[-1] if self._samples else None

    def at(self, t_ns: int) -> Attitude | None:
        """The attitude at ``t_ns``, linearly interpolated between the samples around it.

        Returns:
            None when there is no sample close enough to vouch for it (older than the history,
            or in a gap wider than ``max_gap_ns``, or newer than the newest sample by more
            than that). A time shortly after the newest sample returns the newest sample.
        """
        if not self._samples:
            return None
        index = bisect.bisect_left(self._times, t_ns)
        if index < len(self._times) and self._times[index] == t_ns:
            return self._samples[index]
        if index == 0:
            return None
        before = self._samples[index - 1]
        if index == len(self._samples):
            if t_ns - before.t_ns > self._max_gap_ns:
                return None
            return Attitude(t_ns, before.roll_rad, before.pitch_rad, before.yaw_rad)
        after = self._samples[index]
        gap_ns = after.t_ns - before.t_ns
        if gap_ns > self._max_gap_ns:
            return None
        w = (t_ns - before.t_ns) / gap_ns
        return Attitude(
            t_ns,
            before.roll_rad + w * (after.roll_rad - before.roll_rad),
            before.pitch_rad + w * (after.pitch_rad - before.pitch_rad),
            _lerp_angle_rad(before.yaw_rad, after.yaw_rad, w),
        )
