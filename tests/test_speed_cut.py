"""The top speed the cameras can stop for (issue 53 item 4: thin obstacles).

A head first reads its smallest obstacle (``sectors.min_size_m``) where it spans
``THIN_MIN_PX`` pixels; an obstacle not read yet cannot slow the vehicle, so the top speed is
cut to a stop within that range less the clearance, after the configured latency.
"""

from __future__ import annotations

import logging
import math
from types import SimpleNamespace

import pytest

from avoidd.config import AvoidanceConfig
from avoidd.daemon.avoidance import AvoidanceLoop
from avoidd.planner.cycle import MIN_TOP_SPEED_M_S, PlanningCycle, within_sight
from avoidd.planner.speed import perception_speed_m_s
from avoidd.sim.heads import rig_for
from avoidd.vision.depth import THIN_MIN_PX, resolved_range_m, thin_range_m


def test_thin_range_is_where_the_smallest_obstacle_spans_its_pixels() -> None:
    rig = rig_for("320x240", None)  # f = 200 px, B = 0.12 m
    assert thin_range_m(rig, 0.05, 50.0) == pytest.approx(200.0 * 0.05 / THIN_MIN_PX)
    assert thin_range_m(rig, 0.30, 50.0) == pytest.approx(200.0 * 0.30 / THIN_MIN_PX)
    # The resolved range is a ceiling: nothing beyond it is read at all.
    assert thin_range_m(rig, 0.30, resolved_range_m(rig, 0.5)) == resolved_range_m(rig, 0.5)


def test_the_top_speed_is_cut_to_a_stop_within_the_thin_range() -> None:
    config = AvoidanceConfig(enabled=True, max_speed_m_s=5.0)  # clearance 1.5, 2 m/s2, 0.4 s
    cut = within_sight(config, 8.0)
    expected = -2.0 * 0.4 + math.sqrt((2.0 * 0.4) ** 2 + 2.0 * 2.0 * (8.0 - 1.5))
    assert cut.max_speed_m_s == pytest.approx(expected)  # 4.36 m/s
    assert perception_speed_m_s(8.0, 1.5, 2.0, 0.4) == pytest.approx(expected)
    # A stop from the cut speed fits: latency run plus braking within 8 m less the clearance.
    v = cut.max_speed_m_s
    assert v * 0.4 + v * v / (2 * 2.0) <= 8.0 - 1.5 + 1e-9
    # Slow enough already, or no cameras to judge: unchanged (the same object).
    assert within_sight(AvoidanceConfig(max_speed_m_s=3.0), 8.0).max_speed_m_s == 3.0
    assert within_sight(config, None) is config
    # Heads that read nothing thin beyond the clearance still leave a crawl.
    assert within_sight(config, 1.0).max_speed_m_s == MIN_TOP_SPEED_M_S


def test_the_cycle_keeps_the_cut_when_the_speed_is_raised_in_flight() -> None:
    config = AvoidanceConfig(enabled=True, max_speed_m_s=5.0)
    cycle = PlanningCycle(config, 20.0, 8.0)
    assert cycle.planner.config.max_speed_m_s == pytest.approx(4.36, abs=0.01)
    assert cycle.config.max_speed_m_s == 5.0  # the settings as given stay what is reported
    cycle.reconfigure(config.model_copy(update={"max_speed_m_s": 20.0}))
    assert cycle.planner.config.max_speed_m_s == pytest.approx(4.36, abs=0.01)
    cycle.reconfigure(config.model_copy(update={"max_speed_m_s": 2.0}))
    assert cycle.planner.config.max_speed_m_s == 2.0
    assert PlanningCycle(config, 20.0).planner.config.max_speed_m_s == 5.0


def test_the_daemon_says_when_it_cuts_the_top_speed(caplog: pytest.LogCaptureFixture) -> None:
    vehicle = SimpleNamespace(mode=None, link_up=True, reboots=0, wants_origin=False)
    config = AvoidanceConfig(enabled=True, max_speed_m_s=5.0)
    with caplog.at_level(logging.WARNING, logger="avoidd.daemon.avoidance"):
        loop = AvoidanceLoop(config, None, vehicle, None, lambda *a: None, 20.0, 8.0)  # type: ignore[arg-type]
    assert loop.planner.config.max_speed_m_s < 5.0
    (record,) = [r for r in caplog.records if "cut to" in r.getMessage()]
    assert "5.0 m/s cut to 4.4 m/s" in record.getMessage()
    assert "8.0 m" in record.getMessage()
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="avoidd.daemon.avoidance"):
        AvoidanceLoop(config, None, vehicle, None, lambda *a: None, 20.0, 30.0)  # type: ignore[arg-type]
    assert not [r for r in caplog.records if "cut to" in r.getMessage()]


def test_the_cut_counts_the_delay_the_speed_law_counts() -> None:
    # With no configured latency the speed law still counts one setpoint period (20 Hz) and
    # the autopilot's 0.2 s response: so does the cut.
    config = AvoidanceConfig(enabled=True, max_speed_m_s=10.0, latency_ms=0)
    latency_s = 1.0 / 20.0 + 0.2
    expected = -2.0 * latency_s + math.sqrt((2.0 * latency_s) ** 2 + 2.0 * 2.0 * (8.0 - 1.5))
    assert within_sight(config, 8.0).max_speed_m_s == pytest.approx(expected)


def test_no_size_promised_means_no_cut() -> None:
    rig = rig_for("320x240", None)
    assert thin_range_m(rig, 0.0, 24.0) == math.inf
    config = AvoidanceConfig(enabled=True, max_speed_m_s=5.0)
    assert within_sight(config, thin_range_m(rig, 0.0, 24.0)) is config


def test_the_floor_is_said_as_a_floor(caplog: pytest.LogCaptureFixture) -> None:
    vehicle = SimpleNamespace(mode=None, link_up=True, reboots=0, wants_origin=False)
    config = AvoidanceConfig(enabled=True, max_speed_m_s=5.0)
    with caplog.at_level(logging.WARNING, logger="avoidd.daemon.avoidance"):
        AvoidanceLoop(config, None, vehicle, None, lambda *a: None, 20.0, 1.0)  # type: ignore[arg-type]
    (record,) = [r for r in caplog.records if "cut to" in r.getMessage()]
    assert "cut to its floor of 0.5 m/s" in record.getMessage()
