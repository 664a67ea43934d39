"""Simulated obstacles: texture levels, bottoms above the ground, motion, 3-D collisions."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from avoidd.config.sim import ScenarioConfig, WorldConfig, load_world
from avoidd.errors import ConfigError
from avoidd.planner.core import Goal
from avoidd.sim.lockstep import RIGS, LockstepRun
from avoidd.sim.obstacles import Motion, SimBox, SimCylinder
from avoidd.sim.render import FIRST_OBSTACLE_ID, GROUND_ID, StereoRenderer, camera_pose
from avoidd.sim.world import World
from avoidd.types import Mount

RIG = RIGS["320x240"]


def _world(obstacles: list[dict[str, Any]]) -> World:
    config = WorldConfig.model_validate({"version": 1, "obstacles": obstacles})
    return World.from_config(config)


def _wall(**extra: Any) -> dict[str, Any]:
    return {"shape": "wall", "start_ne_m": [6.0, -10.0], "end_ne_m": [6.0, 10.0]} | extra


# --- texture levels ------------------------------------------------------------------------


def test_textured_true_and_false_still_read_as_full_and_flat() -> None:
    world = _world([_wall(textured=True), _wall(textured=False), _wall(textured="low"), _wall()])
    assert [o.texture for o in world.obstacles] == ["full", "flat", "low", "full"]


def _wall_patch(texture: Any) -> np.ndarray:
    """A wall's face 6 m ahead, 2.3-2.9 m up (within one row of 1.5 m patches), 8 m across."""
    world = World((SimBox(6.15, 0.0, 0.15, 20.0, 4.0, 0.0, texture),), seed=3, treeline_m=None)
    pair = StereoRenderer(world, RIG, Mount(), noise_std=0.0).render(0.0, 0.0, -2.0, 0.0)
    window = (slice(90, 110), slice(20, 300))
    assert (pair.ids[window] == FIRST_OBSTACLE_ID).all()
    return pair.left[window].astype(np.float64)


def test_texture_levels_show_the_pattern_at_full_low_partial_and_no_contrast() -> None:
    full, low, partial, flat = (_wall_patch(t) for t in ("full", "low", "partial", "flat"))
    assert full.std() > 8.0
    # A tenth of the contrast, round the same mean brightness.
    assert 0.05 * full.std() < low.std() < 0.2 * full.std()
    assert abs(low.mean() - full.mean()) < 10.0
    assert flat.std() == 0.0
    # Patches 1.5 m across (about 50 px at 6 m): some columns flat, some textured.
    column_std = partial.std(axis=0)
    assert (column_std < 0.5).mean() > 0.2
    assert (column_std > 0.5 * full.std(axis=0).mean()).mean() > 0.2


def test_a_texture_level_that_does_not_exist_names_the_line_and_key(tmp_path: Path) -> None:
    path = tmp_path / "w.yaml"
    path.write_text(
        "version: 1\nobstacles:\n  - {shape: pole, north_m: 5, east_m: 0, textured: shiny}\n"
    )
    with pytest.raises(ConfigError) as caught:
        load_world(path)
    lines = caught.value.lines
    assert any(f"{path}:3: obstacles[0].textured" in line for line in lines), lines


# --- above the ground ----------------------------------------------------------------------


def test_a_bottom_at_or_above_the_top_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "w.yaml"
    path.write_text(
        "version: 1\nobstacles:\n"
        "  - {shape: box, north_m: 5, east_m: 0, height_m: 2, bottom_m: 2}\n"
        "  - {shape: pole, north_m: 5, east_m: 2, bottom_m: -1}\n"
    )
    with pytest.raises(ConfigError) as caught:
        load_world(path)
    lines = caught.value.lines
    assert any(f"{path}:3: obstacles[0]: bottom_m 2.0 must be below" in line for line in lines)
    assert any(f"{path}:4: obstacles[1].bottom_m" in line for line in lines), lines


def test_clearance_to_a_bar_is_measured_in_three_dimensions() -> None:
    """A bar 1.8-2.1 m above the ground, 0.3 m thick: the vehicle (0.3 m tall, radius 0.5)
    beside it, under it and beyond its end, at 2 m and at 1.2 m."""
    world = _world([_wall(bottom_m=1.8, height_m=2.1)])
    # Level with it, 3 m short: the horizontal gap less the radius.
    assert world.edge_clearance_m(3.0, 0.0, 2.0, 0.5) == pytest.approx(6.0 - 0.15 - 3.0 - 0.5)
    # Right under it at 1.2 m: its underside is 1.8 - 1.35 = 0.45 m above the vehicle's top.
    assert world.edge_clearance_m(6.0, 0.0, 1.2, 0.5) == pytest.approx(0.45)
    # Under it and 0.5 m short of it: the vertical and horizontal gaps together.
    assert world.edge_clearance_m(5.35, 0.0, 1.2, 0.5) == pytest.approx(math.hypot(0.0, 0.45))
    assert world.edge_clearance_m(4.85, 0.0, 1.2, 0.5) == pytest.approx(math.hypot(0.5, 0.45))
    # Inside it: negative.
    assert world.edge_clearance_m(6.0, 0.0, 2.0, 0.5) < 0.0
    # The horizontal clearance at one altitude sees it only at its heights.
    assert math.isinf(world.clearance_m(3.0, 0.0, 1.2))
    assert world.clearance_m(3.0, 0.0, 2.0) == pytest.approx(2.85)


def test_the_oracle_sees_what_reaches_into_the_height_band() -> None:
    """Rays at 2 m with the daemon's band (2 m below, 2 m above): a bar at flight height and one
    whose underside is within 2 m above are seen; one higher up is not."""
    north = np.array([0.0])
    for bottom, seen in ((1.8, True), (3.9, True), (4.1, False)):
        world = _world([_wall(bottom_m=bottom, height_m=bottom + 0.3)])
        reading = float(world.ray_distances(0.0, 0.0, 2.0, north, band_m=(2.0, 2.0))[0])
        assert (reading == pytest.approx(5.85)) if seen else math.isinf(reading), bottom
        level = float(world.ray_distances(0.0, 0.0, 2.0, north)[0])
        assert (level == pytest.approx(5.85)) if bottom < 2.0 else math.isinf(level), bottom


def _reference_depth(boxes: tuple[SimBox, ...], pose: tuple[float, ...]) -> np.ndarray:
    """Per-pixel ray depth to the nearest box by the slab test in float64 (boxes between their
    bottom and top; no ground)."""
    rotation, centre = camera_pose(Mount(), *pose)
    v, u = np.mgrid[0 : RIG.height, 0 : RIG.width].astype(np.float64)
    rays = np.stack([(u - RIG.cx) / RIG.fx, (v - RIG.cy) / RIG.fy, np.ones_like(u)], -1)
    rays = rays @ rotation.T
    depth = np.full(u.shape, np.inf)
    for box in boxes:
        co, si = math.cos(box.yaw_rad), math.sin(box.yaw_rad)
        to_box = np.array([[co, si, 0.0], [-si, co, 0.0], [0.0, 0.0, 1.0]])
        origin = to_box @ (centre - np.array([box.north_m, box.east_m, 0.0]))
        direction = rays @ to_box.T
        low = np.array([-box.half_length_m, -box.half_width_m, -box.height_m])
        high = np.array([box.half_length_m, box.half_width_m, -box.bottom_m])
        with np.errstate(divide="ignore", invalid="ignore"):
            t0 = (low - origin) / direction
            t1 = (high - origin) / direction
        t_in = np.nanmax(np.minimum(t0, t1), axis=-1)
        t_out = np.nanmin(np.maximum(t0, t1), axis=-1)
        hit = (t_in <= t_out) & (t_in > 0.05) & (t_in < depth)
        depth[hit] = t_in[hit]
    return depth


def _floating_box(rng: np.random.Generator) -> SimBox:
    north, east = float(rng.uniform(3, 8)), float(rng.uniform(-3, 3))
    half_length, half_width = (float(x) for x in rng.uniform(0.3, 2.0, 2))
    bottom = float(rng.uniform(0.5, 3.0))
    top = bottom + float(rng.uniform(0.2, 1.5))
    yaw = float(rng.uniform(-math.pi, math.pi))
    return SimBox(north, east, half_length, half_width, top, yaw, bottom_m=bottom)


def test_boxes_above_the_ground_are_rendered_between_their_bottom_and_top() -> None:
    """Random yawed boxes floating 0.5-3 m up, seen from below, level and above: the depth
    matches a slab reference, undersides included, and the ground shows beneath them."""
    rng = np.random.default_rng(5)
    undersides = 0
    for _ in range(10):
        boxes = tuple(_floating_box(rng) for _ in range(2))
        pose = (0.0, 0.0, -float(rng.uniform(0.3, 4.0)), 0.0, *rng.uniform(-10, 10, 2))
        pair = StereoRenderer(World(boxes, treeline_m=None), RIG, Mount(), 0.0).render(*pose)
        reference = _reference_depth(boxes, pose)
        on_box = pair.ids >= FIRST_OBSTACLE_ID
        compared = on_box | (np.isfinite(reference) & (pair.ids != GROUND_ID))
        assert (on_box[compared] == np.isfinite(reference[compared])).mean() > 0.999
        both = on_box & np.isfinite(reference)
        np.testing.assert_allclose(pair.depth_m[both], reference[both], rtol=1e-4)
        undersides += int(-pose[2] < min(b.bottom_m for b in boxes) and both.any())
        assert (pair.ids == GROUND_ID).any()
    assert undersides > 0


def _holding(obstacles: list[dict[str, Any]], seconds: float) -> LockstepRun:
    """A vehicle at 2 m, its camera unplugged from the start: it holds still (no scan, no
    back-away) while things move."""
    scenario = ScenarioConfig.model_validate(
        {
            "version": 1,
            "name": "hold",
            "world": {"kind": "open"},
            "goal": {"north_m": 20.0, "east_m": 0.0},
            "perception": "oracle",
            "duration_s": seconds,
            "timeline": [{"t_s": 0.0, "action": "camera_unplug"}],
        }
    )
    return LockstepRun(scenario, _world(obstacles), Goal(20.0, 0.0, 2.0))


def test_a_bar_over_the_vehicle_is_no_collision_and_one_at_its_height_is() -> None:
    over = _holding([_wall(start_ne_m=[0.0, -5.0], end_ne_m=[0.0, 5.0], bottom_m=2.5)], 1.0)
    summary = over.run()
    assert not summary.collided
    assert summary.min_clearance_m == pytest.approx(2.5 - 2.15, abs=0.02)
    level = _holding([_wall(start_ne_m=[0.0, -5.0], end_ne_m=[0.0, 5.0], bottom_m=1.9)], 1.0)
    assert level.run().collided


# --- moving obstacles ----------------------------------------------------------------------


def test_a_motion_goes_by_its_displacement_and_back_at_its_speed() -> None:
    motion = Motion(3.0, 4.0, 2.0)  # 5 m at 2 m/s: there at 2.5 s, back at 5 s
    assert motion.offset_ne_m(0.0) == (0.0, 0.0)
    assert motion.offset_ne_m(1.25) == pytest.approx((1.5, 2.0))
    assert motion.offset_ne_m(2.5) == pytest.approx((3.0, 4.0))
    assert motion.offset_ne_m(3.75) == pytest.approx((1.5, 2.0))
    assert motion.offset_ne_m(5.0) == pytest.approx((0.0, 0.0), abs=1e-12)
    assert motion.offset_ne_m(6.25) == pytest.approx((1.5, 2.0))


def test_a_moving_pole_is_where_its_time_puts_it_for_oracle_renderer_and_clearance() -> None:
    world = _world(
        [
            {
                "shape": "pole",
                "north_m": 8.0,
                "east_m": -4.0,
                "diameter_m": 0.4,
                "motion": {"by_ne_m": [0.0, 8.0], "speed_m_s": 2.0},
            }
        ]
    )
    assert isinstance(world.obstacles[0], SimCylinder) and world.moves
    # At 2 s it stands straight ahead, 8 m out.
    assert world.clearance_m(0.0, 0.0, 2.0, t_s=2.0) == pytest.approx(7.8)
    north = np.array([0.0])
    assert world.ray_distances(0.0, 0.0, 2.0, north, t_s=2.0)[0] == pytest.approx(7.8)
    assert math.isinf(world.ray_distances(0.0, 0.0, 2.0, north, t_s=0.0)[0])
    renderer = StereoRenderer(world, RIG, Mount(), noise_std=0.0)
    centre = renderer.render(0.0, 0.0, -2.0, 0.0, t_s=2.0)
    row, column = int(RIG.cy), int(RIG.cx)
    assert centre.ids[row, column] == FIRST_OBSTACLE_ID
    assert centre.depth_m[row, column] == pytest.approx(7.8, abs=0.01)
    assert renderer.render(0.0, 0.0, -2.0, 0.0, t_s=0.0).ids[row, column] != FIRST_OBSTACLE_ID


def test_a_pole_moving_into_a_holding_vehicle_is_a_collision_when_it_arrives() -> None:
    """A pole 0.4 m across comes at 1 m/s from 4 m: the edges touch after 4 - 0.2 - 0.5 = 3.3 s
    (the vehicle holds still; a moving obstacle can hit it)."""
    pole = {
        "shape": "pole",
        "north_m": 4.0,
        "east_m": 0.0,
        "diameter_m": 0.4,
        "motion": {"by_ne_m": [-6.0, 0.0], "speed_m_s": 1.0},
    }
    summary = _holding([pole], 5.0).run()
    assert summary.collided
    assert summary.collision_t_s == pytest.approx(3.3, abs=0.15)


def test_a_motion_to_nowhere_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "w.yaml"
    path.write_text(
        "version: 1\nobstacles:\n  - shape: pole\n    north_m: 5\n    east_m: 0\n"
        "    motion: {by_ne_m: [0, 0], speed_m_s: 1}\n"
        "  - {shape: pole, north_m: 5, east_m: 2, motion: {by_ne_m: [1, 0], speed_m_s: 0}}\n"
    )
    with pytest.raises(ConfigError) as caught:
        load_world(path)
    lines = caught.value.lines
    assert any(f"{path}:6: obstacles[0].motion: a motion goes" in line for line in lines), lines
    assert any(f"{path}:7: obstacles[1].motion.speed_m_s" in line for line in lines), lines
