"""Pure health rules over the heads' freshness: boot grace, stale set, HEARTBEAT, reporting.

Nothing here reads a clock or does I/O: every function takes the capture time of each head's
newest processed frame (None before its first) and ``now_ns`` on the same monotonic clock.
"""

from __future__ import annotations

from collections.abc import Mapping, Set
from dataclasses import dataclass

from avoidd.mavlink import codec as mav

BOOT_GRACE_NS = 5_000_000_000
"""After start, how long heads that have produced nothing yet count as booting, not stale."""
ENTER_STALE_NS = 500_000_000
"""A head is reported stale once its data has been too old for this long without a break."""
LEAVE_STALE_NS = 2_000_000_000
"""A stale head is reported fresh again once its data has been fresh this long throughout."""


def is_fresh(t_capture_ns: int | None, now_ns: int, max_age_ns: int) -> bool:
    """Whether a head's newest frame is young enough to be sent.

    Args:
        t_capture_ns: Capture time of the head's newest processed frame, None before the first.
        now_ns: The current time.
        max_age_ns: Age beyond which data is stale.

    Returns:
        True if there is a frame and it is at most ``max_age_ns`` old.
    """
    return t_capture_ns is not None and now_ns - t_capture_ns <= max_age_ns


def in_boot_grace(
    latest_capture_ns: Mapping[str, int | None], started_ns: int, now_ns: int
) -> bool:
    """Whether the daemon is still booting: within the grace and no head has produced yet.

    Args:
        latest_capture_ns: Per head name, the capture time of its newest processed frame.
        started_ns: When the daemon started.
        now_ns: The current time.

    Returns:
        True during the first :data:`BOOT_GRACE_NS` while every head is still without data.
    """
    return now_ns - started_ns < BOOT_GRACE_NS and all(
        t_ns is None for t_ns in latest_capture_ns.values()
    )


def stale_heads(
    latest_capture_ns: Mapping[str, int | None], started_ns: int, now_ns: int, max_age_ns: int
) -> frozenset[str] | None:
    """The heads without fresh data, or None during the boot grace.

    Args:
        latest_capture_ns: Per head name, the capture time of its newest processed frame.
        started_ns: When the daemon started.
        now_ns: The current time.
        max_age_ns: Age beyond which a head's data is stale.

    Returns:
        The names of the stale heads (empty when all are fresh), or None while booting.
    """
    if in_boot_grace(latest_capture_ns, started_ns, now_ns):
        return None
    return frozenset(
        name for name, t_ns in latest_capture_ns.items() if not is_fresh(t_ns, now_ns, max_age_ns)
    )


def mav_state(stale: Set[str] | None) -> int:
    """HEARTBEAT system status: BOOT, then ACTIVE while every head is fresh, else CRITICAL.

    Args:
        stale: What :func:`stale_heads` returned.

    Returns:
        ``MAV_STATE_BOOT``, ``MAV_STATE_ACTIVE`` or ``MAV_STATE_CRITICAL``.
    """
    if stale is None:
        return mav.MAV_STATE_BOOT
    return mav.MAV_STATE_CRITICAL if stale else mav.MAV_STATE_ACTIVE


@dataclass
class Reported:
    """What has been reported about one head: stale or fresh, and since when it disagrees.

    The data sent is never older than ``max_age_ms``, frame by frame; what is *reported*
    (STATUSTEXT, the HEARTBEAT state) follows with hysteresis, so that a head that misses its
    deadline now and then under load is reported once, not every time (12 stale announcements
    in 44 s were seen, half CRITICAL, which ground stations read aloud).
    """

    stale: bool = False
    differs_since_ns: int | None = None
    enter_hold_ns: int = ENTER_STALE_NS
    """How long the data must be too old before it is reported stale (0 for the HEARTBEAT's
    state: CRITICAL at once, only the way back is held)."""

    def update(self, stale_now: bool, now_ns: int) -> bool | None:
        """Take the head's freshness at ``now_ns``.

        Args:
            stale_now: Whether its data is too old right now.
            now_ns: The current time.

        Returns:
            The new reported state when it changes (True: went stale, False: recovered),
            else None.
        """
        if stale_now == self.stale:
            self.differs_since_ns = None
            return None
        if self.differs_since_ns is None:
            self.differs_since_ns = now_ns
        hold_ns = self.enter_hold_ns if stale_now else LEAVE_STALE_NS
        if now_ns - self.differs_since_ns < hold_ns:
            return None
        self.stale = stale_now
        self.differs_since_ns = None
        return stale_now


def stale_reason(
    now_ns: int, last_frame_ns: int | None, arrival_age_ns: int | None, max_age_ns: int
) -> str:
    """Why a head's data is too old, for the operator.

    Args:
        now_ns: The current time.
        last_frame_ns: When its source last delivered a frame (local time), None if never.
        arrival_age_ns: How old that frame already was when it arrived.
        max_age_ns: The age limit.

    Returns:
        "camera lost" (no frames arrive), "frames late" (they arrive already too old: the
        camera or its driver is slow) or "compute late" (they arrive in time but their results
        do not: the machine cannot keep up).
    """
    if last_frame_ns is None or now_ns - last_frame_ns > max_age_ns:
        return "camera lost"
    if arrival_age_ns is not None and arrival_age_ns > max_age_ns:
        return "frames late"
    return "compute late"
