"""One head's vision pipeline: stereo frame in, sector scan and per-stage timings out."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from avoidd.config import HeadConfig, PerceptionConfig
from avoidd.errors import BrokenFrame
from avoidd.perception.blind_band import hidden_bins, settle_hidden, without_band_columns
from avoidd.perception.ground_match import Views
from avoidd.perception.obstacles import Obstacle
from avoidd.perception.perceive import Perception, perceive, rectified_to_level
from avoidd.perception.pose import resolve_pose
from avoidd.types import (
    BoolArray,
    FloatArray,
    FramePose,
    Image,
    Mount,
    RectifiedRig,
    SectorScan,
    StereoFrame,
)
from avoidd.vision.calibration import Calibration
from avoidd.vision.depth import depth_from_disparity, resolved_range_m, thin_range_m
from avoidd.vision.matchers import create_matcher
from avoidd.vision.nearfield import NearField, min_range_m
from avoidd.vision.postprocess import postprocess_disparity
from avoidd.vision.preprocess import (
    adaptive_texture_mask,
    denoise,
    resize,
    scale_rig,
    to_grey,
)
from avoidd.vision.rectify import rectify_pair

STAGES = ("rectify", "preprocess", "match", "post", "depth", "obstacles")


@dataclass(frozen=True)
class HeadResult:
    """What one frame of one head produced.

    Attributes:
        head: The head's name.
        seq: Frame number.
        t_capture_ns: Capture time of the frame.
        scan: The head's 72-bin scan.
        depth_m: Depth map of the left view (NaN invalid).
        valid_fraction: Share of pixels with a valid disparity.
        timing_ms: Milliseconds per stage (see ``STAGES``); ``match`` includes the near-field
            pass, which runs at the start of :meth:`HeadPipeline.finish`.
        steps_ms: Milliseconds of each preprocessing step (``preprocess.resize`` ...), part of
            the ``preprocess`` stage.
        filled_depth_m: Hole-filled depth for display and recordings, when
            ``postprocess.fill_holes`` is on (includes matcher-filled pixels); never used for
            obstacles.
        obstacles: The head's obstacles, nearest first (when asked for).
        pose: Attitude and height the frame was interpreted with.
        obstacle_points: Points left after ground and band rejection.
        near_pixels: Pixels measured by the near-field pass (nearer than the main range).
        left_view: The rectified left view the matcher saw (grey, the depth map's size), for
            display.
        obstacle_mask: Pixels of the depth map kept as obstacle points, for display.
    """

    head: str
    seq: int
    t_capture_ns: int
    scan: SectorScan
    depth_m: FloatArray = field(repr=False)
    valid_fraction: float
    timing_ms: dict[str, float]
    steps_ms: dict[str, float] = field(default_factory=dict)
    filled_depth_m: FloatArray | None = field(default=None, repr=False)
    obstacles: list[Obstacle] = field(default_factory=list)
    pose: FramePose | None = None
    obstacle_points: int = 0
    near_pixels: int = 0
    left_view: Image | None = field(default=None, repr=False)
    obstacle_mask: BoolArray | None = field(default=None, repr=False)


class Matched(NamedTuple):
    """One frame after the matcher: what :meth:`HeadPipeline.finish` turns into a result.

    Attributes:
        frame: The raw stereo pair.
        left: The rectified, preprocessed left view (grey).
        right: The same of the right view.
        texture: Pixels the texture mask keeps, when the mask is on.
        disparity: The main matcher's disparity (NaN unmeasured); the near-field pass is
            applied by :meth:`HeadPipeline.finish`.
        filled_by_matcher: Pixels the matcher filled rather than measured, when it says.
        unchecked: In the left border band, readings dropped because the right view could
            not check them (None: no band was checked).
        timing_ms: Milliseconds of the stages so far (rectify, preprocess, match).
        steps_ms: Milliseconds of each preprocessing step.
    """

    frame: StereoFrame
    left: Image
    right: Image
    texture: BoolArray | None
    disparity: FloatArray
    filled_by_matcher: BoolArray | None
    unchecked: BoolArray | None
    timing_ms: dict[str, float]
    steps_ms: dict[str, float]


class Laps:
    """A stopwatch: each call records the milliseconds since the previous one under a name."""

    def __init__(self, prefix: str = "") -> None:
        self.ms: dict[str, float] = {}
        self._prefix = prefix
        self._last = time.perf_counter()

    def __call__(self, name: str) -> None:
        """Record the time since the previous call (or creation) as ``name``."""
        now = time.perf_counter()
        self.ms[self._prefix + name] = (now - self._last) * 1000.0
        self._last = now


class HeadPipeline:
    """Runs the vision stages of one head; one frame at a time (not thread-safe).

    Args:
        head: The head's configuration.
        calibration: Its loaded calibration.
        max_range_m: Readings at or beyond this range are clear.
        perception: Ground model, height band, attitude fallback and clustering.
    """

    def __init__(
        self,
        head: HeadConfig,
        calibration: Calibration,
        max_range_m: float,
        perception: PerceptionConfig | None = None,
    ) -> None:
        self.name = head.name
        self.rig: RectifiedRig = calibration.rig
        self.mount = Mount(
            head.mount.yaw_deg, head.mount.pitch_deg, head.mount.roll_deg, head.mount.position_m
        )
        self._maps = calibration.maps
        self.rectified_from_raw = calibration.rectified_from_raw
        self._matcher = create_matcher(head.matcher)
        self.near_field = (
            NearField(head.matcher.num_disparities, head.near_field, head.postprocess)
            if head.near_field.enabled
            else None
        )
        self._pre = head.preprocess
        self._post = head.postprocess
        self.work_rig = scale_rig(self.rig, head.preprocess.resize_scale)
        """The rig of the images the matcher sees (differs from ``rig`` when resizing)."""
        self._min_range_m = min_range_m(
            self.work_rig, head.matcher.num_disparities, head.near_field
        )
        self._resolved_range_m = resolved_range_m(self.work_rig, head.disparity_error_px)
        self.sectors = head.sectors
        self._histogram = head.histogram
        self._max_range_m = max_range_m
        self.perception = perception or PerceptionConfig()

    @property
    def min_range_m(self) -> float:
        """Nearest range this head measures (see :func:`avoidd.vision.nearfield.min_range_m`)."""
        return self._min_range_m

    @property
    def max_range_m(self) -> float:
        """Range a clear bin vouches for (readings at or beyond it are clear)."""
        return self._max_range_m

    @property
    def resolved_range_m(self) -> float:
        """Farthest range this head resolves (see :func:`avoidd.vision.depth.resolved_range_m`)."""
        return self._resolved_range_m

    @property
    def thin_range_m(self) -> float:
        """How far this head reads its smallest obstacle (see :func:`thin_range_m`)."""
        return thin_range_m(self.work_rig, self.sectors.min_size_m, self._resolved_range_m)

    def default_pose(self, frame: StereoFrame) -> FramePose:
        """The pose recorded with the frame, else the configured attitude and height."""
        return resolve_pose(frame.t_capture_ns, frame.pose, None, None, None, self.perception)

    def _preprocess(
        self, left: Image, right: Image
    ) -> tuple[Image, Image, npt.NDArray[np.bool_] | None, dict[str, float]]:
        """Resize, denoise, texture mask; returns the views, the mask and step timings."""
        pre = self._pre
        step = Laps("preprocess.")
        if pre.resize_scale != 1.0:
            left, right = resize(left, pre.resize_scale), resize(right, pre.resize_scale)
            step("resize")
        if pre.median_px or pre.mean_px:
            left = denoise(left, pre.median_px, pre.mean_px)
            right = denoise(right, pre.median_px, pre.mean_px)
            step("denoise")
        texture = None
        if pre.texture is not None:
            t = pre.texture
            texture = adaptive_texture_mask(left, t.method, t.window_px, t.offset, t.spread_px)
            step("texture")
        return left, right, texture, step.ms

    def check_frame(self, frame: StereoFrame) -> None:
        """Reject a frame that the stages cannot take.

        A view missing, of another pixel format than 8-bit grey, BGR or BGRA, or of another
        size than the calibration's.

        Raises:
            BrokenFrame: A view missing, of the wrong pixel format or size.
        """
        expected = (self.rig.height, self.rig.width)
        for view, image in (("left", frame.left), ("right", frame.right)):
            if not isinstance(image, np.ndarray):
                raise BrokenFrame(f"head '{self.name}': no {view} image; frame {frame.seq} dropped")
            channels = image.shape[2] if image.ndim == 3 else 1
            if image.dtype != np.uint8 or image.ndim not in (2, 3) or channels not in (1, 3, 4):
                raise BrokenFrame(
                    f"head '{self.name}': {view} image is {image.dtype} with shape "
                    f"{image.shape}, expected 8-bit grey, BGR or BGRA; frame {frame.seq} dropped"
                )
            if image.shape[:2] != expected:
                raise BrokenFrame(
                    f"head '{self.name}': {view} image is {image.shape[1]}x{image.shape[0]}, "
                    f"calibration says {self.rig.width}x{self.rig.height}; "
                    f"frame {frame.seq} dropped"
                )

    def process(
        self, frame: StereoFrame, pose: FramePose | None = None, with_obstacles: bool = False
    ) -> HeadResult:
        """Run every stage on one frame (:meth:`match` then :meth:`finish`).

        Args:
            frame: The raw stereo pair.
            pose: Vehicle attitude and height at capture (from the autopilot); default
                :meth:`default_pose`.
            with_obstacles: Also cluster obstacle points into obstacles (replay, debugging).

        Returns:
            The head's result for this frame.

        Raises:
            BrokenFrame: The frame does not fit the calibration.
        """
        return self.finish(self.match(frame), pose, with_obstacles)

    def match(self, frame: StereoFrame) -> Matched:
        """The first half of the stages: rectify, preprocess and match one frame.

        It may run in one thread while :meth:`finish` runs on the previous frame in another
        (the matcher is used by this half only), but never twice at the same time.

        Args:
            frame: The raw stereo pair.

        Returns:
            The frame's raw disparity and what the second half needs with it.

        Raises:
            BrokenFrame: The frame does not fit the calibration.
        """
        self.check_frame(frame)
        lap = Laps()
        # Grey first: remapping one channel instead of three saves more than the conversion
        # costs, and the two steps commute (up to rounding).
        left, right = to_grey(frame.left), to_grey(frame.right)
        left, right = rectify_pair(left, right, self._maps)
        lap("rectify")
        left, right, texture, steps_ms = self._preprocess(left, right)
        lap("preprocess")
        disparity = self._matcher.compute(left, right)
        lap("match")
        return Matched(
            frame,
            left,
            right,
            texture,
            disparity,
            self._matcher.last_filled,
            self._matcher.last_unchecked,
            lap.ms,
            steps_ms,
        )

    def finish(
        self, matched: Matched, pose: FramePose | None = None, with_obstacles: bool = False
    ) -> HeadResult:
        """The second half of the stages: the near-field pass, post-process, depth, perception.

        Safe to run in another thread than :meth:`match` (the near-field pass has a matcher of
        its own, and the rest only reads the head's settings), but never twice at the same time.

        Args:
            matched: What :meth:`match` made of the frame.
            pose: Vehicle attitude and height at capture; default :meth:`default_pose`.
            with_obstacles: Also cluster obstacle points into obstacles (replay, debugging).

        Returns:
            The head's result for the frame.

        Raises:
            BrokenFrame: The pose or the mount holds a number that is not finite.
        """
        frame, left, right, texture = matched.frame, matched.left, matched.right, matched.texture
        disparity, filled_by_matcher = matched.disparity, matched.filled_by_matcher
        timing_ms = dict(matched.timing_ms)
        lap = Laps()
        near_pixels = 0
        gate = None
        if self.near_field is not None:
            # Here rather than in match(): with the stages overlapped this balances the two
            # threads (the matching thread is the busier one), and the pass's own serial parts
            # run while the other thread's SGBM keeps the second core busy.
            near = self.near_field.apply(left, right, disparity)
            disparity, near_pixels, gate = near.disparity, near.near_pixels, near.texture_gate
            if filled_by_matcher is not None:
                filled_by_matcher = filled_by_matcher & ~near.near  # measured, not filled
            lap("near")
            timing_ms["match"] = timing_ms.get("match", 0.0) + lap.ms.pop("near")
        post = postprocess_disparity(
            left, right, disparity, self._post, texture, filled_by_matcher, gate
        )
        disparity, textured, filled_display, sigma = post
        lap("post")
        # Textured pixels left without a measurement (occluded, too near, too oblique, in the
        # band): something may stand there that no bin can vouch for as clear.
        unmeasured = np.isnan(disparity)
        unresolved = unmeasured if textured is None else unmeasured & textured
        depth = depth_from_disparity(disparity, self.work_rig)
        filled_depth = None
        if filled_display is not None:
            filled_depth = depth_from_disparity(filled_display, self.work_rig)
        lap("depth")
        unresolved_per_column = np.count_nonzero(unresolved, axis=0)
        frame_pose = pose or self.default_pose(frame)

        def see(depth_m: FloatArray, disparity_px: FloatArray) -> Perception:
            return perceive(
                depth_m,
                self.work_rig,
                self.mount,
                frame_pose,
                self.perception,
                self.sectors,
                self._histogram,
                self._max_range_m,
                frame.t_capture_ns,
                with_obstacles,
                self.rectified_from_raw,
                unresolved_per_column,
                Views(left, right, disparity_px, sigma),
            )

        seen = see(depth, disparity)
        # The left border band cannot show a surface nearer than f*B/x at column x (its match
        # would be outside the right image). Where a bin's band pixels show that something
        # nearer than its reading stands unseen, the bin reads what its other columns show if
        # that is no farther, else unknown (never clear).
        band_px = min(self._matcher.num_disparities, unresolved.shape[1])
        evidence = unresolved[:, :band_px].copy()
        if matched.unchecked is not None:
            checked = min(band_px, matched.unchecked.shape[1])
            evidence[:, :checked] &= ~matched.unchecked[:, :checked]
        hidden = hidden_bins(
            evidence,
            self.work_rig,
            rectified_to_level(self.mount, seen.pose, self.rectified_from_raw),
            self.sectors.min_size_m,
            self.sectors.min_pixels,
            seen.scan.distance_m,
        )
        if hidden.any():
            without_band = (
                without_band_columns(depth, band_px),
                without_band_columns(disparity, band_px),
            )
            blind = see(*without_band).scan
            settle_hidden(seen.scan, blind, hidden)
        lap("obstacles")
        valid = float(np.count_nonzero(~np.isnan(disparity))) / disparity.size
        return HeadResult(
            self.name,
            frame.seq,
            frame.t_capture_ns,
            seen.scan,
            depth,
            valid,
            {**timing_ms, **lap.ms},
            matched.steps_ms,
            filled_depth,
            seen.obstacles,
            seen.pose,
            seen.candidates,
            near_pixels,
            left,
            seen.candidate_mask,
        )
