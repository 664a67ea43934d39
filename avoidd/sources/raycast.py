"""Ray intersections with the synthetic scene's shapes: ground, boxes, vertical cylinders.

Rays are in the rig's level frame (X forward, Y right, Z down, ground at Z = 0); every
function offers its hits to a :class:`Hits` buffer that keeps the nearest per ray.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from avoidd.types import FloatArray, RectifiedRig

Indices = npt.NDArray[np.intp]
SKY_ID = 0
GROUND_ID = 1


@dataclass(frozen=True)
class Box:
    """An axis-aligned box standing on the ground (footprint centre, size in metres)."""

    forward_m: float
    right_m: float
    depth_m: float
    width_m: float
    height_m: float


@dataclass(frozen=True)
class Pole:
    """A vertical cylinder standing on the ground."""

    forward_m: float
    right_m: float
    diameter_m: float
    height_m: float


class Hits:
    """Nearest intersection per ray so far: distance, id, texture coordinates and normal."""

    def __init__(self, count: int) -> None:
        self.t = np.full(count, np.inf, dtype=np.float32)
        self.ids = np.full(count, SKY_ID, dtype=np.int16)
        self.s = np.zeros(count, dtype=np.float32)
        self.u = np.zeros(count, dtype=np.float32)
        self.normal = np.zeros((count, 3), dtype=np.float32)

    def offer(
        self,
        t: FloatArray,
        surface_id: int,
        s: FloatArray,
        u: FloatArray,
        normal: FloatArray,
        where: Indices | None = None,
    ) -> None:
        """Keep the offered hits that are nearer; ``where`` are the rays they belong to."""
        current = self.t if where is None else self.t[where]
        closer = t < current
        if not closer.any():
            return
        index = np.flatnonzero(closer) if where is None else where[closer]
        self.t[index] = t[closer]
        self.ids[index] = surface_id
        self.s[index] = s[closer]
        self.u[index] = u[closer]
        self.normal[index] = normal[closer] if normal.ndim == 2 else normal


def intersect_ground(hits: Hits, origin: FloatArray, rays: FloatArray) -> None:
    """Offer every ray's hit with the ground plane (Z = 0)."""
    down = rays[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(down > 1e-6, -origin[2] / down, np.inf).astype(np.float32)
    x = origin[0] + t * rays[:, 0]
    y = origin[1] + t * rays[:, 1]
    hits.offer(t, GROUND_ID, x, y, np.array([0.0, 0.0, -1.0], dtype=np.float32))


def intersect_vertical_cylinder(
    origin: FloatArray,
    rays: FloatArray,
    centre: tuple[float, float],
    radius: float,
    height: float,
    inside: bool,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Ray and vertical cylinder wall (Z in [-height, 0]): t, arc coordinate, height, normal."""
    ox = origin[0] - centre[0]
    oy = origin[1] - centre[1]
    dx = rays[:, 0]
    dy = rays[:, 1]
    a = dx * dx + dy * dy
    b = 2.0 * (ox * dx + oy * dy)
    c = ox * ox + oy * oy - radius * radius
    disc = b * b - 4.0 * a * c
    with np.errstate(invalid="ignore", divide="ignore"):
        root = np.sqrt(np.maximum(disc, 0.0))
        sign = 1.0 if inside else -1.0
        t = ((-b + sign * root) / (2.0 * a)).astype(np.float32)
    z = origin[2] + t * rays[:, 2]
    ok = (disc >= 0) & (a > 1e-12) & (t > 1e-4) & (z >= -height) & (z <= 0)
    t = np.where(ok, t, np.inf).astype(np.float32)
    px = ox + np.where(ok, t, 0) * dx
    py = oy + np.where(ok, t, 0) * dy
    # The arc coordinate's seam (where the angle wraps) must stay out of sight: behind a pole
    # (seen from the rig, which stands at smaller X) and behind the rig for the tree line.
    facing = -px if not inside else px
    arc = (np.arctan2(py, facing) * radius).astype(np.float32)
    normal = np.stack([px, py, np.zeros_like(px)], axis=-1) / np.float32(radius)
    if inside:
        normal = -normal
    return t, arc, z.astype(np.float32), normal.astype(np.float32)


def intersect_pole(
    hits: Hits,
    origin: FloatArray,
    rays: FloatArray,
    pole: Pole,
    surface_id: int,
    where: Indices | None,
) -> None:
    """Offer the hits of rays (the subset ``where``) with a pole's wall and top cap."""
    radius = pole.diameter_m / 2.0
    centre = (pole.forward_m, pole.right_m)
    t, arc, z, normal = intersect_vertical_cylinder(
        origin, rays, centre, radius, pole.height_m, inside=False
    )
    hits.offer(t, surface_id, arc, z, normal, where)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_cap = np.where(np.abs(rays[:, 2]) > 1e-9, (-pole.height_m - origin[2]) / rays[:, 2], -1)
    cx = origin[0] + t_cap * rays[:, 0] - centre[0]
    cy = origin[1] + t_cap * rays[:, 1] - centre[1]
    on_cap = (t_cap > 1e-4) & (cx * cx + cy * cy <= radius * radius)
    t_cap = np.where(on_cap, t_cap, np.inf).astype(np.float32)
    hits.offer(
        t_cap,
        surface_id,
        cx.astype(np.float32),
        cy.astype(np.float32),
        np.array([0.0, 0.0, -1.0], dtype=np.float32),
        where,
    )


def intersect_box(
    hits: Hits,
    origin: FloatArray,
    rays: FloatArray,
    box: Box,
    surface_id: int,
    where: Indices | None,
) -> None:
    """Offer the hits of rays (the subset ``where``) with a box's faces."""
    low = np.array(
        [box.forward_m - box.depth_m / 2, box.right_m - box.width_m / 2, -box.height_m],
        dtype=np.float32,
    )
    high = np.array(
        [box.forward_m + box.depth_m / 2, box.right_m + box.width_m / 2, 0.0], dtype=np.float32
    )
    safe = np.where(np.abs(rays) < 1e-9, np.float32(1e-9), rays)
    t1 = (low - origin) / safe
    t2 = (high - origin) / safe
    t_in = np.minimum(t1, t2)
    t_out = np.maximum(t1, t2)
    axis = np.argmax(t_in, axis=1)
    t_near = np.max(t_in, axis=1)
    t_far = np.min(t_out, axis=1)
    ok = (t_near <= t_far) & (t_near > 1e-4)
    t = np.where(ok, t_near, np.inf).astype(np.float32)
    point = origin + np.where(ok, t_near, 0.0)[:, None] * rays
    # Texture coordinates lie on the face that was hit; the normal faces the ray.
    s = np.where(axis == 0, point[:, 1], point[:, 0]).astype(np.float32)
    u = np.where(axis == 2, point[:, 1], point[:, 2]).astype(np.float32)
    normal = np.zeros_like(rays)
    rows = np.arange(rays.shape[0])
    normal[rows, axis] = -np.sign(rays[rows, axis])
    hits.offer(t, surface_id, s + np.float32(surface_id * 3.7), u, normal.astype(np.float32), where)


def _bounds(obstacle: Box | Pole) -> tuple[FloatArray, FloatArray]:
    """Low and high corners of an obstacle's axis-aligned bounding box (world frame)."""
    if isinstance(obstacle, Box):
        half = (obstacle.depth_m / 2, obstacle.width_m / 2)
    else:
        half = (obstacle.diameter_m / 2, obstacle.diameter_m / 2)
    low = np.array(
        [obstacle.forward_m - half[0], obstacle.right_m - half[1], -obstacle.height_m],
        dtype=np.float32,
    )
    high = np.array([obstacle.forward_m + half[0], obstacle.right_m + half[1], 0.0], np.float32)
    return low, high


def screen_window(
    obstacle: Box | Pole, origin: FloatArray, rotation: FloatArray, rig: RectifiedRig
) -> Indices | None:
    """Pixels (flat indices) whose rays can hit the obstacle, or None to test every ray.

    The eight corners of the bounding box are projected; the rectangle around them (with a
    margin) holds every pixel that can see the obstacle. A corner behind the image plane makes
    the rectangle unbounded, so every ray is tested.
    """
    low, high = _bounds(obstacle)
    corners = np.array(
        [
            [x, y, z]
            for x in (low[0], high[0])
            for y in (low[1], high[1])
            for z in (low[2], high[2])
        ],
        dtype=np.float32,
    )
    optical = (corners - origin) @ rotation
    if np.any(optical[:, 2] < 0.05):
        return None
    u = rig.fx * optical[:, 0] / optical[:, 2] + rig.cx
    v = rig.fy * optical[:, 1] / optical[:, 2] + rig.cy
    u0, u1 = max(int(np.floor(u.min())) - 2, 0), min(int(np.ceil(u.max())) + 3, rig.width)
    v0, v1 = max(int(np.floor(v.min())) - 2, 0), min(int(np.ceil(v.max())) + 3, rig.height)
    if u0 >= u1 or v0 >= v1:
        return np.empty(0, dtype=np.intp)
    rows = np.arange(v0, v1, dtype=np.intp)[:, None] * rig.width
    return (rows + np.arange(u0, u1, dtype=np.intp)[None, :]).ravel()
