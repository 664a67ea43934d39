"""Rendered silhouettes across bin boundaries: no reading spills into the neighbouring bin.

Beside a near object's silhouette, pixels of the background (sky, the tree line, the ground
beside a box) can take the object's disparity. When the silhouette lies near a bin boundary
that strip falls in the next bin and reads as an obstacle where there is none. Each scene
here puts one box or pole so that one of its side edges lies 0.2 to 1.5 degrees from a bin
boundary (drawn by a seeded generator, not picked), against the tree line or open sky, and
counts the bins next to the object's own that read an obstacle with none in them. Thin poles
at 5 m (5 cm) must still be seen: the same suppression must not erase them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from avoidd.config import HeadConfig, PerceptionConfig
from avoidd.evaluation.scenes import NEAR_RIG, SceneCase, truth_bins
from avoidd.pipeline import HeadPipeline
from avoidd.sources.scene import Box, Pole, Scene, render_pair, to_uint8
from avoidd.types import SECTOR_COUNT, StereoFrame
from avoidd.vision.calibration import Calibration

_HEIGHT_M = 1.5
_MAX_RANGE_M = 20.0


@dataclass
class EdgeResult:
    """One silhouette scene's verdict.

    Attributes:
        name: The scene.
        beside: ``(bin, read m)`` of bins next to the object's bins that read an obstacle
            with none in them, at the object's distance (within 30%): its silhouette spilled.
        elsewhere: Other bins that read an obstacle with none in them (not an edge effect;
            over open flat ground, mostly far ground read too near: see docs/perception.md).
        missed: Neither the object's nearest bin nor a bin next to it reads the object's
            distance within 10% (a sliver of it past a bin boundary may read unknown, while
            the bin beside holds it).
    """

    name: str
    beside: list[tuple[int, float]] = field(default_factory=list)
    elsewhere: list[tuple[int, float]] = field(default_factory=list)
    missed: str | None = None


def edge_suite(count: int = 24, seed: int = 4242) -> list[SceneCase]:
    """Boxes and poles whose left or right silhouette lies just past a bin boundary."""
    rng = np.random.default_rng(seed)
    cases = []
    for index in range(count):
        kind = ("box", "pole", "thin")[index % 3]
        distance = 5.0 if kind == "thin" else float(rng.uniform(1.2, 6.0))
        boundary_deg = 2.5 + 5.0 * int(rng.integers(-5, 5))
        side = 1.0 if rng.random() < 0.5 else -1.0  # which edge sits at the boundary
        edge = math.radians(boundary_deg + side * float(rng.uniform(0.2, 1.5)))
        if kind == "box":
            width = float(rng.uniform(0.4, 1.5))
            centre = distance * math.tan(edge) - side * width / 2
            obstacle: Box | Pole = Box(distance + 0.3, centre, 0.6, width, 3.0)
        else:
            diameter = 0.05 if kind == "thin" else float(rng.uniform(0.1, 0.3))
            centre = distance * math.tan(edge) - side * diameter / 2
            obstacle = Pole(distance + diameter / 2, centre, diameter, 3.0)
        scene = Scene(
            camera_height_m=_HEIGHT_M,
            camera_pitch_deg=0.0,
            obstacles=(obstacle,),
            backdrop_m=45.0 if index % 2 == 0 else None,
            seed=int(rng.integers(1, 10_000)),
        )
        sky = "treeline" if index % 2 == 0 else "sky"
        name = f"edge-{kind}-{index:02d}-{distance:.1f}m-{sky}"
        cases.append(SceneCase(name, NEAR_RIG, scene, 0.0))
    return cases


def _head() -> HeadConfig:
    return HeadConfig.model_validate(
        {
            "name": "front",
            "calibration": __file__,  # validated as existing, never read: the rig is handed over
            "source": {"kind": "synthetic"},
            "matcher": {"kind": "sgbm", "num_disparities": 64},
        }
    )


def run_edge_case(case: SceneCase, noise_std: float = 1.5) -> EdgeResult:
    """Render one silhouette scene and sort its false bins into beside and elsewhere."""
    rendered = render_pair(case.scene, case.rig)
    rng = np.random.default_rng(case.scene.seed)
    left, right = (
        to_uint8(view, rng.normal(0.0, noise_std, view.shape).astype(np.float32))
        for view in (rendered.left, rendered.right)
    )
    perception = PerceptionConfig()
    pipeline = HeadPipeline(
        _head(), Calibration(case.rig, None, Path("edges")), _MAX_RANGE_M, perception
    )
    result = pipeline.process(StereoFrame(0, 0, left, right, rendered.truth, case.pose))
    # As in the near suite: bins where the object covers at least the smallest object the
    # sensor promises to see (a 5 cm square at its distance).
    resolvable_px = case.rig.fx * pipeline.sectors.min_size_m
    occupied = truth_bins(rendered.truth, pipeline.mount, case.pose, perception, resolvable_px)
    verdict = EdgeResult(case.name)
    neighbours = {(b + k) % SECTOR_COUNT for b in occupied for k in (-1, 1)} - set(occupied)
    object_m = min(occupied.values()) if occupied else math.inf
    distance = result.scan.distance_m
    for index in np.flatnonzero(np.isfinite(distance)):
        if int(index) in occupied:
            continue
        read_m = float(distance[index])
        spilled = int(index) in neighbours and abs(read_m / object_m - 1.0) <= 0.3
        (verdict.beside if spilled else verdict.elsewhere).append((int(index), read_m))
    if occupied:
        nearest_bin = min(occupied, key=lambda b: occupied[b])
        truth_m = occupied[nearest_bin]
        reads = [float(distance[(nearest_bin + k) % SECTOR_COUNT]) for k in (0, -1, 1)]
        if not any(math.isfinite(r) and abs(r / truth_m - 1.0) <= 0.1 for r in reads):
            verdict.missed = f"bin {nearest_bin}: read {reads[0]:.2f}, truth {truth_m:.2f}"
    else:
        verdict.missed = "the object is outside the band"
    return verdict


def format_edges(results: list[EdgeResult]) -> str:
    """A table of the silhouette scenes and the totals."""
    lines = [f"{'edge scene':<32} beside (bin: m)        elsewhere   missed"]
    for r in results:
        beside = ", ".join(f"{b}: {m:.2f}" for b, m in r.beside) or "-"
        elsewhere = ", ".join(f"{b}: {m:.1f}" for b, m in r.elsewhere) or "-"
        lines.append(f"{r.name:<32} {beside:<22} {elsewhere:<11} {r.missed or ''}")
    beside_total = sum(len(r.beside) for r in results)
    elsewhere_total = sum(len(r.elsewhere) for r in results)
    missed = sum(r.missed is not None for r in results)
    lines.append(
        f"silhouettes: {beside_total} false bins beside them, {elsewhere_total} elsewhere, "
        f"{missed} objects missed, over {len(results)} scenes"
    )
    return "\n".join(lines)
