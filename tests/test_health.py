"""The daemon's pure health rules: boot grace, stale heads, HEARTBEAT state, transitions."""

from __future__ import annotations

from avoidd.daemon.health import (
    BOOT_GRACE_NS,
    Transition,
    in_boot_grace,
    is_fresh,
    mav_state,
    stale_heads,
    transitions,
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


def test_transitions_both_ways_stale_first_then_by_name() -> None:
    assert transitions(set(), set()) == []
    assert transitions({"front"}, {"front"}) == []
    assert transitions(set(), {"rear", "front"}) == [
        Transition("front", stale=True),
        Transition("rear", stale=True),
    ]
    assert transitions({"front", "rear"}, set()) == [
        Transition("front", stale=False),
        Transition("rear", stale=False),
    ]
    assert transitions({"front"}, {"rear"}) == [
        Transition("rear", stale=True),
        Transition("front", stale=False),
    ]


def test_a_head_going_stale_and_recovering_over_time() -> None:
    """The check the daemon runs: stale set at each time, transitions between checks."""
    latest: dict[str, int | None] = {"front": None, "rear": None}
    seen: list[Transition] = []
    previous: frozenset[str] = frozenset()
    for step in range(100):
        now_ns = STARTED_NS + step * 100 * MS
        if step >= 3:
            latest["front"] = now_ns - 20 * MS
        if 3 <= step < 40 or step >= 60:
            latest["rear"] = now_ns - 20 * MS
        stale = stale_heads(latest, STARTED_NS, now_ns, MAX_AGE_NS)
        if stale is None:
            continue
        seen += transitions(previous, stale)
        previous = stale
    # rear's last frame is at step 39: stale once it is older than 300 ms (step 43), back at 60.
    assert seen == [Transition("rear", stale=True), Transition("rear", stale=False)]
