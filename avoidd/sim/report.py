"""The batch table and its totals, from run summaries as JSON (:meth:`Summary.as_json`).

One line per run, then the totals against the planner's targets: collisions, reachable goals
reached, dead ends ending in "no path", clearance kept in 99 % of the steps, side changes per
detour, and the flight speed while moving in the pole forests and box fields as a share of
the maximum speed.
"""

from __future__ import annotations

import itertools
import math
from typing import TYPE_CHECKING, Any

from avoidd.sim.summary import MOVING_M_S

if TYPE_CHECKING:
    from avoidd.sim.external import ExternalSummary

SPEED_KINDS = ("pole_forest", "boxes")
"""The generators whose runs the speed target is measured on."""


def _number(value: float | None, digits: int = 2) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def format_table(results: list[dict[str, Any]]) -> str:
    """One line per run: collision, clearance, goal, times, speed, side changes, verdict.

    ``v move`` is the speed while moving (distance over the time faster than 0.3 m/s),
    ``start`` the delay from the goal to moving, ``nopath`` the time to "no path"; ``sides``
    is the most side changes within one detour (a detour lasts while the chosen way is more
    than 10 degrees off the goal's direction).
    """
    lines = [
        f"{'scenario':24} {'seed':>4} {'coll':>4} {'min m':>6} {'p01 m':>6} {'goal':>4} "
        f"{'t goal':>6} {'v move':>6} {'start':>5} {'nopath':>6} {'sides':>5} {'end':9} "
        f"{'wall s':>6} verdict"
    ]
    for r in results:
        lines.append(
            f"{r['name'][:24]:24} {r['seed']:>4} {'YES' if r['collided'] else 'no':>4} "
            f"{_number(r['min_clearance_m']):>6} {_number(r['clearance_p01_m']):>6} "
            f"{'yes' if r['reached'] else 'no':>4} {_number(r['time_to_goal_s'], 1):>6} "
            f"{_number(r.get('moving_speed_m_s')):>6} {_number(r.get('start_delay_s'), 1):>5} "
            f"{_number(r.get('no_path_s'), 1):>6} {r.get('detour_side_changes', 0):>5} "
            f"{r['end_state'][:9]:9} "
            f"{_number(r.get('wall_time_s'), 1):>6} "
            f"{'pass' if r['passed'] else 'FAIL: ' + '; '.join(r['failures'])}"
        )
    return "\n".join(lines)


def format_totals(results: list[dict[str, Any]]) -> str:
    """The batch against the targets, in three lines (see the module's docstring)."""
    count = len(results)
    collisions = sum(r["collided"] for r in results)
    reached = [r for r in results if r["reached"]]
    times = [r["time_to_goal_s"] for r in reached]
    mean_time = sum(times) / len(times) if times else None
    passed = sum(r["passed"] for r in results)
    reachable = [r for r in results if r.get("reachable", True)]
    reached_reachable = sum(r["reached"] for r in reachable)
    dead_ends = [r for r in results if not r.get("reachable", True)]
    no_path = sum(r["end_state"] == "no path" for r in dead_ends)
    clear = sum(
        r["clearance_p01_m"] is None or r["clearance_p01_m"] >= r.get("clearance_target_m", 0.0)
        for r in results
    )
    sides = max((r.get("detour_side_changes", 0) for r in results), default=0)
    share = 100.0 * reached_reachable / len(reachable) if reachable else 100.0
    return (
        f"{count} runs: {collisions} collisions, {len(reached)} goals reached, "
        f"{passed} passed; mean time to goal {_number(mean_time, 1)} s\n"
        f"reachable goals reached {reached_reachable}/{len(reachable)} ({share:.1f} %); "
        f"dead ends ending 'no path' {no_path}/{len(dead_ends)}; clearance >= margin - 0.1 m "
        f"in 99 % of steps: {clear}/{count} runs; most side changes in one detour: {sides}\n"
        f"{_speeds(results)}{_times(results)}"
    )


def _speeds(results: list[dict[str, Any]]) -> str:
    """The speed while moving in pole forests and box fields, as a share of the maximum."""
    shares = [
        100.0 * r["moving_speed_m_s"] / r["speed_limit_m_s"]
        for r in results
        if r.get("world_kind") in SPEED_KINDS
        and r.get("moving_speed_m_s") is not None
        and r.get("speed_limit_m_s")
    ]
    if not shares:
        return "flight speed while moving in pole forests/boxes: no such runs"
    return (
        f"flight speed while moving in pole forests/boxes: {sum(shares) / len(shares):.0f} % "
        f"of max speed on average, lowest {min(shares):.0f} % ({len(shares)} runs)"
    )


def _times(results: list[dict[str, Any]]) -> str:
    """The start delays, the times to "no path", the stale-to-hold time."""
    parts = []
    delays = [r["start_delay_s"] for r in results if r.get("start_delay_s") is not None]
    if delays:
        parts.append(
            f"start delay {sum(delays) / len(delays):.1f} s on average, at most {max(delays):.1f} s"
        )
    no_paths = [r["no_path_s"] for r in results if r.get("no_path_s") is not None]
    if no_paths:
        parts.append(f"'no path' after at most {max(no_paths):.1f} s")
    holds = [r["stale_to_hold_ms"] for r in results if r.get("stale_to_hold_ms") is not None]
    if holds:
        parts.append(f"stale to zero-velocity setpoint at most {max(holds):.0f} ms")
    return "".join(f"; {part}" for part in parts)


def external_row(summary: ExternalSummary, wall_time_s: float | None = None) -> dict[str, Any]:
    """A real-time or SITL run's summary as one line of :func:`format_table`.

    The speed while moving, the 1 % clearance quantile and the time of the first "no path"
    come from the position samples and avoidd's state changes; what only the lockstep run
    counts (side changes per detour, the start delay) reads as none.
    """
    samples = summary.samples
    steps = [(a, b) for a, b in itertools.pairwise(samples) if a.speed_m_s > MOVING_M_S]
    flown_m = sum(math.dist((a.north_m, a.east_m), (b.north_m, b.east_m)) for a, b in steps)
    moving_s = sum(b.t_s - a.t_s for a, b in steps)
    clearances = sorted(s.clearance_m for s in samples)
    p01 = clearances[int(0.01 * (len(clearances) - 1))] if clearances else None
    states = [entry.split(" ", 1) for entry in summary.states]
    no_path = next((float(t) for t, state in states if state == "no path"), None)
    return {
        "name": summary.scenario,
        "seed": summary.mode,
        "collided": summary.collided,
        "min_clearance_m": summary.min_clearance_m if samples else None,
        "clearance_p01_m": p01,
        "reached": summary.reached_s is not None,
        "time_to_goal_s": summary.reached_s,
        "moving_speed_m_s": flown_m / moving_s if moving_s > 0 else None,
        "start_delay_s": None,
        "no_path_s": no_path,
        "detour_side_changes": "-",
        "end_state": states[-1][-1] if states else "-",
        "wall_time_s": wall_time_s,
        "passed": summary.passed,
        "failures": summary.failures,
    }
