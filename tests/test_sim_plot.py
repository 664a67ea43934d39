"""The simulator's picture: cut to the flight, legend off the map, closest approach, time marks."""

from __future__ import annotations

import math
from pathlib import Path

from avoidd.config.sim import load_world
from avoidd.sim.plot import FlightTrack, plot_track
from avoidd.sim.world import World


def _wall_world(tmp_path: Path) -> World:
    path = tmp_path / "wall.yaml"
    path.write_text(
        "version: 1\nobstacles:\n"
        "  - {shape: wall, start_ne_m: [12, -25], end_ne_m: [12, 25], thickness_m: 0.3}\n"
    )
    return World.from_config(load_world(path))


def test_the_map_is_cut_to_the_flight_and_the_closest_approach_is_named(tmp_path: Path) -> None:
    # A 50 m wall across a 10 m flight: the map is the flight's, not the wall's.
    times = [0.1 * k for k in range(101)]
    north = [0.1 * k for k in range(101)]
    clearance = [11.5 - n for n in north]
    clearance[60] = 0.8  # the closest step, at 6.0 s
    track = FlightTrack(
        "a flight",
        _wall_world(tmp_path),
        times,
        north,
        [0.0] * len(times),
        [1.0] * len(times),
        clearance,
        0.9,
        (10.0, 2.0),
    )
    out = tmp_path / "plot.png"
    (west, east, south, north_m), labels = plot_track(track, out)
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert -5.0 < west < 0.0 and 2.0 < east < 7.0  # the path and the goal, padded
    assert -5.0 < south < 0.0 and 10.0 < north_m < 15.0
    assert "closest: 0.80 m at 6.0 s" in labels
    assert {"goal", "start", "edge clearance < 0.9 m"} <= set(labels)


def test_a_flight_without_samples_still_draws(tmp_path: Path) -> None:
    track = FlightTrack("nothing flown", _wall_world(tmp_path), [], [], [], [], [], 0.9, None)
    extent, labels = plot_track(track, tmp_path / "empty.png")
    assert labels == [] and extent == (-4.0, 4.0, -4.0, 4.0)


def test_a_moving_obstacle_is_drawn_where_it_was_at_the_closest_approach(tmp_path: Path) -> None:
    path = tmp_path / "mover.yaml"
    path.write_text(
        "version: 1\nobstacles:\n"
        "  - {shape: pole, north_m: 5, east_m: -4, motion: {by_ne_m: [0, 8], speed_m_s: 1}}\n"
    )
    world = World.from_config(load_world(path))
    times = [0.1 * k for k in range(61)]
    north = [t for t in times]
    clearance = [
        math.dist((n, 0.0), (5.0, -4.0 + t)) - 0.5 for n, t in zip(north, times, strict=True)
    ]
    track = FlightTrack(
        "crossing", world, times, north, [0.0] * 61, [1.0] * 61, clearance, 0.9, None
    )
    _, labels = plot_track(track, tmp_path / "mover.png")
    assert "movers at the closest" in labels
    closest = min(range(61), key=lambda k: clearance[k])
    assert f"closest: {clearance[closest]:.2f} m at {times[closest]:.1f} s" in labels
