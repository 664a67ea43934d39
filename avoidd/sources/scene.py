"""Ray-cast rendering of a synthetic outdoor scene as a rectified stereo pair with exact depth.

The world frame is the rig's level frame: X forward, Y right, Z down, ground at Z = 0, the left
camera at (0, 0, -h) and the right camera one baseline along its own x axis; both share the
rig's pitch and the vehicle's roll and pitch. The scene holds
textured ground, boxes and poles standing on it, an optional far tree line (a cylinder around the
rig) and sky at infinity. Textures (:mod:`avoidd.sources.texture`) are procedural value noise
defined on the surfaces in metres and band-limited to the pixel footprint, so both views see the
same surface pattern without aliasing.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from avoidd.perception.frames import camera_to_level
from avoidd.sources.raycast import (
    GROUND_ID,
    SKY_ID,
    Box,
    Hits,
    Pole,
    intersect_box,
    intersect_ground,
    intersect_pole,
    intersect_vertical_cylinder,
    screen_window,
)
from avoidd.sources.texture import surface_texture
from avoidd.types import FloatArray, GroundTruth, Image, Mount, RectifiedRig

__all__ = [
    "BACKDROP_ID",
    "FIRST_OBSTACLE_ID",
    "GROUND_ID",
    "SKY_ID",
    "Box",
    "Pole",
    "RenderedPair",
    "Scene",
    "camera_rotation",
    "pixel_rays",
    "render_pair",
    "to_uint8",
]

BoolArray = npt.NDArray[np.bool_]
Indices = npt.NDArray[np.intp]

BACKDROP_ID = 2
FIRST_OBSTACLE_ID = 3

_BACKDROP_HEIGHT_M = 14.0
_SUN = np.array([0.45, 0.35, -0.82], dtype=np.float32) / np.float32(
    np.linalg.norm([0.45, 0.35, -0.82])
)


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


def _render_view(
    scene: Scene, rig: RectifiedRig, rays: FloatArray, origin: FloatArray, rotation: FloatArray
) -> tuple[FloatArray, Hits]:
    hits = Hits(rays.shape[0])
    intersect_ground(hits, origin, rays)
    if scene.backdrop_m is not None:
        t, arc, z, normal = intersect_vertical_cylinder(
            origin, rays, (0.0, 0.0), scene.backdrop_m, _BACKDROP_HEIGHT_M, inside=True
        )
        hits.offer(t, BACKDROP_ID, arc, z, normal)
    for index, obstacle in enumerate(scene.obstacles):
        surface_id = FIRST_OBSTACLE_ID + index
        where = screen_window(obstacle, origin, rotation, rig)
        subset = rays if where is None else rays[where]
        if subset.shape[0] == 0:
            continue
        if isinstance(obstacle, Box):
            intersect_box(hits, origin, subset, obstacle, surface_id, where)
        else:
            intersect_pole(hits, origin, subset, obstacle, surface_id, where)

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
