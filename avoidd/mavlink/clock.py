"""Mapping avoidd's monotonic clock to the autopilot's boot clock, and seeing it reboot.

The autopilot stamps ATTITUDE, SYSTEM_TIME and others with ``time_boot_ms``. A message is received
some unknown, non-negative delay after it was stamped, so each one gives a lower bound of the
offset (autopilot boot time minus local monotonic time); the largest bound seen recently is the
estimate (the message that travelled fastest). Bounds older than a window are forgotten: a
crystal drifts by a few parts per million, but a simulated autopilot's clock can run slower than
the wall clock (PX4 SITL with SIH ran 1.4 % slow on a busy machine, more with both cores loaded:
over a 60 s window its messages looked 0.8 s older than they were, over 10 s still 0.2-0.44 s
while they had arrived less than 0.11 s before, and avoidd took its fresh attitude for stale).
Three seconds of the 10-50 Hz streams avoidd asks for still hold a message that travelled fast.
"""

from __future__ import annotations

from collections import deque

_WINDOW_NS = 3_000_000_000
_REBOOT_NS = 1_000_000_000
"""A boot clock that runs this far behind the estimate started over: the autopilot rebooted."""
_CONFIRM_NS = 200_000_000
"""...and still does in a message received this much later: a busy machine that reads its
socket a second late gets a burst of stamps that look a second old, but the messages read
after the burst are on time again."""


class ClockSync:
    """Estimates the autopilot's clocks from the timestamps in its messages."""

    def __init__(self) -> None:
        self._bounds: deque[tuple[int, int]] = deque()  # (local receive ns, offset bound ns)
        self._offset_ns: int | None = None
        self._behind_since_ns: int | None = None
        self._reference_ns: int | None = None

    @property
    def synced(self) -> bool:
        """Whether the boot-clock offset is known."""
        return self._offset_ns is not None

    @property
    def offset_ns(self) -> int | None:
        """Autopilot boot time minus local monotonic time, in ns (None until synced)."""
        return self._offset_ns

    def observe_boot_ms(self, time_boot_ms: int, received_ns: int) -> bool:
        """Take one autopilot ``time_boot_ms`` stamp received at local monotonic ``received_ns``.

        Returns:
            True when the stamps show the autopilot rebooted: its boot clock runs more than a
            second behind the estimate, which no delay in transit explains, in every message
            for at least 0.2 s (a burst of queued messages read late looks so only once). The
            estimate starts over.
        """
        bound = time_boot_ms * 1_000_000 - received_ns
        rebooted = False
        # Behind the estimate held when the first such message came (the window may forget
        # the bounds before it meanwhile).
        reference_ns = self._offset_ns if self._behind_since_ns is None else self._reference_ns
        if reference_ns is None or bound >= reference_ns - _REBOOT_NS:
            self._behind_since_ns = None
        elif self._behind_since_ns is None:
            self._behind_since_ns, self._reference_ns = received_ns, reference_ns
        elif received_ns - self._behind_since_ns >= _CONFIRM_NS:
            rebooted = True
            self._behind_since_ns = None
            self._bounds.clear()
        while self._bounds and self._bounds[-1][1] <= bound:
            self._bounds.pop()
        self._bounds.append((received_ns, bound))
        while self._bounds and received_ns - self._bounds[0][0] > _WINDOW_NS:
            self._bounds.popleft()
        self._offset_ns = self._bounds[0][1]
        return rebooted

    def to_autopilot_boot_ns(self, local_ns: int) -> int | None:
        """A local monotonic time on the autopilot's boot clock (None until synced)."""
        if self._offset_ns is None:
            return None
        return local_ns + self._offset_ns

    def to_local_ns(self, time_boot_ms: float) -> int | None:
        """An autopilot boot-clock time (ms) on the local monotonic clock (None until synced)."""
        if self._offset_ns is None:
            return None
        return int(time_boot_ms * 1_000_000) - self._offset_ns
