"""Pure health rules over the heads' freshness: boot grace, stale set, HEARTBEAT state, changes.

Nothing here reads a clock or does I/O: every function takes the capture time of each head's
newest processed frame (None before its first) and ``now_ns`` on the same monotonic clock.
"""

from __future__ import annotations

from collections.abc import Mapping, Set
from dataclasses import dataclass

from avoidd.mavlink import codec as mav

BOOT_GRACE_NS = 5_000_000_000
"""After start, how long heads that have produced nothing yet count as booting, not stale."""


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


@dataclass(frozen=True)
class Transition:
    """A head's freshness changed.

    Attributes:
        head: The head's name.
        stale: True if it went stale, False if it recovered.
    """

    head: str
    stale: bool


def transitions(before: Set[str], after: Set[str]) -> list[Transition]:
    """What changed between two stale sets: heads that went stale, then heads that recovered.

    Args:
        before: The stale heads at the previous check.
        after: The stale heads now.

    Returns:
        One transition per changed head, those that went stale first, each group by name.
    """
    went_stale = [Transition(name, stale=True) for name in sorted(after - before)]
    recovered = [Transition(name, stale=False) for name in sorted(before - after)]
    return went_stale + recovered
