"""A suite of rendered scenes with exact ground truth that measures obstacle perception.

Each scene is rendered by :mod:`avoidd.sources.scene` (varied textures; poles, boxes and walls
standing on textured ground; camera tilt; vehicle roll and pitch), run through the head pipeline
and compared with the truth: the nearest obstacle's distance, the bin of every obstacle, false
obstacle bins, and the paper's ground-plane range at ground-contact points. Scenes are drawn
from a seeded generator, never chosen or tuned one by one.
"""

from __future__ import annotations

import dataclasses
import math
import statistics
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from avoidd.config import HeadConfig, PerceptionConfig
from avoidd.perception.geometry import ground_range
from avoidd.perception.measure import camera_geometry
from avoidd.perception.sectors import bin_of_bearing
from avoidd.pipeline import HeadPipeline
from avoidd.sources.scene import (
    FIRST_OBSTACLE_ID,
    Box,
    Pole,
    RenderedPair,
    Scene,
    render_pair,
    to_uint8,
)
from avoidd.sources.truth import level_points, nearest_obstacle
from avoidd.types import SECTOR_COUNT, FramePose, Mount, RectifiedRig, StereoFrame
from avoidd.vision.calibration import Calibration

NEAR_RIG = RectifiedRig(640, 480, 400.0, 400.0, 319.5, 239.5, 0.12)
"""f B = 48 px m: one pixel of disparity is at most 10% of depth up to 4.8 m."""
FAR_RIG = RectifiedRig(640, 480, 400.0, 400.0, 319.5, 239.5, 0.5)
"""f B = 200 px m: up to 20 m."""
_HEIGHT_M = 1.5
_MAX_RANGE_M = 20.0


@dataclass(frozen=True)
class SceneCase:
    """One scene of the suite."""

    name: str
    rig: RectifiedRig
    scene: Scene
    mount_pitch_deg: float

    @property
    def pose(self) -> FramePose:
        """The vehicle pose the scene was rendered with."""
        return FramePose(
            self.scene.vehicle_roll_deg, self.scene.vehicle_pitch_deg, _HEIGHT_M, "truth", "truth"
        )


@dataclass
class SceneResult:
    """What one scene measured.

    Attributes:
        name: The scene.
        truth_m: Exact nearest obstacle distance (None for obstacle-free scenes).
        measured_m: Reported nearest distance (None if no bin holds an obstacle).
        missed: Obstacles whose nearest point's bin does not report them within 10%.
        false_bins: Bins reporting an obstacle where no obstacle stands (within one bin).
        contact_errors_pct: Ground-plane vs stereo depth at obstacles' ground-contact pixels.
    """

    name: str
    truth_m: float | None
    measured_m: float | None
    missed: list[str] = field(default_factory=list)
    false_bins: list[int] = field(default_factory=list)
    contact_errors_pct: list[float] = field(default_factory=list)

    @property
    def error_pct(self) -> float | None:
        """Nearest-distance error, percent."""
        if self.truth_m is None or self.measured_m is None:
            return None
        return 100.0 * (self.measured_m / self.truth_m - 1.0)


def _obstacle(rng: np.random.Generator, rig: RectifiedRig, kind: str) -> Box | Pole:
    """An obstacle whose nearest face lies where one pixel of disparity is <= 10% of depth."""
    focal_baseline = rig.fx * rig.baseline_m
    nearest = 0.5 if rig is NEAR_RIG else 5.0
    forward = float(rng.uniform(nearest, 0.1 * focal_baseline * 0.9))
    bearing = math.radians(float(rng.uniform(-25.0, 25.0)))
    right = forward * math.tan(bearing)
    if kind == "pole":
        diameter = float(rng.uniform(0.1, 0.3))
        return Pole(forward + diameter / 2, right, diameter, float(rng.uniform(2.5, 4.0)))
    width = float(rng.uniform(0.4, 1.5)) if kind == "box" else 6.0
    depth = float(rng.uniform(0.4, 1.2)) if kind == "box" else 0.3
    return Box(forward + depth / 2, right, depth, width, float(rng.uniform(2.0, 4.0)))


def suite(count: int = 24, seed: int = 2024) -> list[SceneCase]:
    """The scene suite: ``count`` scenes with one obstacle each, plus obstacle-free ground.

    Obstacle scenes alternate between the near and the far rig and between poles, boxes and
    walls; vehicle roll and pitch are drawn within +-20 degrees and the mount pitch from
    {-10, 0, +5} degrees. Ground scenes cover the corners of +-20 degrees roll and pitch.
    """
    rng = np.random.default_rng(seed)
    cases = []
    kinds = ("pole", "box", "wall")
    for index in range(count):
        rig = NEAR_RIG if index % 2 == 0 else FAR_RIG
        kind = kinds[index % 3]
        mount_pitch = float(rng.choice([-10.0, 0.0, 5.0]))
        scene = Scene(
            camera_height_m=_HEIGHT_M,
            camera_pitch_deg=mount_pitch,
            obstacles=(_obstacle(rng, rig, kind),),
            backdrop_m=45.0,
            seed=int(rng.integers(1, 10_000)),
            vehicle_roll_deg=float(rng.uniform(-20.0, 20.0)),
            vehicle_pitch_deg=float(rng.uniform(-20.0, 20.0)),
        )
        cases.append(SceneCase(f"{kind}-{index:02d}", rig, scene, mount_pitch))
    for roll, pitch in ((20.0, 0.0), (-20.0, 0.0), (0.0, 20.0), (0.0, -20.0), (20.0, -20.0)):
        for rig in (NEAR_RIG, FAR_RIG):
            scene = Scene(
                camera_height_m=_HEIGHT_M,
                camera_pitch_deg=0.0,
                obstacles=(),
                backdrop_m=45.0,
                seed=int(rng.integers(1, 10_000)),
                vehicle_roll_deg=roll,
                vehicle_pitch_deg=pitch,
            )
            name = f"ground-r{roll:+.0f}-p{pitch:+.0f}-fb{rig.fx * rig.baseline_m:.0f}"
            cases.append(SceneCase(name, rig, scene, 0.0))
    return cases


def draws(seeds: Sequence[int], count: int = 24) -> list[SceneCase]:
    """Several draws of :func:`suite`, each scene's name prefixed with its draw's seed.

    Args:
        seeds: One draw per seed.
        count: Obstacle scenes per draw.

    Returns:
        The scenes of every draw, named ``SEED/NAME``.
    """
    return [
        dataclasses.replace(case, name=f"{seed}/{case.name}")
        for seed in seeds
        for case in suite(count, seed)
    ]


def suite_head(case: SceneCase, num_disparities: int = 128) -> HeadConfig:
    """The head a rendered suite runs: SGBM, the case's mount pitch."""
    return HeadConfig.model_validate(
        {
            "name": "front",
            # Validated as an existing file but never read: the suite hands the rig over.
            "calibration": __file__,
            "mount": {"pitch_deg": case.mount_pitch_deg},
            "source": {"kind": "synthetic"},
            "matcher": {"kind": "sgbm", "num_disparities": num_disparities},
        }
    )


def noisy_frame(case: SceneCase, rendered: RenderedPair, noise_std: float) -> StereoFrame:
    """The rendered pair as a camera delivers it: seeded sensor noise, 8 bits, the pose."""
    rng = np.random.default_rng(case.scene.seed)
    left, right = (
        to_uint8(view, rng.normal(0.0, noise_std, view.shape).astype(np.float32))
        for view in (rendered.left, rendered.right)
    )
    return StereoFrame(0, 0, left, right, rendered.truth, case.pose)


def run_case(case: SceneCase, noise_std: float = 1.5) -> SceneResult:
    """Render one scene, run the pipeline on it and score it against its truth."""
    rendered = render_pair(case.scene, case.rig)
    frame = noisy_frame(case, rendered, noise_std)
    head = suite_head(case)
    perception = PerceptionConfig()
    pipeline = HeadPipeline(
        head, Calibration(case.rig, None, Path("suite")), _MAX_RANGE_M, perception
    )
    result = pipeline.process(frame, with_obstacles=True)
    mount = pipeline.mount
    truth = nearest_obstacle(rendered.truth, mount, case.pose, perception)
    nearest = result.scan.nearest()
    score = SceneResult(
        case.name,
        truth.distance_m if truth is not None else None,
        nearest.distance_m if nearest is not None else None,
    )
    occupied = truth_bins(rendered.truth, mount, case.pose, perception)
    distance = result.scan.distance_m
    for finite_bin in np.flatnonzero(np.isfinite(distance)):
        near = {(int(finite_bin) + k) % SECTOR_COUNT for k in (-1, 0, 1)}
        if not near & set(occupied):
            score.false_bins.append(int(finite_bin))
    if truth is not None:
        index = int(bin_of_bearing(truth.bearing_deg))
        reading = float(distance[index])
        if not (math.isfinite(reading) and abs(reading / occupied[index] - 1.0) <= 0.1):
            score.missed.append(f"bin {index}: read {reading:.2f}, truth {occupied[index]:.2f}")
        score.contact_errors_pct.extend(_contact_errors(pipeline, result, rendered.truth))
    return score


def truth_bins(
    truth: Any,
    mount: Mount,
    pose: FramePose,
    perception: PerceptionConfig,
    resolvable_px: float = 0.0,
) -> dict[int, float]:
    """Exact nearest obstacle distance of every bin an obstacle occupies (in band, in range).

    Args:
        truth: The rendered ground truth of the left view.
        mount: The head's mount.
        pose: The vehicle pose it was rendered with.
        perception: Ground margin and height band.
        resolvable_px: ``f * s`` for the smallest obstacle side ``s`` the sensor promises to
            see: a bin counts only if its obstacle pixels cover that square at their distance
            (``(f s / Z)**2`` pixels); 0 counts every pixel.
    """
    points = level_points(truth, mount, pose)[truth.object_id >= FIRST_OBSTACLE_ID]
    lowest = min(pose.height_m - perception.ground.margin_m, perception.band.below_m)
    points = points[(points[:, 2] >= -perception.band.above_m) & (points[:, 2] <= lowest)]
    ranges = np.hypot(points[:, 0], points[:, 1])
    bins = bin_of_bearing(np.degrees(np.arctan2(points[:, 1], points[:, 0])))
    occupied: dict[int, float] = {}
    for index in np.unique(bins):
        in_bin = ranges[bins == index]
        nearest = float(in_bin.min())
        if in_bin.size >= (resolvable_px / nearest) ** 2:
            occupied[int(index)] = nearest
    return occupied


def _contact_errors(pipeline: HeadPipeline, result: Any, truth: Any) -> list[float]:
    """Ground-plane vs stereo depth along the line where the obstacle stands on the ground.

    Contact pixels come from the truth (an obstacle pixel with ground in the 3 rows below), so
    this scores the geometry, not a search for the contact. For each, the stereo depth is the
    median of the measured obstacle pixels in the 5 rows up to the contact, and the
    ground-plane depth is taken at the contact line (half a row below the last obstacle row).
    The scene's figure is the median over its contact columns, which keeps the few columns
    where stereo smears depth across the silhouette's side edges from deciding it. Only where
    the paper's model holds: the camera is not rolled (its formulas have no roll).
    """
    geometry = camera_geometry(pipeline.mount, pipeline.rectified_from_raw, result.pose)
    if abs(geometry.roll_deg) > 0.5:
        return []
    ids = truth.object_id
    rig = pipeline.work_rig
    differences = []
    obstacle_columns = np.flatnonzero((ids >= FIRST_OBSTACLE_ID).any(axis=0))
    for u in obstacle_columns:
        v = int(np.flatnonzero(ids[:, u] >= FIRST_OBSTACLE_ID).max())
        if v + 3 >= ids.shape[0] or not (ids[v + 1 : v + 4, u] == 1).all():
            continue
        above = result.depth_m[max(v - 4, 0) : v + 1, u]
        above = above[np.isfinite(above)]
        ground = ground_range(
            geometry.height_m, geometry.tilt_rad, u - rig.cx, rig.cy - (v + 0.5), rig.fx
        )
        if above.size < 3 or ground is None:
            continue
        differences.append(100.0 * (ground.depth_m / float(np.median(above)) - 1.0))
    return [float(np.median(differences))] if differences else []


def contact_suite(count: int = 12, seed: int = 77) -> list[SceneCase]:
    """Scenes where the paper's ground-plane model holds: no roll, varied tilt, one obstacle.

    The obstacle's base must be in view, so it stands at least twice the camera height away
    divided by the tangent of the lower field-of-view edge.
    """
    rng = np.random.default_rng(seed)
    cases = []
    for index in range(count):
        rig = NEAR_RIG if index % 2 == 0 else FAR_RIG
        mount_pitch = float(rng.choice([-10.0, 0.0]))
        vehicle_pitch = float(rng.uniform(-8.0, 5.0))
        obstacle = _obstacle(rng, rig, "pole" if index % 4 < 2 else "box")
        lowest_view = math.atan(rig.cy / rig.fy) - math.radians(mount_pitch + vehicle_pitch)
        nearest_base = _HEIGHT_M / math.tan(lowest_view) * 1.2
        if obstacle.forward_m < nearest_base:
            obstacle = dataclasses.replace(obstacle, forward_m=nearest_base + 0.5)
        scene = Scene(
            camera_height_m=_HEIGHT_M,
            camera_pitch_deg=mount_pitch,
            obstacles=(obstacle,),
            backdrop_m=45.0,
            seed=int(rng.integers(1, 10_000)),
            vehicle_roll_deg=0.0,
            vehicle_pitch_deg=vehicle_pitch,
        )
        cases.append(SceneCase(f"contact-{index:02d}", rig, scene, mount_pitch))
    return cases


@dataclass
class SuiteSummary:
    """The suite's figures."""

    results: list[SceneResult]

    @property
    def errors_pct(self) -> list[float]:
        """Nearest-distance errors of the obstacle scenes, percent."""
        return [abs(e) for r in self.results if (e := r.error_pct) is not None]

    def percentile(self, q: float) -> float:
        """A percentile of the absolute nearest-distance errors."""
        return float(np.percentile(self.errors_pct, q)) if self.errors_pct else math.nan

    @property
    def missed(self) -> list[str]:
        """Every missed obstacle, named by scene."""
        return [f"{r.name}: {m}" for r in self.results for m in r.missed] + [
            f"{r.name}: nothing reported"
            for r in self.results
            if r.truth_m is not None and r.measured_m is None
        ]

    @property
    def false_bins(self) -> list[str]:
        """Every false obstacle bin, named by scene."""
        return [f"{r.name}: bin {b}" for r in self.results for b in r.false_bins]

    @property
    def contact_errors_pct(self) -> list[float]:
        """Ground-plane vs stereo differences at ground contacts, percent."""
        return [e for r in self.results for e in r.contact_errors_pct]

    def headline(self) -> str:
        """The summary in one line: nearest-distance errors, misses and false bins."""
        return (
            f"median {self.percentile(50):.2f}%, p95 {self.percentile(95):.2f}%, "
            f"max {max(self.errors_pct, default=math.nan):.2f}% over {len(self.errors_pct)} "
            f"scenes; missed {len(self.missed)}; false bins {len(self.false_bins)} in "
            f"{len({r.name for r in self.results if r.false_bins})} of {len(self.results)} scenes"
        )

    def format(self) -> str:
        """A table of every scene and the summary figures."""
        lines = [f"{'scene':<26} {'truth m':>8} {'read m':>8} {'err %':>7}  notes"]
        for r in self.results:
            error = r.error_pct
            notes = "; ".join(
                [*r.missed, *(f"false bin {b}" for b in r.false_bins)]
                + [f"contact {c:+.1f}%" for c in r.contact_errors_pct]
            )
            lines.append(
                f"{r.name:<26} {_fmt(r.truth_m):>8} {_fmt(r.measured_m):>8} "
                f"{'' if error is None else f'{error:+.2f}':>7}  {notes}"
            )
        contact = [abs(c) for c in self.contact_errors_pct]
        if self.errors_pct:
            lines.append(
                f"nearest distance |error|: median {statistics.median(self.errors_pct):.2f}%, "
                f"p95 {self.percentile(95):.2f}%, max {max(self.errors_pct):.2f}% over "
                f"{len(self.errors_pct)} scenes"
            )
        else:
            lines.append("nearest distance |error|: no scene with an obstacle to range")
        lines.append(
            f"missed obstacles: {len(self.missed)}; false bins: {len(self.false_bins)} "
            f"in {len({r.name for r in self.results if r.false_bins})} of "
            f"{len(self.results)} scenes"
        )
        if contact:
            lines.append(
                f"ground-plane vs stereo at ground contacts: max |diff| {max(contact):.2f}% "
                f"over {len(contact)} contacts"
            )
        return "\n".join(lines)


def _fmt(value: float | None) -> str:
    return "-" if value is None else f"{value:.3f}"


def run_suite(cases: list[SceneCase]) -> SuiteSummary:
    """Run every scene."""
    return SuiteSummary([run_case(case) for case in cases])
