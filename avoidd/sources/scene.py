"""Ray-cast rendering of a synthetic outdoor scene as a rectified stereo pair with exact depth.

The world frame is the rig's level frame: X forward, Y right, Z down, ground at Z = 0, the left
camera at (0, 0, -h) and the right camera one baseline along its own x axis; both share the
rig's pitch and the vehicle's roll and pitch. The scene holds
textured ground, boxes and poles standing on it, an optional far tree line (a cylinder around the
rig) and sky at infinity. Textures are procedural value noise defined on the surfaces in metres and
band-limited to the pixel footprint, so both views see the same surface pattern without aliasing.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from avoidd.perception.frames import camera_to_level
from avoidd.types import FloatArray, GroundTruth, Image, Mount, RectifiedRig

BoolArray = npt.NDArray[np.bool_]
Indices = npt.NDArray[np.intp]

SKY_ID = 0
GROUND_ID = 1
BACKDROP_ID = 2
FIRST_OBSTACLE_ID = 3

_BACKDROP_HEIGHT_M = 14.0
_OCTAVE_BASE_M = 0.015
_OCTAVES = 10
_SUN = np.array([0.45, 0.35, -0.82], dtype=np.float32) / np.float32(
    np.linalg.norm([0.45, 0.35, -0.82])
)


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


@dataclass(frozen=True)
class Scene:
    """Everything the renderer needs besides the rig.

    Attributes:
        camera_height_m: Height of the camera centres above the ground.
        camera_pitch_deg: Pitch of the rig, positive up.
        obstacles: Boxes and poles; obstacle ``i`` gets object id ``FIRST_OBSTACLE_ID + i``.
        backdrop_m: Radius of the tree line around the rig, or None for open sky.
        seed: Seed of the textures.
        vehicle_roll_deg: Roll of the vehicle carrying the rig (positive right side down).
        vehicle_pitch_deg: Pitch of the vehicle (positive nose up), applied after the rig's
            own pitch: the camera looks along the mount pitch turned by the vehicle attitude.
    """

    camera_height_m: float
    camera_pitch_deg: float
    obstacles: tuple[Box | Pole, ...]
    backdrop_m: float | None
    seed: int
    vehicle_roll_deg: float = 0.0
    vehicle_pitch_deg: float = 0.0


class RenderedPair(NamedTuple):
    """A rendered stereo pair (BGR, noise free) and the left view's ground truth."""

    left: FloatArray
    right: FloatArray
    truth: GroundTruth


class _Hits:
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


def camera_rotation(
    pitch_deg: float, vehicle_roll_deg: float = 0.0, vehicle_pitch_deg: float = 0.0
) -> FloatArray:
    """Rotation from the optical frame (x right, y down, z forward) to the rig's world frame.

    Args:
        pitch_deg: Mount pitch of the rig, positive up.
        vehicle_roll_deg: Vehicle roll, positive right side down.
        vehicle_pitch_deg: Vehicle pitch, positive nose up.

    Returns:
        3x3 float32 matrix.
    """
    pose = camera_to_level(Mount(pitch_deg=pitch_deg), vehicle_roll_deg, vehicle_pitch_deg)
    return np.asarray(pose.rotation, dtype=np.float32)


@functools.lru_cache(maxsize=8)
def pixel_rays(
    rig: RectifiedRig,
    pitch_deg: float,
    vehicle_roll_deg: float = 0.0,
    vehicle_pitch_deg: float = 0.0,
) -> FloatArray:
    """World-frame ray of every pixel, scaled so that the ray parameter is the optical depth.

    Args:
        rig: The rectified rig.
        pitch_deg: Rig pitch, positive up.
        vehicle_roll_deg: Vehicle roll, positive right side down.
        vehicle_pitch_deg: Vehicle pitch, positive nose up.

    Returns:
        (H*W, 3) float32 directions.
    """
    v, u = np.mgrid[0 : rig.height, 0 : rig.width].astype(np.float32)
    optical = np.stack(
        [
            (u - np.float32(rig.cx)) / np.float32(rig.fx),
            (v - np.float32(rig.cy)) / np.float32(rig.fy),
            np.ones_like(u),
        ],
        axis=-1,
    ).reshape(-1, 3)
    rotation = camera_rotation(pitch_deg, vehicle_roll_deg, vehicle_pitch_deg)
    rays: FloatArray = optical @ rotation.T
    rays.flags.writeable = False  # shared between frames through the cache
    return rays


def _hash01(i: npt.NDArray[np.int64], j: npt.NDArray[np.int64], salt: int) -> FloatArray:
    """Integer lattice hash to [0, 1) (no period within any practical scene)."""
    mask = np.uint64(0xFFFFFFFF)
    h = (i.astype(np.uint64) * np.uint64(0x9E3779B1)) ^ (
        j.astype(np.uint64) * np.uint64(0x85EBCA77)
    )
    h = (h ^ np.uint64((salt * 0xC2B2AE3D) & 0xFFFFFFFF)) & mask
    h ^= h >> np.uint64(15)
    h = (h * np.uint64(0x2C1B3C6D)) & mask
    h ^= h >> np.uint64(12)
    h = (h * np.uint64(0x297A2D39)) & mask
    h ^= h >> np.uint64(15)
    return (h.astype(np.float32) * np.float32(1.0 / 4294967296.0)).astype(np.float32)


def _value_noise(s: FloatArray, u: FloatArray, salt: int) -> FloatArray:
    fs = np.floor(s)
    fu = np.floor(u)
    i = fs.astype(np.int64)
    j = fu.astype(np.int64)
    a = s - fs
    b = u - fu
    a = a * a * (3.0 - 2.0 * a)
    b = b * b * (3.0 - 2.0 * b)
    top = _hash01(i, j, salt) * (1 - a) + _hash01(i + 1, j, salt) * a
    bottom = _hash01(i, j + 1, salt) * (1 - a) + _hash01(i + 1, j + 1, salt) * a
    return (top * (1 - b) + bottom * b).astype(np.float32)


def surface_texture(s: FloatArray, u: FloatArray, footprint_m: FloatArray, salt: int) -> FloatArray:
    """Multi-octave value noise in [0, 1]; octaves finer than two pixel footprints fade out.

    Args:
        s: First surface coordinate in metres.
        u: Second surface coordinate in metres.
        footprint_m: Size of the pixel on the surface in metres.
        salt: Texture seed (differs per surface).

    Returns:
        Texture value per point.
    """
    total = np.zeros_like(s)
    weight = np.zeros_like(s)
    for octave in range(_OCTAVES):
        wavelength = _OCTAVE_BASE_M * (2.0**octave)
        fade = np.clip(wavelength / np.maximum(footprint_m, 1e-6) - 1.0, 0.0, 1.0)
        active = fade > 0
        if not active.any():
            continue
        noise = _value_noise(
            s[active] / np.float32(wavelength) + np.float32(octave * 17.3),
            u[active] / np.float32(wavelength) - np.float32(octave * 5.1),
            salt * 31 + octave,
        )
        total[active] += fade[active] * (noise - 0.5)
        weight[active] += fade[active] * fade[active]
    # Independent octaves add in variance: normalising by the root of the summed squared
    # weights keeps the contrast the same however many octaves the footprint lets through.
    contrast = np.where(weight > 0, total / np.sqrt(np.maximum(weight, 1e-6)), 0.0)
    return np.clip(0.5 + 1.2 * contrast, 0.0, 1.0).astype(np.float32)


def _intersect_ground(hits: _Hits, origin: FloatArray, rays: FloatArray) -> None:
    down = rays[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(down > 1e-6, -origin[2] / down, np.inf).astype(np.float32)
    x = origin[0] + t * rays[:, 0]
    y = origin[1] + t * rays[:, 1]
    hits.offer(t, GROUND_ID, x, y, np.array([0.0, 0.0, -1.0], dtype=np.float32))


def _intersect_vertical_cylinder(
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


def _intersect_pole(
    hits: _Hits,
    origin: FloatArray,
    rays: FloatArray,
    pole: Pole,
    surface_id: int,
    where: Indices | None,
) -> None:
    radius = pole.diameter_m / 2.0
    centre = (pole.forward_m, pole.right_m)
    t, arc, z, normal = _intersect_vertical_cylinder(
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


def _intersect_box(
    hits: _Hits,
    origin: FloatArray,
    rays: FloatArray,
    box: Box,
    surface_id: int,
    where: Indices | None,
) -> None:
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


def _sky(rays: FloatArray) -> FloatArray:
    unit = rays / np.linalg.norm(rays, axis=1, keepdims=True)
    elevation = np.clip(-unit[:, 2], -1.0, 1.0)
    return np.asarray(0.75 + 0.2 * elevation, dtype=np.float32)


def _albedo_tint(surface_id: int) -> tuple[float, FloatArray]:
    if surface_id == GROUND_ID:
        return 0.55, np.array([0.55, 0.75, 0.65], dtype=np.float32)
    if surface_id == BACKDROP_ID:
        return 0.45, np.array([0.45, 0.8, 0.5], dtype=np.float32)
    rng = np.random.default_rng(surface_id)
    return 0.6, rng.uniform(0.55, 1.0, size=3).astype(np.float32)


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


def _screen_window(
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


def _render_view(
    scene: Scene, rig: RectifiedRig, rays: FloatArray, origin: FloatArray, rotation: FloatArray
) -> tuple[FloatArray, _Hits]:
    hits = _Hits(rays.shape[0])
    _intersect_ground(hits, origin, rays)
    if scene.backdrop_m is not None:
        t, arc, z, normal = _intersect_vertical_cylinder(
            origin, rays, (0.0, 0.0), scene.backdrop_m, _BACKDROP_HEIGHT_M, inside=True
        )
        hits.offer(t, BACKDROP_ID, arc, z, normal)
    for index, obstacle in enumerate(scene.obstacles):
        surface_id = FIRST_OBSTACLE_ID + index
        where = _screen_window(obstacle, origin, rotation, rig)
        subset = rays if where is None else rays[where]
        if subset.shape[0] == 0:
            continue
        if isinstance(obstacle, Box):
            _intersect_box(hits, origin, subset, obstacle, surface_id, where)
        else:
            _intersect_pole(hits, origin, subset, obstacle, surface_id, where)

    ray_norm = np.linalg.norm(rays, axis=1)
    unit = rays / ray_norm[:, None]
    image = np.empty((rays.shape[0], 3), dtype=np.float32)
    sky = hits.ids == SKY_ID
    image[sky] = _sky(rays[sky])[:, None] * np.array([1.0, 0.95, 0.85], dtype=np.float32)
    for surface_id in np.unique(hits.ids[~sky]):
        where = hits.ids == surface_id
        normal = hits.normal[where]
        cos_incidence = np.abs(np.sum(normal * unit[where], axis=1))
        distance = hits.t[where] * ray_norm[where]
        footprint = distance / np.float32(rig.fx) / np.maximum(cos_incidence, 0.05)
        texture = surface_texture(
            hits.s[where], hits.u[where], footprint, scene.seed * 101 + int(surface_id)
        )
        albedo, tint = _albedo_tint(int(surface_id))
        light = 0.55 + 0.45 * np.clip(normal @ -_SUN, 0.0, 1.0)
        value = albedo * (0.25 + 0.75 * texture) * light
        image[where] = value[:, None] * tint[None, :]
    return image.reshape(rig.height, rig.width, 3), hits


def render_pair(scene: Scene, rig: RectifiedRig) -> RenderedPair:
    """Render both views of the scene and the left view's ground truth.

    Args:
        scene: The scene.
        rig: The rectified rig (``doffs_px`` must be 0: both views share cx).

    Returns:
        Noise-free BGR images in [0, 1] and the exact geometry of the left view.

    Raises:
        ValueError: The rig has a principal point offset, which the renderer does not model.
    """
    if rig.doffs_px != 0.0:
        raise ValueError("the synthetic renderer needs a rig with doffs = 0")
    attitude = (scene.camera_pitch_deg, scene.vehicle_roll_deg, scene.vehicle_pitch_deg)
    rays = pixel_rays(rig, *attitude)
    rotation = camera_rotation(*attitude)
    left_origin = np.array([0.0, 0.0, -scene.camera_height_m], dtype=np.float32)
    # The right camera sits one baseline along the optical x axis, wherever that points.
    right_origin = left_origin + np.float32(rig.baseline_m) * rotation[:, 0]
    left, hits = _render_view(scene, rig, rays, left_origin, rotation)
    right, _ = _render_view(scene, rig, rays, right_origin, rotation)
    depth = hits.t.reshape(rig.height, rig.width)
    with np.errstate(invalid="ignore"):
        points = np.where(np.isfinite(hits.t)[:, None], hits.t[:, None] * rays, np.inf)
    truth = GroundTruth(
        depth_m=depth.astype(np.float32),
        object_id=hits.ids.reshape(rig.height, rig.width),
        points_m=points.reshape(rig.height, rig.width, 3).astype(np.float32),
    )
    return RenderedPair(left, right, truth)


def to_uint8(image: FloatArray, noise: FloatArray | None = None) -> Image:
    """Quantise a rendered image in [0, 1] to 8 bits, adding sensor noise in grey levels.

    Args:
        image: Rendered image in [0, 1].
        noise: Optional additive noise in grey levels, broadcastable to the image.

    Returns:
        The uint8 image.
    """
    scaled = image * np.float32(255.0)
    if noise is not None:
        scaled = scaled + noise
    return np.asarray(np.clip(np.rint(scaled), 0, 255), dtype=np.uint8)
