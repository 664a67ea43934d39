"""The daemon's YAML configuration as frozen, typed models (version 1)."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Annotated, Literal

from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Discriminator,
    Field,
    Tag,
    ValidationInfo,
    field_validator,
    model_validator,
)

from avoidd.mavlink.url import LinkSpec, parse_connection
from avoidd.yamlfile import load_yaml, validate_document


class _Strict(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")


def _resolve_path(value: Path, info: ValidationInfo) -> Path:
    base = (info.context or {}).get("base_dir")
    path = value.expanduser()
    if not path.is_absolute() and base is not None:
        path = Path(base) / path
    return path


ConfigPath = Annotated[Path, AfterValidator(_resolve_path)]
"""A path in the config; relative paths are relative to the config file's folder."""


def _existing_file(value: Path) -> Path:
    if not value.is_file():
        raise ValueError(f"file not found: {value}; check the path (relative to the config file)")
    return value


def _existing_path(value: Path) -> Path:
    if not value.exists():
        raise ValueError(f"not found: {value}; check the path (relative to the config file)")
    return value


class MountConfig(_Strict):
    """Pose of a stereo head in the body FRD frame (see ``avoidd.types.Mount``)."""

    yaw_deg: float = Field(0.0, ge=-180.0, le=360.0)
    pitch_deg: float = Field(0.0, ge=-90.0, le=90.0)
    roll_deg: float = Field(0.0, ge=-180.0, le=180.0)
    position_m: tuple[float, float, float] = (0.0, 0.0, 0.0)


class SyntheticObstacleConfig(_Strict):
    """An obstacle of the synthetic scene, standing on the ground.

    ``forward_m``/``right_m`` locate the centre of its footprint relative to the camera. A box is
    ``width_m`` across (right) and ``depth_m`` deep (forward); a pole is a vertical cylinder of
    diameter ``width_m``.
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


class SyntheticSourceConfig(_Strict):
    """A rendered scene: textured ground, boxes and poles, a far tree line; exact depth known.

    ``camera_pitch_deg`` is the head's mount pitch (the head's ``mount.pitch_deg`` must say the
    same); ``vehicle_roll_deg`` and ``vehicle_pitch_deg`` tilt the whole rig and travel with
    each frame as its recorded attitude, as does ``camera_height_m`` as its height.
    """

    kind: Literal["synthetic"]
    fps: float = Field(15.0, gt=0.0, le=240.0)
    seed: int = Field(1, ge=0)
    camera_height_m: float = Field(1.5, gt=0.05, le=100.0)
    camera_pitch_deg: float = Field(0.0, ge=-45.0, le=45.0)
    vehicle_roll_deg: float = Field(0.0, ge=-45.0, le=45.0)
    vehicle_pitch_deg: float = Field(0.0, ge=-45.0, le=45.0)
    noise_std: float = Field(1.5, ge=0.0, le=20.0)
    approach_speed_mps: float = Field(0.0, ge=0.0, le=30.0)
    min_forward_m: float = Field(1.0, gt=0.0)
    backdrop_m: float | None = Field(45.0, gt=1.0)
    obstacles: list[SyntheticObstacleConfig] = Field(default_factory=_default_obstacles)


class FilesSourceConfig(_Strict):
    """Recorded frames: a folder with ``left/`` and ``right/`` images, or a side-by-side video."""

    kind: Literal["files"]
    path: Annotated[ConfigPath, AfterValidator(_existing_path)]
    fps: float | None = Field(None, gt=0.0, le=240.0)
    loop: bool = False


class V4l2SourceConfig(_Strict):
    """Live cameras through V4L2: two devices (left, right) or one side-by-side device."""

    kind: Literal["v4l2"]
    devices: list[str] = Field(min_length=1, max_length=2)
    width: int = Field(gt=0, le=8192)
    height: int = Field(gt=0, le=8192)
    fps: float = Field(30.0, gt=0.0, le=480.0)
    fourcc: str | None = "MJPG"
    reopen_min_s: float = Field(0.5, gt=0.0)
    reopen_max_s: float = Field(10.0, gt=0.0)

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


SourceConfig = Annotated[
    SyntheticSourceConfig | FilesSourceConfig | V4l2SourceConfig, Field(discriminator="kind")
]


def _multiple_of_16(value: int) -> int:
    if value % 16:
        raise ValueError(f"must be a multiple of 16; use {((value + 15) // 16) * 16}")
    return value


def _odd(value: int) -> int:
    if value % 2 == 0:
        raise ValueError(f"must be odd; use {value + 1}")
    return value


DisparityRange = Annotated[int, Field(ge=16, le=512), AfterValidator(_multiple_of_16)]
"""Width of a disparity search range: a multiple of 16 pixels."""


class SgbmConfig(_Strict):
    """OpenCV semi-global matching; ``p1``/``p2`` default to 8 and 64 times block_size squared.

    ``pad_left`` matches the left border band (the first ``num_disparities`` columns, which
    OpenCV leaves unmatched) by padding both views with replicated columns; estimates whose match
    would fall in the padding are dropped. The band's disparities are less reliable (a near
    object there has no match in the right image), so obstacle detection never uses them; it
    still pays to pad, because SGBM's paths then reach the pixels right of the band with context
    (without it the rendered truth suite's p95 range error rose from 5.0 to 6.4%).
    The defaults (pad, uniqueness 5, P2 64 bs^2) were measured over Middlebury 2014 Q, 2003
    and 2001 together (README, "Stereo quality").
    """

    kind: Literal["sgbm"] = "sgbm"
    min_disparity: int = Field(0, ge=-128, le=256)
    num_disparities: DisparityRange = 64
    block_size: Annotated[int, Field(ge=1, le=15), AfterValidator(_odd)] = 5
    p1: int | None = Field(None, gt=0)
    p2: int | None = Field(None, gt=0)
    uniqueness_ratio: int = Field(5, ge=0, le=100)
    speckle_window_size: int = Field(100, ge=0)
    speckle_range: int = Field(2, ge=0)
    disp12_max_diff: int = Field(1, ge=-1)
    pre_filter_cap: int = Field(63, ge=1, le=255)
    mode: Literal["sgbm", "hh", "sgbm_3way", "hh4"] = "sgbm_3way"
    pad_left: bool = True

    @model_validator(mode="after")
    def _p2_above_p1(self) -> SgbmConfig:
        if self.p1 is not None and self.p2 is not None and self.p2 <= self.p1:
            raise ValueError("p2 must be greater than p1 (p2 penalises large disparity jumps)")
        return self


class SadConfig(_Strict):
    """SAD block matching (OpenCV StereoBM): the paper's first matcher.

    Attributes:
        block_size: Odd window side (5 to 51).
        texture_threshold: Minimum texture (sum of |x-derivative| over the window) to match.
        uniqueness_ratio: Percent by which the best cost must beat the second best.
        pre_filter: ``xsobel`` (OpenCV's default) or ``normalized_response``.
        pad_left: As for SGBM.
    """

    kind: Literal["sad"]
    num_disparities: DisparityRange = 64
    block_size: Annotated[int, Field(ge=5, le=51), AfterValidator(_odd)] = 11
    texture_threshold: int = Field(10, ge=0)
    uniqueness_ratio: int = Field(15, ge=0, le=100)
    speckle_window_size: int = Field(100, ge=0)
    speckle_range: int = Field(2, ge=0)
    disp12_max_diff: int = Field(1, ge=-1)
    pre_filter: Literal["xsobel", "normalized_response"] = "xsobel"
    pad_left: bool = False


class CensusConfig(_Strict):
    """Census transform + sum of Hamming distances (the paper's SHD matcher).

    Attributes:
        pattern: ``sparse5x5`` (8 samples on a 5x5 ring) or ``full5x5`` (24 bits).
        aggregation_px: Side of the window the Hamming distances are summed over (11 in the
            paper).
        max_mean_distance: Drop a match whose mean Hamming distance per pixel exceeds this share
            of the code's bits.
        texture_window_px: Window of the texture test.
        min_texture_std: Minimum grey-level standard deviation in that window; flatter pixels
            are not matched (their census codes carry no information).
        lr_max_diff_px: Left-right check: the right view's match must point back within this.
        speckle_window_size: Islands of similar disparity smaller than this are dropped (0: off).
    """

    kind: Literal["census"]
    num_disparities: Annotated[int, Field(ge=16, le=256), AfterValidator(_multiple_of_16)] = 64
    pattern: Literal["sparse5x5", "full5x5"] = "sparse5x5"
    aggregation_px: Annotated[int, Field(ge=3, le=31), AfterValidator(_odd)] = 11
    max_mean_distance: float = Field(0.35, gt=0.0, le=1.0)
    texture_window_px: Annotated[int, Field(ge=3, le=31), AfterValidator(_odd)] = 7
    min_texture_std: float = Field(1.0, ge=0.0)
    lr_max_diff_px: int = Field(1, ge=0)
    speckle_window_size: int = Field(100, ge=0)


class SegmentConfig(_Strict):
    """The paper's segmentation-based hybrid matcher.

    Lightness (Lab L) is clustered by K-means on its histogram; each cluster is cleaned by a
    morphological opening and split into connected regions; SAD block matching is kept only on
    region boundaries; each region's interior is filled from its boundary disparities (a plane
    fitted to them). Interior pixels are filled, not measured: obstacles never use them.

    Attributes:
        clusters: K of the K-means on lightness.
        open_px: Side of the opening that removes thin fragments of a cluster (odd; 1 = off).
        min_region_px: Regions smaller than this are not filled; their pixels keep the SAD value.
        boundary_px: Width of the boundary band on each side of a region edge.
        block_size: SAD window side (odd).
        texture_threshold: As for ``sad``.
        uniqueness_ratio: As for ``sad``.
        min_boundary_px: Boundary measurements a region needs before its interior is filled.
        max_residual_px: A region is filled only if its boundary disparities fit a plane this
            well (median absolute residual); otherwise it spans a depth edge and stays empty.
        pad_left: As for SGBM.
    """

    kind: Literal["segment"]
    num_disparities: DisparityRange = 64
    clusters: int = Field(8, ge=2, le=16)
    open_px: Annotated[int, Field(ge=1, le=15), AfterValidator(_odd)] = 3
    min_region_px: int = Field(64, ge=1)
    boundary_px: int = Field(2, ge=1, le=8)
    block_size: Annotated[int, Field(ge=5, le=51), AfterValidator(_odd)] = 9
    texture_threshold: int = Field(10, ge=0)
    uniqueness_ratio: int = Field(15, ge=0, le=100)
    min_boundary_px: int = Field(12, ge=3)
    max_residual_px: float = Field(1.0, gt=0.0)
    pad_left: bool = True


def _matcher_kind(value: object) -> str:
    if isinstance(value, dict):
        return str(value.get("kind", "sgbm"))
    return str(getattr(value, "kind", "sgbm"))


MatcherConfig = Annotated[
    Annotated[SgbmConfig, Tag("sgbm")]
    | Annotated[SadConfig, Tag("sad")]
    | Annotated[CensusConfig, Tag("census")]
    | Annotated[SegmentConfig, Tag("segment")],
    Discriminator(_matcher_kind),
]
"""The ``matcher`` section of a head: one of the matchers, chosen by ``kind``."""


class SectorsConfig(_Strict):
    """How a head's obstacle points become the 72 distance bins.

    Attributes:
        min_pixels: Points a bin's nearest cluster needs before it counts as an obstacle, so that
            a few speckles cannot create one.
        cluster_window_px: Width of that cluster in disparity pixels (about the matcher's noise
            band; see ``avoidd.perception.sectors.nearest_cluster``).
        min_valid_fraction: Below this share of measured pixels a bin without an obstacle is
            unknown rather than clear.
        min_size_m: A cluster must also cover a square of this side at its own distance (so
            near clusters need many pixels, and pixels smeared off an edge cannot pass for an
            object). The default is the smallest obstacle avoidd must see: a 5 cm pole.
    """

    min_pixels: int = Field(20, ge=1)
    cluster_window_px: float = Field(0.8, gt=0.0, le=16.0)
    min_valid_fraction: float = Field(0.3, ge=0.0, le=1.0)
    min_size_m: float = Field(0.05, ge=0.0, le=1.0)

    @model_validator(mode="before")
    @classmethod
    def _no_row_band(cls, data: object) -> object:
        if isinstance(data, dict) and "row_band" in data:
            raise ValueError(
                "row_band is gone: obstacles are now points between the ground and the "
                "height band of 'perception' (ground.margin_m, band.above_m, band.below_m); "
                "delete row_band"
            )
        return data


class TextureConfig(_Strict):
    """The paper's adaptive-threshold texture mask.

    A pixel is textured when it differs from the mean (or median) of its ``window_px`` window by
    at least ``offset`` grey levels, or has such a pixel within ``spread_px``; disparities of
    untextured pixels are dropped rather than guessed.
    """

    method: Literal["mean", "median"] = "mean"
    window_px: Annotated[int, Field(ge=3, le=31), AfterValidator(_odd)] = 7
    offset: float = Field(2.0, ge=0.0, le=255.0)
    spread_px: Annotated[int, Field(ge=1, le=31), AfterValidator(_odd)] = 5


class PreprocessConfig(_Strict):
    """Image preparation before matching, as the paper has it; every step off unless asked.

    Attributes:
        resize_scale: Scale both views (and the rig) by this factor before matching (1: off).
        median_px: Median denoise window (0: off; 3, 5 or 7).
        mean_px: Mean (box) denoise window (0: off; odd).
        texture: Adaptive-threshold texture mask (None: off).
    """

    resize_scale: float = Field(1.0, ge=0.25, le=1.0)
    median_px: Literal[0, 3, 5, 7] = 0
    mean_px: Annotated[int, Field(ge=0, le=15)] = 0
    texture: TextureConfig | None = None

    @field_validator("mean_px")
    @classmethod
    def _mean_window(cls, value: int) -> int:
        if value and value % 2 == 0:
            raise ValueError(f"must be 0 or odd; use {value + 1}")
        return value


class PostprocessConfig(_Strict):
    """Disparity post-processing after any matcher.

    Attributes:
        subpixel_refine: One Gauss-Newton step along the epipolar line after the matcher
            (off by default: SGBM and SAD interpolate to 1/16 px themselves, and on the
            Middlebury scenes the extra step raises their sub-pixel error; see the README).
        refine_window_px: Window of that step (odd).
        median_size: Median filter on the disparity over each window's measured pixels (0 off,
            3 or 5).
        speckle_window_px: An extra speckle pass after the median: islands smaller than this
            are dropped (0 off; every matcher already removes speckles in its own step).
        speckle_range_px: Disparity step that separates islands in that pass.
        fill_holes: Also produce a hole-filled depth map (``filled_depth_m``, for display and
            recordings). Obstacles never use it: they see measured pixels only.
        min_texture_snr: Drop disparities where the left view's local contrast (standard
            deviation over ``texture_window_px``) is below this multiple of the frame's
            sensor noise: a match in sky or on a blank wall is a guess (0: off).
        texture_window_px: Window of that test (odd).
    """

    subpixel_refine: bool = False
    refine_window_px: int = Field(7, ge=3, le=21)
    median_size: Literal[0, 3, 5] = 5
    speckle_window_px: int = Field(0, ge=0)
    speckle_range_px: float = Field(1.0, gt=0.0)
    fill_holes: bool = False
    min_texture_snr: float = Field(1.5, ge=0.0, le=20.0)
    texture_window_px: Annotated[int, Field(ge=3, le=31), AfterValidator(_odd)] = 7

    @field_validator("refine_window_px")
    @classmethod
    def _odd_window(cls, value: int) -> int:
        if value % 2 == 0:
            raise ValueError(f"must be odd; use {value + 1}")
        return value


class HistogramConfig(_Strict):
    """The per-frame depth histogram (linearly spaced edges from ``min_m`` to ``max_m``)."""

    min_m: float = Field(0.0, ge=0.0)
    max_m: float = Field(20.0, gt=0.0, le=1000.0)
    bins: int = Field(40, ge=1, le=1000)

    @model_validator(mode="after")
    def _range(self) -> HistogramConfig:
        if self.max_m <= self.min_m:
            raise ValueError("max_m must be greater than min_m")
        return self


_HEAD_NAME = re.compile(r"^[a-z][a-z0-9_-]{0,31}$")


class HeadConfig(_Strict):
    """One stereo head: its calibration file, its mount, its source and its matcher."""

    name: str
    calibration: Annotated[ConfigPath, AfterValidator(_existing_file)]
    mount: MountConfig = MountConfig()
    source: SourceConfig
    matcher: MatcherConfig = SgbmConfig()
    preprocess: PreprocessConfig = PreprocessConfig()
    postprocess: PostprocessConfig = PostprocessConfig()
    sectors: SectorsConfig = SectorsConfig()
    histogram: HistogramConfig = HistogramConfig()

    @field_validator("name")
    @classmethod
    def _name(cls, value: str) -> str:
        if not _HEAD_NAME.match(value):
            raise ValueError("use lower case letters, digits, '-' or '_', e.g. 'front'")
        return value


class GroundConfig(_Strict):
    """The ground-plane model that keeps the ground from looking like an obstacle.

    The ground is a horizontal plane ``height_m`` below the body origin (in the level frame,
    which follows the vehicle attitude). The height comes from the first of these that is
    known: a fresh downward rangefinder (DISTANCE_SENSOR, PITCH_270) corrected for the tilt,
    the height above home (LOCAL_POSITION_NED) when ``use_altitude`` is on (flat ground only),
    the height recorded with the frame, and finally ``height_m``.

    Attributes:
        height_m: Height of the body origin above the ground when nothing better is known.
        use_altitude: Trust the height above home as height above ground.
        margin_m: Points less than this above the ground plane are ground.
        disparity_tolerance_px: A point must stay above the margin with its disparity this
            much smaller (farther along its ray): far ground measured a pixel too near would
            otherwise stand up as an obstacle.
        rangefinder_max_age_ms: A rangefinder reading older than this is not used.
    """

    height_m: float = Field(1.5, gt=0.0, le=500.0)
    use_altitude: bool = False
    margin_m: float = Field(0.3, ge=0.0, le=5.0)
    disparity_tolerance_px: float = Field(1.0, ge=0.0, le=16.0)
    rangefinder_max_age_ms: int = Field(500, ge=10, le=5000)


class BandConfig(_Strict):
    """Points more than ``above_m`` above or ``below_m`` below the body origin are ignored."""

    above_m: float = Field(2.0, gt=0.0, le=100.0)
    below_m: float = Field(2.0, gt=0.0, le=100.0)


class AttitudeConfig(_Strict):
    """Attitude assumed when neither the autopilot nor the recording gives one."""

    roll_deg: float = Field(0.0, ge=-90.0, le=90.0)
    pitch_deg: float = Field(0.0, ge=-90.0, le=90.0)


class TemporalConfig(_Strict):
    """Per-bin filter between frames (see ``avoidd.perception.temporal``).

    Attributes:
        confirm_frames: A new obstacle is reported once it was seen in this many ...
        window_frames: ... of the last this many frames (k of n); until then its bin is
            unknown, neither clear nor an obstacle.
        hold_ms: A confirmed obstacle that vanishes keeps its distance this long at most
            (and never beyond ``pipeline.max_age_ms``: every bin carries its reading's capture
            time, and the sender makes older bins unknown).
    """

    confirm_frames: int = Field(2, ge=1, le=10)
    window_frames: int = Field(3, ge=1, le=10)
    hold_ms: int = Field(200, ge=0, le=2000)

    @model_validator(mode="after")
    def _k_of_n(self) -> TemporalConfig:
        if self.confirm_frames > self.window_frames:
            raise ValueError("confirm_frames cannot exceed window_frames (k of n needs k <= n)")
        return self


class ObstaclesConfig(_Strict):
    """Clustering of obstacle points into obstacles (per head and frame).

    Attributes:
        bearing_cell_deg: Angular cell of the clustering grid.
        disparity_cell_px: Range cell of the grid, in disparity pixels (range noise is about
            constant in disparity).
        min_points: Points an obstacle needs.
        max_count: Obstacles listed per head and frame, nearest first.
    """

    bearing_cell_deg: float = Field(1.0, gt=0.05, le=10.0)
    disparity_cell_px: float = Field(1.0, gt=0.05, le=16.0)
    min_points: int = Field(30, ge=1)
    max_count: int = Field(16, ge=1, le=256)


class PerceptionConfig(_Strict):
    """Vehicle-wide perception: ground model, height band, attitude fallback, filtering."""

    ground: GroundConfig = GroundConfig()
    band: BandConfig = BandConfig()
    attitude: AttitudeConfig = AttitudeConfig()
    temporal: TemporalConfig = TemporalConfig()
    obstacles: ObstaclesConfig = ObstaclesConfig()


class ObstacleDistanceConfig(_Strict):
    """OBSTACLE_DISTANCE output: rate and the sensor's range in centimetres."""

    rate_hz: float = Field(15.0, ge=1.0, le=50.0)
    min_distance_cm: int = Field(20, ge=1, le=65533)
    max_distance_cm: int = Field(2000, ge=2, le=65533)

    @model_validator(mode="after")
    def _range(self) -> ObstacleDistanceConfig:
        if self.max_distance_cm <= self.min_distance_cm:
            raise ValueError("max_distance_cm must be greater than min_distance_cm")
        return self


class StreamsConfig(_Strict):
    """Rates at which avoidd asks the autopilot for vehicle state (0 = do not ask).

    Each is requested with MAV_CMD_SET_MESSAGE_INTERVAL, repeated until acknowledged, and again
    whenever the link comes back (an autopilot forgets requested intervals when it reboots).
    """

    attitude_hz: float = Field(50.0, ge=0.0, le=1000.0)
    local_position_hz: float = Field(10.0, ge=0.0, le=1000.0)
    distance_sensor_hz: float = Field(10.0, ge=0.0, le=1000.0)
    system_time_hz: float = Field(1.0, ge=0.0, le=1000.0)


def _known_message(value: str) -> str:
    from avoidd.mavlink.codec import message_id

    try:
        message_id(value)
    except KeyError:
        raise ValueError(f"'{value}' is not a MAVLink message name (e.g. RADIO_STATUS)") from None
    return value


class SigningConfig(_Strict):
    """MAVLink 2 signing. Give the key as ``key_file`` or as a systemd credential name.

    Attributes:
        key_file: File holding the 32-byte key (raw, or 64 hex digits).
        key_credential: Name of a credential in ``$CREDENTIALS_DIRECTORY`` (systemd
            ``LoadCredential=NAME:/path``); preferred in production.
        allow_unsigned: Messages accepted without a valid signature.
        timestamp_file: Where the signing timestamp is kept across restarts (needed on boards
            without a real-time clock); its folder must exist.
        link_id: Link id carried in our signatures.
    """

    key_file: ConfigPath | None = None
    key_credential: str | None = Field(None, pattern=r"^[A-Za-z0-9_.-]+$")
    allow_unsigned: list[Annotated[str, AfterValidator(_known_message)]] = ["RADIO_STATUS"]
    timestamp_file: ConfigPath | None = None
    link_id: int = Field(0, ge=0, le=255)

    @model_validator(mode="after")
    def _one_key(self) -> SigningConfig:
        if (self.key_file is None) == (self.key_credential is None):
            raise ValueError("give exactly one of key_file and key_credential")
        return self


class DistanceSensorConfig(_Strict):
    """DISTANCE_SENSOR per head: its nearest obstacle, oriented by its mount.

    A head's mount must point along one of the orientations DISTANCE_SENSOR can name: yaw a
    multiple of 45 degrees with pitch 0, or straight up or down.
    """

    enabled: bool = False
    rate_hz: float = Field(10.0, ge=1.0, le=50.0)


class ObstacleDistance3dConfig(_Strict):
    """OBSTACLE_DISTANCE_3D: the nearest ``max_points`` obstacle points (BODY_FRD, metres)."""

    enabled: bool = False
    rate_hz: float = Field(10.0, ge=1.0, le=50.0)
    max_points: int = Field(16, ge=1, le=72)


class MavlinkConfig(_Strict):
    """The MAVLink link and avoidd's identity on it.

    Attributes:
        system_id: The vehicle's system id, or "auto" to learn it from the first autopilot
            heartbeat (avoidd uses 1 until then). Messages of other systems are ignored.
        autopilot_component_id: Component id of the autopilot (1).
        link_timeout_s: The link is down when no autopilot heartbeat came for this long.
    """

    connection: str
    system_id: int | Literal["auto"] = "auto"
    component_id: int = Field(196, ge=1, le=255)
    autopilot_component_id: int = Field(1, ge=1, le=255)
    heartbeat_hz: float = Field(1.0, gt=0.0, le=10.0)
    link_timeout_s: float = Field(3.0, ge=0.5, le=60.0)
    obstacle_distance: ObstacleDistanceConfig = ObstacleDistanceConfig()
    distance_sensor: DistanceSensorConfig = DistanceSensorConfig()
    obstacle_distance_3d: ObstacleDistance3dConfig = ObstacleDistance3dConfig()
    streams: StreamsConfig = StreamsConfig()
    signing: SigningConfig | None = None

    @field_validator("system_id")
    @classmethod
    def _system_id(cls, value: int | str) -> int | str:
        if isinstance(value, int) and not 1 <= value <= 255:
            raise ValueError("a system id is 1 to 255, or auto")
        return value

    @field_validator("connection")
    @classmethod
    def _connection(cls, value: str) -> str:
        parse_connection(value)
        return value

    @property
    def link(self) -> LinkSpec:
        """The parsed connection string."""
        return parse_connection(self.connection)

    @property
    def fixed_system_id(self) -> int | None:
        """The configured system id, or None when it is learned."""
        return None if self.system_id == "auto" else int(self.system_id)


class PipelineConfig(_Strict):
    """Daemon-wide timing.

    Attributes:
        max_age_ms: A scan older than this (from capture to send) is never sent; every bin goes
            out as unknown instead.
        log_interval_s: Period of the one-line status log.
    """

    max_age_ms: int = Field(300, ge=20, le=5000)
    log_interval_s: float = Field(5.0, gt=0.0)


class AppConfig(_Strict):
    """The whole configuration file."""

    version: Literal[1]
    heads: list[HeadConfig] = Field(min_length=1, max_length=8)
    mavlink: MavlinkConfig
    pipeline: PipelineConfig = PipelineConfig()
    perception: PerceptionConfig = PerceptionConfig()

    @field_validator("heads")
    @classmethod
    def _unique_names(cls, value: list[HeadConfig]) -> list[HeadConfig]:
        names = [head.name for head in value]
        duplicates = sorted({name for name in names if names.count(name) > 1})
        if duplicates:
            raise ValueError(f"head names must be unique; rename {', '.join(duplicates)}")
        return value


def load_config(path: Path) -> AppConfig:
    """Load and validate a configuration file.

    Args:
        path: The YAML file.

    Returns:
        The validated configuration; relative paths in it are resolved against its folder.

    Raises:
        ConfigError: One line per problem, naming file, line, key path, value and remedy.
    """
    doc = load_yaml(path)
    return validate_document(doc, AppConfig, {"base_dir": path.parent.resolve()})
