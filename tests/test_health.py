"""The daemon's pure health rules: boot grace, stale heads, HEARTBEAT state, reporting."""

from __future__ import annotations

from avoidd.daemon.health import (
    BOOT_GRACE_NS,
    Reported,
    in_boot_grace,
    is_fresh,
    mav_state,
    stale_heads,
    stale_reason,
)
from avoidd.mavlink import codec as mav

MS = 1_000_000
MAX_AGE_NS = 300 * MS
STARTED_NS = 1_000 * MS


def test_freshness_is_age_against_max_age() -> None:
    now_ns = 10_000 * MS
    assert is_fresh(now_ns - MAX_AGE_NS, now_ns, MAX_AGE_NS)
    assert not is_fresh(now_ns - MAX_AGE_NS - 1, now_ns, MAX_AGE_NS)
    assert not is_fresh(None, now_ns, MAX_AGE_NS)


def test_boot_grace_until_a_head_produces_or_the_grace_ends() -> None:
    nothing = {"front": None, "rear": None}
    early_ns = STARTED_NS + BOOT_GRACE_NS - 1
    assert in_boot_grace(nothing, STARTED_NS, early_ns)
    assert stale_heads(nothing, STARTED_NS, early_ns, MAX_AGE_NS) is None
    assert mav_state(stale_heads(nothing, STARTED_NS, early_ns, MAX_AGE_NS)) == mav.MAV_STATE_BOOT
    # One head producing ends the grace: the other one is stale at once.
    one = {"front": early_ns - 10 * MS, "rear": None}
    assert not in_boot_grace(one, STARTED_NS, early_ns)
    assert stale_heads(one, STARTED_NS, early_ns, MAX_AGE_NS) == {"rear"}
    # So does the end of the grace, even if nothing came.
    late_ns = STARTED_NS + BOOT_GRACE_NS
    assert stale_heads(nothing, STARTED_NS, late_ns, MAX_AGE_NS) == {"front", "rear"}
    assert mav_state(stale_heads(nothing, STARTED_NS, late_ns, MAX_AGE_NS)) == (
        mav.MAV_STATE_CRITICAL
    )


def test_one_stale_head_among_fresh_ones_is_critical() -> None:
    now_ns = STARTED_NS + 60_000 * MS
    latest = {"front": now_ns - 50 * MS, "left": now_ns - 301 * MS, "right": now_ns}
    stale = stale_heads(latest, STARTED_NS, now_ns, MAX_AGE_NS)
    assert stale == {"left"}
    assert mav_state(stale) == mav.MAV_STATE_CRITICAL
    fresh = {name: now_ns - 10 * MS for name in latest}
    assert stale_heads(fresh, STARTED_NS, now_ns, MAX_AGE_NS) == frozenset()
    assert mav_state(frozenset()) == mav.MAV_STATE_ACTIVE


def _report(
    stale_at: list[bool], step_ms: int = 50, enter_hold_ns: int | None = None
) -> list[tuple[int, bool]]:
    """Feed one head's raw freshness every ``step_ms``; the changes reported, with their step."""
    state = Reported() if enter_hold_ns is None else Reported(enter_hold_ns=enter_hold_ns)
    changes = []
    for step, stale in enumerate(stale_at):
        change = state.update(stale, STARTED_NS + step * step_ms * MS)
        if change is not None:
            changes.append((step, change))
    return changes


def test_a_short_miss_is_not_reported_a_lasting_one_is_once() -> None:
    # 300 ms stale (a late frame under load): nothing reported.
    assert _report([False] * 10 + [True] * 6 + [False] * 50) == []
    # Stale for 2 s: reported once, after 0.5 s; recovered after 2 s of fresh data.
    changes = _report([False] * 10 + [True] * 40 + [False] * 50)
    assert changes == [(20, True), (90, False)]


def test_flapping_under_load_is_one_episode() -> None:
    # Stale 0.6 s, fresh 0.5 s, over and over for 10 s (the demo under CPU load): reported
    # stale once, and fresh again only once the data stays fresh for 2 s.
    pattern = ([True] * 12 + [False] * 10) * 9
    changes = _report(pattern + [False] * 60)
    assert [change for _, change in changes] == [True, False]
    assert changes[1][0] == len(pattern) - 10 + 40  # 2 s after the last stale sample


def test_the_heartbeat_state_goes_critical_at_once_and_does_not_flap() -> None:
    # The HEARTBEAT's own state (no hold on the way in): CRITICAL with the first stale sample,
    # ACTIVE after 2 s of fresh data; a 300 ms miss is one CRITICAL spell of 2.3 s, and
    # flapping under load is one episode, as for the announcements.
    assert _report([False] * 10 + [True] * 6 + [False] * 50, enter_hold_ns=0) == [
        (10, True),
        (56, False),
    ]
    pattern = ([True] * 12 + [False] * 10) * 9
    changes = _report(pattern + [False] * 60, enter_hold_ns=0)
    assert changes == [(0, True), (len(pattern) - 10 + 40, False)]


def test_the_reason_names_where_the_time_went() -> None:
    now_ns = STARTED_NS + 10_000 * MS
    assert stale_reason(now_ns, None, None, MAX_AGE_NS) == "camera lost"
    assert stale_reason(now_ns, now_ns - 2_000 * MS, 10 * MS, MAX_AGE_NS) == "camera lost"
    assert stale_reason(now_ns, now_ns - 10 * MS, 500 * MS, MAX_AGE_NS) == "frames late"
    assert stale_reason(now_ns, now_ns - 10 * MS, 20 * MS, MAX_AGE_NS) == "compute late"
