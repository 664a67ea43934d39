"""Mapping avoidd's monotonic clock to the autopilot's boot clock and to its UTC time.

The autopilot stamps ATTITUDE, SYSTEM_TIME and others with ``time_boot_ms``. A message is received
some unknown, non-negative delay after it was stamped, so each one gives a lower bound of the
offset (autopilot boot time minus local monotonic time); the largest bound seen recently is the
estimate (the message that travelled fastest). Clocks drift by a few parts per million, so
bounds older than a window are forgotten.
"""

from __future__ import annotations

from collections import deque

_WINDOW_NS = 60_000_000_000
_UTC_VALID_AFTER_US = 1_546_300_800_000_000  # 2019-01-01: older "UTC" means no real clock


class ClockSync:
    """Estimates the autopilot's clocks from the timestamps in its messages."""

    def __init__(self) -> None:
        self._bounds: deque[tuple[int, int]] = deque()  # (local receive ns, offset bound ns)
        self._offset_ns: int | None = None
        self._utc_minus_boot_us: int | None = None

    @property
    def synced(self) -> bool:
        """Whether the boot-clock offset is known."""
        return self._offset_ns is not None

    @property
    def offset_ns(self) -> int | None:
        """Autopilot boot time minus local monotonic time, in ns (None until synced)."""
        return self._offset_ns

    def observe_boot_ms(self, time_boot_ms: int, received_ns: int) -> None:
        """Take one autopilot ``time_boot_ms`` stamp received at local monotonic ``received_ns``."""
        bound = time_boot_ms * 1_000_000 - received_ns
        if self._offset_ns is not None and bound < self._offset_ns - 10_000_000_000:
            # The autopilot rebooted (its clock went back by more than 10 s): start over.
            self._bounds.clear()
            self._utc_minus_boot_us = None
        while self._bounds and self._bounds[-1][1] <= bound:
            self._bounds.pop()
        self._bounds.append((received_ns, bound))
        while self._bounds and received_ns - self._bounds[0][0] > _WINDOW_NS:
            self._bounds.popleft()
        self._offset_ns = self._bounds[0][1]

    def observe_system_time(self, time_unix_usec: int, time_boot_ms: int, received_ns: int) -> None:
        """Take a SYSTEM_TIME: its boot stamp, and its UTC time when the autopilot has one."""
        self.observe_boot_ms(time_boot_ms, received_ns)
        if time_unix_usec >= _UTC_VALID_AFTER_US:
            self._utc_minus_boot_us = time_unix_usec - time_boot_ms * 1000

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

    def time_usec(self, local_ns: int) -> int:
        """The ``time_usec`` to put in a message about something that happened at ``local_ns``.

        UTC on the autopilot's own clock when it has one, which ArduPilot converts back to its
        boot time to age the data; else time since the autopilot booted; else (not synced yet)
        time since the companion booted. PX4 stamps OBSTACLE_DISTANCE on receipt, and ArduPilot
        falls back to its receipt time for values that are not UTC, so the last two are safe.
        """
        boot_ns = self.to_autopilot_boot_ns(local_ns)
        if boot_ns is None:
            return max(local_ns // 1000, 0)
        if self._utc_minus_boot_us is not None:
            return boot_ns // 1000 + self._utc_minus_boot_us
        return max(boot_ns // 1000, 0)
