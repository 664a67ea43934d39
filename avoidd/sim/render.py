"""A fast stereo renderer for simulated worlds: rectified grey pairs and the left view's depth.

Every pixel's ray is intersected analytically with the ground, the tree line and, inside the
screen window each obstacle covers, with that obstacle (slabs for a yawed box, a quadratic for
a cylinder): depth is exact, and the work per obstacle is the size it has on screen.

Obstacles span their own heights (a bar above the ground shows its underside to a camera
below it), and moving ones are drawn where they are at the frame's time. The hits are shaded
by :mod:`avoidd.sim.shading` (texture by each surface's level, light, sky, noise).

Measured by ``avoidd bench --sim-render`` (see ``docs/simulation.md``).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt

from avoidd.config.sim_world import TextureLevel
from avoidd.perception.frames import camera_to_level
from avoidd.sim.shading import SKY_ID, Hits, Shader, SurfaceTable
from avoidd.sim.world import SimBox, SimCylinder, World
from avoidd.types import FloatArray, GroundTruth, Image, Mount, RectifiedRig

__all__ = [
    "FIRST_OBSTACLE_ID",
    "GROUND_ID",
    "SKY_ID",
    "RenderedStereo",
    "StereoRenderer",
    "camera_pose",
]

AnyFloat = npt.NDArray[np.floating[Any]]
AnyArray = npt.NDArray[Any]

GROUND_ID = 1
TREELINE_ID = 2
FIRST_OBSTACLE_ID = 3

_TREELINE_HEIGHT_M = 14.0
_NEAR_M = 0.05
_NOISE_FIELDS = 6
_SUN_NED = np.array([-0.45, -0.35, 0.82]) / np.linalg.norm([0.45, 0.35, 0.82])
"""Direction the sunlight travels (down, from the north-east)."""


class RenderedStereo:
    """One rendered pair: 8-bit grey views and the left view's exact geometry."""

    def __init__(self, left: Image, right: Image, depth_m: FloatArray, ids: npt.NDArray[np.int16]):
        self.left = left
        self.right = right
        self.depth_m = depth_m
        self.ids = ids

    def truth(self) -> GroundTruth:
        """The left view's depth and surface ids as the pipeline's ground truth (no points)."""
        points = np.full((*self.depth_m.shape, 3), np.nan, dtype=np.float32)
        return GroundTruth(self.depth_m, self.ids, points)


def camera_pose(
    mount: Mount,
    north_m: float,
    east_m: float,
    down_m: float,
    yaw_rad: float,
    roll_deg: float,
    pitch_deg: float,
) -> tuple[FloatArray, FloatArray]:
    """The left camera's rotation (optical to NED) and centre (NED) for a vehicle state."""
    level = camera_to_level(mount, roll_deg, pitch_deg)
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    heading = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    rotation = heading @ np.asarray(level.rotation, dtype=np.float64)
    centre = np.array([north_m, east_m, down_m]) + heading @ np.asarray(level.translation)
    return rotation, centre


def _light(normal_ned: FloatArray) -> FloatArray:
    """Lambert shading with an ambient floor (normals: (..., 3))."""
    return np.asarray(0.55 + 0.45 * np.clip(normal_ned @ -_SUN_NED, 0.0, 1.0), dtype=np.float32)


class StereoRenderer:
    """Renders one head's rectified pair of a world from any vehicle state.

    Args:
        world: The world.
        rig: The head's rectified rig (``doffs_px`` must be 0).
        mount: The head's mount on the vehicle.
        noise_std: Sensor noise in grey levels.
    """

    def __init__(
        self, world: World, rig: RectifiedRig, mount: Mount, noise_std: float = 1.0
    ) -> None:
        if rig.doffs_px != 0.0:
            raise ValueError("the simulator renders rigs with doffs = 0 only")
        self.world = world
        self.rig = rig
        self.mount = mount
        self.noise_std = noise_std
        v, u = np.mgrid[0 : rig.height, 0 : rig.width].astype(np.float64)
        self._optical = np.stack(
            [(u - rig.cx) / rig.fx, (v - rig.cy) / rig.fy, np.ones_like(u)], axis=-1
        )
        self._ray_length = np.linalg.norm(self._optical, axis=-1).astype(np.float32)
        rng = np.random.default_rng(world.seed)
        albedo = np.concatenate([[0.0, 0.5, 0.42], rng.uniform(0.45, 0.75, len(world.obstacles))])
        levels: list[TextureLevel] = ["flat", "full", "full"]  # sky, ground, tree line
        levels += [o.texture for o in world.obstacles]
        self._shader = Shader(SurfaceTable.of(rng, albedo, levels), rig.fx)
        # A small bank of noise fields, drawn from per frame (drawing fresh Gaussian noise
        # for every pixel costs as much as rendering).
        noise_rng = np.random.default_rng(world.seed + 1)
        self._noise = [
            noise_rng.normal(0.0, noise_std, (rig.height, rig.width)).astype(np.float32)
            for _ in range(_NOISE_FIELDS)
        ]

    def render(
        self,
        north_m: float,
        east_m: float,
        down_m: float,
        yaw_rad: float,
        roll_deg: float = 0.0,
        pitch_deg: float = 0.0,
        rng: np.random.Generator | None = None,
        t_s: float = 0.0,
    ) -> RenderedStereo:
        """Both views from a vehicle state (local NED, attitude in degrees).

        Args:
            north_m: Vehicle position.
            east_m: Vehicle position.
            down_m: Vehicle position (negative above the ground).
            yaw_rad: Heading.
            roll_deg: Roll, positive right side down.
            pitch_deg: Pitch, positive nose up.
            rng: Source of sensor noise (None: no noise).
            t_s: The frame's time (where moving obstacles are).

        Returns:
            The pair and the left view's depth (``inf`` for sky) and surface ids.
        """
        rotation, centre = camera_pose(
            self.mount, north_m, east_m, down_m, yaw_rad, roll_deg, pitch_deg
        )
        rays = (self._optical @ rotation.T).astype(np.float32)
        obstacles = self.world.at(t_s)
        left = self._view(rays, rotation, centre, obstacles)
        right_centre = centre + self.rig.baseline_m * rotation[:, 0]
        right = self._view(rays, rotation, right_centre, obstacles)
        noise: list[FloatArray | None] = [None, None]
        if rng is not None and self.noise_std > 0:
            picks = rng.choice(len(self._noise), size=2, replace=False)
            noise = [self._noise[int(i)] for i in picks]
        return RenderedStereo(
            self._shader.shade(left, rays, self._ray_length, noise[0]),
            self._shader.shade(right, rays, self._ray_length, noise[1]),
            left.t,
            left.ids,
        )

    # --- geometry --------------------------------------------------------------------------

    def _view(
        self,
        rays: FloatArray,
        rotation: FloatArray,
        centre: FloatArray,
        obstacles: tuple[SimBox | SimCylinder, ...],
    ) -> Hits:
        shape = (self.rig.height, self.rig.width)
        hits = Hits(shape)
        everywhere = (slice(None), slice(None))
        cn, ce, cd = (float(x) for x in centre)
        rn, re, rd = rays[..., 0], rays[..., 1], rays[..., 2]
        if cd < 0:
            with np.errstate(divide="ignore", invalid="ignore"):
                t = np.where(rd > 1e-6, -cd / rd, np.inf).astype(np.float32)
            hits.offer(
                everywhere,
                t,
                GROUND_ID,
                cn + t * rn,
                ce + t * re,
                np.abs(rd) / self._ray_length,
                float(_light(np.array([0.0, 0.0, -1.0]))),
            )
        radius = self.world.treeline_m
        if radius is not None and math.hypot(cn, ce) < radius:
            rows = self._treeline_rows(rays, centre, radius)
            self._cylinder(
                hits,
                rows,
                rays[rows],
                centre,
                (0.0, 0.0),
                radius,
                (0.0, _TREELINE_HEIGHT_M),
                TREELINE_ID,
                inside=True,
            )
        for index, obstacle in enumerate(obstacles):
            window = self._window(obstacle, rotation, centre)
            if window is None:
                continue
            surface_id = FIRST_OBSTACLE_ID + index
            if isinstance(obstacle, SimCylinder):
                self._cylinder(
                    hits,
                    window,
                    rays[window],
                    centre,
                    (obstacle.north_m, obstacle.east_m),
                    obstacle.radius_m,
                    (obstacle.bottom_m, obstacle.height_m),
                    surface_id,
                    inside=False,
                )
            else:
                self._box(hits, rays, rotation, centre, obstacle, surface_id)
        return hits

    def _treeline_rows(
        self, rays: FloatArray, centre: FloatArray, radius_m: float
    ) -> tuple[slice, slice]:
        """The rows whose rays can meet the tree line (it spans a band of elevations)."""
        off_m = math.hypot(float(centre[0]), float(centre[1]))
        height_m = -float(centre[2])
        nearest_m, farthest_m = radius_m - off_m, radius_m + off_m
        low = (
            math.atan2(-height_m, nearest_m) if height_m > 0 else math.atan2(-height_m, farthest_m)
        )
        top = _TREELINE_HEIGHT_M - height_m
        high = math.atan2(top, nearest_m) if top > 0 else math.atan2(top, farthest_m)
        # Elevation along each row is extreme at its ends or its middle.
        columns = [0, self.rig.width // 2, self.rig.width - 1]
        sample = rays[:, columns, :]
        elevation = np.arctan2(-sample[..., 2], np.hypot(sample[..., 0], sample[..., 1]))
        inside = (elevation.max(axis=1) >= low - 0.01) & (elevation.min(axis=1) <= high + 0.01)
        found = np.flatnonzero(inside)
        if found.size == 0:
            return slice(0, 0), slice(None)
        return slice(int(found[0]), int(found[-1]) + 1), slice(None)

    def _window(
        self, obstacle: SimBox | SimCylinder, rotation: FloatArray, centre: FloatArray
    ) -> tuple[slice, slice] | None:
        """The screen rectangle the obstacle can cover (None: out of view)."""
        if isinstance(obstacle, SimCylinder):
            half_n = half_e = obstacle.radius_m
        else:
            c, s = abs(math.cos(obstacle.yaw_rad)), abs(math.sin(obstacle.yaw_rad))
            half_n = obstacle.half_length_m * c + obstacle.half_width_m * s
            half_e = obstacle.half_length_m * s + obstacle.half_width_m * c
        corners = np.array(
            [
                (obstacle.north_m + a * half_n, obstacle.east_m + b * half_e, -h)
                for a in (-1, 1)
                for b in (-1, 1)
                for h in (obstacle.bottom_m, obstacle.height_m)
            ]
        )
        return self._project(corners, rotation, centre)

    def _project(
        self, corners_ned: FloatArray, rotation: FloatArray, centre: FloatArray
    ) -> tuple[slice, slice] | None:
        """The screen rectangle round points (N x 3, NED) that bound a shape (None: unseen)."""
        optical = (corners_ned - centre) @ rotation  # rows: points in the camera frame
        z = optical[:, 2]
        rig = self.rig
        if (z <= _NEAR_M).all():
            return None
        if (z <= _NEAR_M).any():
            # Partly behind the camera: its projection is unbounded; take the whole view.
            return slice(None), slice(None)
        u = rig.fx * optical[:, 0] / z + rig.cx
        v = rig.fy * optical[:, 1] / z + rig.cy
        u0, u1 = max(math.floor(float(u.min())), 0), min(math.ceil(float(u.max())) + 1, rig.width)
        v0, v1 = max(math.floor(float(v.min())), 0), min(math.ceil(float(v.max())) + 1, rig.height)
        if u0 >= u1 or v0 >= v1:
            return None
        return slice(v0, v1), slice(u0, u1)

    def _cylinder(
        self,
        hits: Hits,
        window: tuple[slice, slice],
        rays: FloatArray,
        centre: FloatArray,
        axis_ne: tuple[float, float],
        radius_m: float,
        extent_m: tuple[float, float],
        surface_id: int,
        inside: bool,
    ) -> None:
        on, oe = float(centre[0]) - axis_ne[0], float(centre[1]) - axis_ne[1]
        rn, re, rd = rays[..., 0], rays[..., 1], rays[..., 2]
        a = rn * rn + re * re
        b = on * rn + oe * re
        c = on * on + oe * oe - radius_m * radius_m
        disc = b * b - a * c
        with np.errstate(divide="ignore", invalid="ignore"):
            root = np.sqrt(np.maximum(disc, 0.0))
            t = ((-b + root) if inside else (-b - root)) / a
        down = float(centre[2]) + t * rd
        hit = (disc > 0) & (t > _NEAR_M) & (down <= -extent_m[0]) & (down >= -extent_m[1])
        t = np.where(hit, t, np.inf).astype(np.float32)
        pn, pe = on + t * rn, oe + t * re
        with np.errstate(invalid="ignore"):
            arc = np.arctan2(pe, pn) * radius_m
            normal_n, normal_e = pn / radius_m, pe / radius_m
            cos = np.abs(normal_n * rn + normal_e * re) / np.sqrt(a + rd * rd)
        with np.errstate(invalid="ignore"):
            sunward = -(normal_n * _SUN_NED[0] + normal_e * _SUN_NED[1])
        light = 0.55 + 0.45 * np.clip(sunward, 0, 1)
        if inside:
            light = np.float32(0.8)  # the tree line: lit from the inside, evenly
        hits.offer(window, t, surface_id, arc, down, cos, light)

    def _box(
        self,
        hits: Hits,
        rays: FloatArray,
        rotation: FloatArray,
        centre: FloatArray,
        box: SimBox,
        surface_id: int,
    ) -> None:
        """Offer the faces of a box the camera is outside of, each over its own screen window.

        A ray enters a convex box through a face whose outer side the camera is on, so only
        those faces (three at most) are intersected: a plane each, then a bounds check in it.
        A face covers less of the screen than the box, and each pixel costs a few operations
        per face rather than a slab test on all three axes. Faces are offered along the
        length, across, then top and bottom; a pixel on an edge keeps the nearer hit, the
        first on a tie (float rounding may pick the other face there than a slab test would).
        """
        co, si = math.cos(box.yaw_rad), math.sin(box.yaw_rad)
        on, oe, od = float(centre[0]) - box.north_m, float(centre[1]) - box.east_m, float(centre[2])
        # The camera in the box frame: along its length (a), across it (c), down (d).
        pa, pc = on * co + oe * si, -on * si + oe * co
        half_a, half_c, height = box.half_length_m, box.half_width_m, box.height_m
        bottom = -box.bottom_m
        for axis, plane, normal_ned in _facing_box_faces(pa, pc, od, box):
            corners = _face_corners_ned(box, axis, plane)
            window = self._project(corners, rotation, centre)
            if window is None:
                continue
            part = rays[window]
            rn, re, rd = part[..., 0], part[..., 1], part[..., 2]
            ra = rn * np.float32(co) + re * np.float32(si)
            rc = re * np.float32(co) - rn * np.float32(si)
            t: AnyFloat
            s: AnyFloat
            u: AnyFloat
            toward: AnyFloat
            with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
                if axis == 0:
                    t = (plane - pa) / ra
                    s = pc + t * rc
                    u = od + t * rd
                    inside = (np.abs(s) <= half_c) & (u <= bottom) & (u >= -height)
                    toward = ra
                elif axis == 1:
                    t = (plane - pc) / rc
                    s = pa + t * ra
                    u = od + t * rd
                    inside = (np.abs(s) <= half_a) & (u <= bottom) & (u >= -height)
                    toward = rc
                else:
                    t = (plane - od) / rd
                    s = pa + t * ra
                    u = pc + t * rc
                    inside = (np.abs(s) <= half_a) & (np.abs(u) <= half_c)
                    toward = rd
                t = np.where(inside & (t > _NEAR_M), t, np.inf).astype(np.float32)
            cos = np.abs(toward) / self._ray_length[window]
            hits.offer(window, t, surface_id, s, u, cos, float(_light(normal_ned)))


def _facing_box_faces(
    pa: float, pc: float, od: float, box: SimBox
) -> list[tuple[int, float, FloatArray]]:
    """The faces of a box whose outer side a point is on (box frame: along, across, down).

    Returns:
        Per face: its axis (0 along the length, 1 across, 2 down), the plane's coordinate on
        that axis, and its outward normal in NED (the underside faces down, away from the sun:
        a camera sees it under a bar above the ground).
    """
    co, si = math.cos(box.yaw_rad), math.sin(box.yaw_rad)
    faces: list[tuple[int, float, FloatArray]] = []
    if pa > box.half_length_m:
        faces.append((0, box.half_length_m, np.array([co, si, 0.0])))
    elif pa < -box.half_length_m:
        faces.append((0, -box.half_length_m, np.array([-co, -si, 0.0])))
    if pc > box.half_width_m:
        faces.append((1, box.half_width_m, np.array([-si, co, 0.0])))
    elif pc < -box.half_width_m:
        faces.append((1, -box.half_width_m, np.array([si, -co, 0.0])))
    if od < -box.height_m:
        faces.append((2, -box.height_m, np.array([0.0, 0.0, -1.0])))
    elif od > -box.bottom_m:
        faces.append((2, -box.bottom_m, np.array([0.0, 0.0, 1.0])))
    return faces


def _face_corners_ned(box: SimBox, axis: int, plane: float) -> FloatArray:
    """The four corners (NED) of the box face on ``axis`` at ``plane``."""
    half_a, half_c, height = box.half_length_m, box.half_width_m, box.height_m
    bottom = -box.bottom_m
    if axis == 0:
        local = [(plane, c, d) for c in (-half_c, half_c) for d in (bottom, -height)]
    elif axis == 1:
        local = [(a, plane, d) for a in (-half_a, half_a) for d in (bottom, -height)]
    else:
        local = [(a, c, plane) for a in (-half_a, half_a) for c in (-half_c, half_c)]
    co, si = math.cos(box.yaw_rad), math.sin(box.yaw_rad)
    return np.array(
        [(box.north_m + a * co - c * si, box.east_m + a * si + c * co, d) for a, c, d in local]
    )
