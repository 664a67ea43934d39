"""Rendered near-range scenes: walls, boxes and poles from 0.3 to 1.2 m, scored bin by bin.

The near field is where a stereo head is most easily wrong in the unsafe direction: an object
nearer than the matcher's search range reads farther than it is. Every scene here is drawn
from a seeded generator (distance, bearing, size, camera tilt and vehicle attitude), rendered
with exact depth through the demo rig (f B = 48 px m, so 64 disparities reach down to
0.76 m only) and run through the head pipeline. A bin fails when it reads farther than the
nearest obstacle point in it by more than 10% (clear counts as infinitely far); unknown is
allowed, since it claims nothing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from avoidd.config import PerceptionConfig
from avoidd.evaluation.scenes import NEAR_RIG, SceneCase, noisy_frame, suite_head, truth_bins
from avoidd.pipeline import HeadPipeline
from avoidd.sources.scene import Box, Pole, Scene, render_pair
from avoidd.vision.calibration import Calibration

_HEIGHT_M = 1.5
_MAX_RANGE_M = 20.0
_TOLERANCE = 0.10


@dataclass
class NearResult:
    """One near scene's verdict.

    Attributes:
        name: The scene.
        truth_m: Exact nearest obstacle distance in the scene.
        measured_m: Nearest reading of the scan (None if no bin holds one).
        farther: ``(bin, truth m, read m)`` of every bin that reads more than 10% too far.
        occupied_bins: Bins with an obstacle in them (truth).
        unknown_bins: Of those, the bins that read unknown.
    """

    name: str
    truth_m: float
    measured_m: float | None
    farther: list[tuple[int, float, float]] = field(default_factory=list)
    occupied_bins: int = 0
    unknown_bins: int = 0


def near_suite(count: int = 24, seed: int = 3030) -> list[SceneCase]:
    """``count`` scenes, each with one wall, box or pole whose near side is 0.3 to 1.2 m away."""
    rng = np.random.default_rng(seed)
    kinds = ("wall", "box", "pole")
    cases = []
    for index in range(count):
        kind = kinds[index % 3]
        distance = float(rng.uniform(0.3, 1.2))
        bearing = math.radians(float(rng.uniform(-30.0, 30.0)))
        right = distance * math.tan(bearing)
        obstacle: Box | Pole
        if kind == "pole":
            diameter = float(rng.uniform(0.05, 0.25))
            obstacle = Pole(distance + diameter / 2, right, diameter, float(rng.uniform(2.0, 4.0)))
        elif kind == "box":
            depth = float(rng.uniform(0.3, 1.0))
            obstacle = Box(
                distance + depth / 2,
                right,
                depth,
                float(rng.uniform(0.3, 1.2)),
                float(rng.uniform(1.2, 3.0)),
            )
        else:
            obstacle = Box(distance + 0.15, right, 0.3, float(rng.uniform(3.0, 10.0)), 3.0)
        mount_pitch = float(rng.choice([-10.0, 0.0]))
        scene = Scene(
            camera_height_m=_HEIGHT_M,
            camera_pitch_deg=mount_pitch,
            obstacles=(obstacle,),
            backdrop_m=45.0,
            seed=int(rng.integers(1, 10_000)),
            vehicle_roll_deg=float(rng.uniform(-5.0, 5.0)),
            vehicle_pitch_deg=float(rng.uniform(-5.0, 5.0)),
        )
        cases.append(
            SceneCase(f"near-{kind}-{index:02d}-{distance:.2f}m", NEAR_RIG, scene, mount_pitch)
        )
    return cases


def run_near_case(case: SceneCase, noise_std: float = 1.5) -> NearResult:
    """Render one near scene, run the pipeline and compare every occupied bin with the truth."""
    rendered = render_pair(case.scene, case.rig)
    frame = noisy_frame(case, rendered, noise_std)
    perception = PerceptionConfig()
    pipeline = HeadPipeline(
        suite_head(case, 64), Calibration(case.rig, None, Path("near")), _MAX_RANGE_M, perception
    )
    result = pipeline.process(frame)
    # Bins where the obstacle covers at least the smallest object the sensor promises to see
    # (sectors.min_size_m, a 5 cm square at its distance): a corner of a box a few pixels
    # wide in a bin is below that, and is reported in the bin that holds the box.
    resolvable_px = case.rig.fx * pipeline.sectors.min_size_m
    occupied = truth_bins(rendered.truth, pipeline.mount, case.pose, perception, resolvable_px)
    nearest = result.scan.nearest()
    verdict = NearResult(
        case.name,
        min(occupied.values()) if occupied else math.inf,
        nearest.distance_m if nearest is not None else None,
        occupied_bins=len(occupied),
    )
    for index, truth_m in sorted(occupied.items()):
        read_m = float(result.scan.distance_m[index])
        if math.isnan(read_m):
            verdict.unknown_bins += 1
        elif read_m > truth_m * (1.0 + _TOLERANCE):
            verdict.farther.append((index, truth_m, read_m))
    return verdict


def format_near(results: list[NearResult]) -> str:
    """A table of the near scenes and the totals."""
    lines = [f"{'near scene':<26} {'truth m':>8} {'read m':>8} {'bins':>5} {'unknown':>8}  too far"]
    for r in results:
        read = "-" if r.measured_m is None else f"{r.measured_m:.3f}"
        too_far = "; ".join(f"bin {b}: {t:.2f} read {m:.2f}" for b, t, m in r.farther)
        lines.append(
            f"{r.name:<26} {r.truth_m:>8.3f} {read:>8} {r.occupied_bins:>5} "
            f"{r.unknown_bins:>8}  {too_far}"
        )
    farther = sum(len(r.farther) for r in results)
    bins = sum(r.occupied_bins for r in results)
    unknown = sum(r.unknown_bins for r in results)
    lines.append(
        f"near range: {farther} of {bins} occupied bins read more than 10% too far "
        f"({unknown} unknown) over {len(results)} scenes"
    )
    return "\n".join(lines)
