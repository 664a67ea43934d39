"""Records that travel between the pipeline stages (frames, rigs, mounts, sector scans)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

Image = npt.NDArray[np.uint8]
"""An 8-bit image, grey (H, W) or BGR (H, W, 3)."""

FloatArray = npt.NDArray[np.float32]
"""A float32 array; NaN marks an invalid (unmeasured) value."""
BoolArray = npt.NDArray[np.bool_]
"""A boolean mask, one value per pixel."""

IdArray = npt.NDArray[np.int16]
"""Per-pixel surface ids of a synthetic view."""

SECTOR_COUNT = 72
SECTOR_WIDTH_DEG = 5.0


class GroundTruth(NamedTuple):
    """Exact geometry of the left view of a synthetic frame.

    Attributes:
        depth_m: Depth along the optical axis, ``inf`` for sky.
        object_id: Surface id per pixel (0 sky, 1 ground, 2 tree line, 3+ obstacles).
        points_m: (H, W, 3) surface points relative to the left camera centre in the level rig
            frame (X forward, Y right, Z down); ``inf`` for sky.
    """

    depth_m: FloatArray
    object_id: IdArray
    points_m: FloatArray


class FramePose(NamedTuple):
    """Vehicle attitude and height above ground at a frame's capture time.

    Attributes:
        roll_deg: Vehicle roll, positive right side down.
        pitch_deg: Vehicle pitch, positive nose up.
        height_m: Height of the body origin above the ground.
        source: Where the attitude came from (``mavlink``, ``recording``, ``config``).
        height_source: Where the height came from (``rangefinder``, ``altitude``,
            ``recording``, ``config``).
    """

    roll_deg: float
    pitch_deg: float
    height_m: float
    source: str = "config"
    height_source: str = "config"


class VehicleSample(NamedTuple):
    """Vehicle heading and local position at a frame's capture, as a recording carries them.

    Attributes:
        yaw_deg: Heading, degrees clockwise from north, in (-180, 180]; NaN when unknown.
        north_m: Local position (``LOCAL_POSITION_NED``) north of the origin; NaN when unknown.
        east_m: East of the origin; NaN when unknown.
        down_m: Below the origin (negative above it); NaN when unknown.
    """

    yaw_deg: float = math.nan
    north_m: float = math.nan
    east_m: float = math.nan
    down_m: float = math.nan


class StereoFrame(NamedTuple):
    """One stereo pair as a source delivers it.

    Attributes:
        seq: Frame number assigned by the source, increasing by one per delivered frame.
        t_capture_ns: Capture time, monotonic clock in nanoseconds (or the recorded time).
        left: Left image (the reference view of the disparity map).
        right: Right image.
        truth: Exact geometry, for synthetic sources only.
        pose: Attitude and height recorded with the frame (recordings, synthetic scenes).
        restarts: How many times the source started over before this frame (a looping
            recording or moving scene): a change means the scene jumped, not moved.
        vehicle: Heading and local position recorded with the frame (recordings only).
    """

    seq: int
    t_capture_ns: int
    left: Image
    right: Image
    truth: GroundTruth | None = None
    pose: FramePose | None = None
    restarts: int = 0
    vehicle: VehicleSample | None = None


@dataclass(frozen=True)
class RectifiedRig:
    """Intrinsics of a rectified stereo pair (both views share fx, fy, cy).

    Depth follows ``Z = fx * baseline_m / (d + doffs_px)`` where ``d`` is the disparity in pixels
    and ``doffs_px`` the difference of the principal points (``cx_right - cx_left``).
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    baseline_m: float
    doffs_px: float = 0.0

    @property
    def hfov_deg(self) -> float:
        """Horizontal field of view of the left view in degrees."""
        left = math.atan(self.cx / self.fx)
        right = math.atan((self.width - 1 - self.cx) / self.fx)
        return math.degrees(left + right)


@dataclass(frozen=True)
class Mount:
    """Pose of a stereo head on the vehicle, body FRD frame.

    Attributes:
        yaw_deg: Rotation about body down, positive turns the camera to the right.
        pitch_deg: Rotation about body right, positive tilts the camera up.
        roll_deg: Rotation about the optical axis, positive is right side down.
        position_m: (forward, right, down) of the left camera centre relative to the body origin.
    """

    yaw_deg: float = 0.0
    pitch_deg: float = 0.0
    roll_deg: float = 0.0
    position_m: tuple[float, float, float] = (0.0, 0.0, 0.0)


TimeArray = npt.NDArray[np.int64]
"""Per-bin times in nanoseconds."""

TrackPoint = tuple[int, float, float, float, float]
"""``(t_ns, north_m, east_m, north_m_s, east_m_s)``: a reported position and velocity."""


@dataclass(frozen=True)
class SectorScan:
    """Distances around the vehicle in 72 bins of 5 degrees (body FRD, bin i centred on i*5 deg).

    Values are metres. ``NaN`` means unknown (not covered, not measured, or stale) and ``inf``
    means measured clear up to the sensor's maximum range.

    Attributes:
        t_capture_ns: Capture time of the newest frame in the scan.
        distance_m: (72,) horizontal distance per bin.
        points_frd_m: (72, 3) the body-frame point each finite bin reports (NaN elsewhere),
            or None.
        reading_t_ns: (72,) capture time of each bin's reading, or None when every bin comes
            from ``t_capture_ns``; a held reading is older than the frame.
    """

    t_capture_ns: int
    distance_m: FloatArray = field(repr=False)
    points_frd_m: FloatArray | None = field(default=None, repr=False)
    reading_t_ns: TimeArray | None = field(default=None, repr=False)

    @staticmethod
    def unknown(t_capture_ns: int = 0) -> SectorScan:
        """A scan in which every bin is unknown."""
        return SectorScan(t_capture_ns, np.full(SECTOR_COUNT, np.nan, dtype=np.float32))

    def times_ns(self) -> TimeArray:
        """Capture time of every bin's reading."""
        if self.reading_t_ns is not None:
            return self.reading_t_ns
        return np.full(SECTOR_COUNT, self.t_capture_ns, dtype=np.int64)

    def expired(self, now_ns: int, max_age_ns: int) -> SectorScan:
        """This scan with every bin whose reading is older than ``max_age_ns`` made unknown."""
        old = now_ns - self.times_ns() > max_age_ns
        if not old.any():
            return self
        distance = self.distance_m.copy()
        distance[old] = np.nan
        points = None
        if self.points_frd_m is not None:
            points = self.points_frd_m.copy()
            points[old] = np.nan
        return SectorScan(self.t_capture_ns, distance, points, self.reading_t_ns)

    def nearest(self) -> Nearest | None:
        """The closest measured bin, or None if no bin holds a finite distance."""
        finite = np.isfinite(self.distance_m)
        if not finite.any():
            return None
        masked = np.where(finite, self.distance_m, np.inf)
        index = int(np.argmin(masked))
        return Nearest(float(masked[index]), bin_bearing_deg(index))


class Nearest(NamedTuple):
    """The closest obstacle: distance in metres and bearing in degrees (-180, 180], FRD."""

    distance_m: float
    bearing_deg: float


def bin_bearing_deg(index: int) -> float:
    """Bearing of the centre of sector ``index``, wrapped into (-180, 180]."""
    return wrap_deg(index * SECTOR_WIDTH_DEG)


def wrap_deg(angle_deg: float) -> float:
    """Wrap an angle into (-180, 180] degrees."""
    wrapped = math.fmod(angle_deg + 180.0, 360.0)
    if wrapped <= 0.0:
        wrapped += 360.0
    return wrapped - 180.0


@dataclass(frozen=True)
class LocalPosition:
    """LOCAL_POSITION_NED, on avoidd's clock."""

    t_ns: int
    north_m: float
    east_m: float
    down_m: float
    vn_m_s: float
    ve_m_s: float
    vd_m_s: float


@dataclass(frozen=True)
class Rangefinder:
    """The latest downward DISTANCE_SENSOR reading, on avoidd's clock."""

    t_ns: int
    distance_m: float
