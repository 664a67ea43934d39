"""The perception targets on rendered scenes with exact truth (see avoidd.evaluation.scenes).

Targets (issue: perception): within the range where one pixel of disparity is at most 10% of
depth, the nearest-obstacle distance has a median error <= 2% and a 95th percentile <= 5%;
every obstacle (all are at least 0.1 m wide) is reported in its bin; obstacle-free ground seen
with roll and pitch up to 20 degrees gives no obstacle bin; the paper's ground-plane geometry
agrees with stereo within 3% at ground contacts where its model holds.
"""

from __future__ import annotations

import pytest

from avoidd.evaluation.scenes import SuiteSummary, contact_suite, run_suite, suite


@pytest.fixture(scope="module")
def summary() -> SuiteSummary:
    return run_suite(suite() + contact_suite())


def test_nearest_distance_error(summary: SuiteSummary) -> None:
    errors = summary.errors_pct
    assert len(errors) == 36
    assert summary.percentile(50) <= 2.0, summary.format()
    assert summary.percentile(95) <= 5.0, summary.format()


def test_every_obstacle_in_its_bin_and_no_false_bins(summary: SuiteSummary) -> None:
    assert summary.missed == [], summary.format()
    assert summary.false_bins == [], summary.format()
    ground = [r for r in summary.results if r.name.startswith("ground")]
    assert len(ground) == 10 and all(r.measured_m is None for r in ground)


def test_ground_plane_geometry_agrees_with_stereo_at_contacts(summary: SuiteSummary) -> None:
    contacts = summary.contact_errors_pct
    assert len(contacts) >= 10
    assert max(abs(c) for c in contacts) <= 3.0, summary.format()
