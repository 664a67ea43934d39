"""The external-SITL runner's flight samples: the window a failed flight shows."""

from __future__ import annotations

import itertools

from avoidd.sim.external import Sample, window_around_minimum


def _flight() -> list[Sample]:
    # 20 Hz for 20 s; the edge comes nearest (0.3 m) at 12 s.
    samples = []
    for i in range(400):
        t_s = i / 20.0
        samples.append(
            Sample(t_s, t_s, 0.0, 2.5, 1.0, 0.3 + abs(t_s - 12.0), (1.0, 0.0), "moving", (1.2, 0.0))
        )
    return samples


def test_the_window_holds_the_closest_approach_and_its_seconds_around_thinned() -> None:
    window = window_around_minimum(_flight(), 2.0)
    times = [s.t_s for s in window]
    assert min(window, key=lambda s: s.clearance_m).clearance_m == 0.3
    assert 12.0 in times
    assert times[0] >= 10.0 and times[-1] <= 14.0
    assert times[0] <= 10.2 and times[-1] >= 13.8  # the whole 4 s, not a part
    assert all(b - a >= 0.2 - 1e-9 for a, b in itertools.pairwise(times) if b != 12.0)
    assert 18 <= len(window) <= 22  # 5 a second, not 20
    assert window_around_minimum([], 2.0) == []


def test_a_sample_describes_where_how_fast_and_what_the_planner_wanted() -> None:
    line = _flight()[240].describe()
    assert "12.0 s" in line and "edge  0.30" in line
    assert "v +1.00 +0.00" in line and "set +1.20 +0.00" in line and "moving" in line
    bare = Sample(1.0, 0.0, 0.0, 2.5, 0.0, 3.0).describe()
    assert "set" not in bare and "None" in bare
