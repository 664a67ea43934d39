"""Frame source sections of a head: synthetic scene, recorded files, V4L2 cameras."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import AfterValidator, Field, field_validator, model_validator

from avoidd.config.base import ConfigPath, Lax, Strict, _existing_file, _existing_path


class SyntheticObstacleConfig(Strict):
    """An obstacle of the synthetic scene, standing on the ground.

    ``forward_m``/``right_m`` locate the centre of its footprint relative to the camera. A box is
    ``width_m`` across (right) and ``depth_m`` deep (forward); a pole is a vertical cylinder of
    diameter ``width_m``.

    Attributes:
        shape: ``box`` or ``pole``.
        forward_m: Footprint centre ahead of the camera.
        right_m: Footprint centre right of the camera.
        width_m: Extent across (a pole's diameter).
        depth_m: Extent along the view (boxes).
        height_m: Height above the ground.
    """

    shape: Literal["box", "pole"]
    forward_m: float = Field(gt=0.0, le=200.0)
    right_m: float = Field(0.0, ge=-200.0, le=200.0)
    width_m: float = Field(1.0, gt=0.0, le=100.0)
    depth_m: float = Field(1.0, gt=0.0, le=100.0)
    height_m: float = Field(3.0, gt=0.0, le=100.0)


def _default_obstacles() -> list[SyntheticObstacleConfig]:
    return [
        # Its nearest point, the front-left corner (5.0 m, 1.82 m), is at 20.0 deg: bin 4.
        SyntheticObstacleConfig(
            shape="box", forward_m=5.5, right_m=2.42, width_m=1.2, depth_m=1.0, height_m=3.0
        ),
        SyntheticObstacleConfig(shape="pole", forward_m=9.0, right_m=-3.5, width_m=0.3, height_m=5),
        SyntheticObstacleConfig(
            shape="box", forward_m=14.0, right_m=-0.5, width_m=3.0, depth_m=2.0, height_m=4.0
        ),
    ]


class SyntheticSourceConfig(Strict):
    """A rendered scene: textured ground, boxes and poles, a far tree line; exact depth known.

    ``camera_pitch_deg`` is the head's mount pitch (the head's ``mount.pitch_deg`` must say the
    same); ``vehicle_roll_deg`` and ``vehicle_pitch_deg`` tilt the whole rig and travel with
    each frame as its recorded attitude, as does ``camera_height_m`` as its height.

    Attributes:
        fps: Frames per second rendered.
        seed: Seed of the textures and noise.
        camera_height_m: Camera height above the ground (recorded with each frame).
        camera_pitch_deg: Camera tilt; must equal the head's ``mount.pitch_deg``.
        vehicle_roll_deg: Roll of the whole rig (recorded with each frame).
        vehicle_pitch_deg: Pitch of the whole rig (recorded with each frame).
        noise_std: Grey-level noise added to each view.
        approach_speed_mps: The scene moves towards the camera at this speed (0: still), down to
            ``min_forward_m``, then starts over.
        min_forward_m: Nearest an obstacle comes while approaching.
        backdrop_m: Distance of the far tree line (null: sky only).
        obstacles: The obstacles standing on the ground (default: a box, a pole and a far box).
    """

    kind: Literal["synthetic"]
    fps: float = Field(15.0, ge=0.1, le=240.0)
    seed: int = Field(1, ge=0)
    camera_height_m: float = Field(1.5, gt=0.05, le=100.0)
    camera_pitch_deg: float = Field(0.0, ge=-45.0, le=45.0)
    vehicle_roll_deg: float = Field(0.0, ge=-45.0, le=45.0)
    vehicle_pitch_deg: float = Field(0.0, ge=-45.0, le=45.0)
    noise_std: float = Field(1.5, ge=0.0, le=20.0)
    approach_speed_mps: float = Field(0.0, ge=0.0, le=30.0)
    min_forward_m: float = Field(1.0, gt=0.0, le=200.0)
    backdrop_m: float | None = Field(45.0, gt=1.0, le=10_000.0)
    obstacles: list[SyntheticObstacleConfig] = Field(default_factory=_default_obstacles)


class FilesSourceConfig(Strict):
    """Recorded frames: a folder with ``left/`` and ``right/`` images, or a side-by-side video.

    Attributes:
        path: A folder with ``left/`` and ``right/`` (and optional ``frames.csv``), or a
            side-by-side video.
        fps: Pacing in ``run`` (null: from ``frames.csv`` times, else 10 fps; a video's own
            rate); replay reads as fast as it can.
        loop: Start over at the end (``run`` only; replay reads once).
    """

    kind: Literal["files"]
    path: Annotated[ConfigPath, AfterValidator(_existing_path)]
    fps: float | None = Field(None, ge=0.1, le=240.0)
    loop: bool = False


class V4l2SourceConfig(Strict):
    """Live cameras through V4L2: two devices (left, right) or one side-by-side device.

    A camera that fails is reopened after ``reopen_min_s``, the wait doubling up to
    ``reopen_max_s``.

    Attributes:
        devices: Two devices (left, right) or one side-by-side device: /dev/videoN or
            /dev/v4l/by-id/....
        width: Width of one eye in pixels.
        height: Height in pixels.
        fps: Frames per second asked of the camera.
        fourcc: Pixel format asked of the camera (MJPG, YUYV...; null: the driver's default).
        reopen_min_s: First wait before reopening a failed camera.
        reopen_max_s: Longest wait (the wait doubles up to it).
    """

    kind: Literal["v4l2"]
    devices: list[str] = Field(min_length=1, max_length=2)
    width: int = Field(gt=0, le=8192)
    height: int = Field(gt=0, le=8192)
    fps: float = Field(30.0, ge=0.1, le=480.0)
    fourcc: str | None = "MJPG"
    reopen_min_s: float = Field(0.5, ge=0.05, le=60.0)
    reopen_max_s: float = Field(10.0, ge=0.05, le=600.0)

    @model_validator(mode="after")
    def _backoff(self) -> V4l2SourceConfig:
        if self.reopen_min_s > self.reopen_max_s:
            raise ValueError(
                f"reopen_min_s ({self.reopen_min_s:g} s) is above reopen_max_s "
                f"({self.reopen_max_s:g} s): the back-off grows from the first to the second; "
                "swap them or raise reopen_max_s"
            )
        return self

    @field_validator("fourcc")
    @classmethod
    def _fourcc(cls, value: str | None) -> str | None:
        if value is not None and len(value) != 4:
            raise ValueError("a FOURCC has exactly 4 characters, e.g. MJPG or YUYV")
        return value

    @field_validator("devices")
    @classmethod
    def _devices(cls, value: list[str]) -> list[str]:
        for device in value:
            if not (device.startswith("/dev/") or device.isdigit()):
                raise ValueError(
                    f"'{device}' is not a device; use /dev/videoN or /dev/v4l/by-id/..."
                )
        return value


class SimSourceConfig(Strict):
    """A simulated world rendered from the pose the autopilot reports (an external SITL).

    For flying avoidd, unchanged, against a SITL autopilot (ArduPilot, PX4) that simulates
    the vehicle: each frame is the world seen from the newest LOCAL_POSITION_NED and ATTITUDE
    avoidd heard (see ``avoidd/sim/pose_source.py``). Only ``avoidd run`` opens it; the
    calibration must be a rectified rig without ``doffs``.

    Attributes:
        world: A world file (``sitl/worlds/*.yaml``).
        fps: Frames per second.
        origin_ne_m: Where in the world the autopilot's local origin (its home) is, north and
            east.
        noise_std: Sensor noise in grey levels.
    """

    kind: Literal["sim"]
    world: Annotated[ConfigPath, AfterValidator(_existing_file)]
    fps: float = Field(10.0, ge=0.1, le=60.0)
    origin_ne_m: Annotated[
        tuple[
            Annotated[float, Field(ge=-1000.0, le=1000.0)],
            Annotated[float, Field(ge=-1000.0, le=1000.0)],
        ],
        Lax,
    ] = (0.0, 0.0)
    noise_std: float = Field(1.0, ge=0.0, le=20.0)


SourceConfig = Annotated[
    SyntheticSourceConfig | FilesSourceConfig | V4l2SourceConfig | SimSourceConfig,
    Field(discriminator="kind"),
]
