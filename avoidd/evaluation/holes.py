"""Rendered suites that count holes: bins where a surface stands that read unknown or too far.

ArduPilot ignores an unknown bin (65535), so a bin over a real surface that reads unknown
holds nothing for it, and avoidd's own planner, which treats unknown as blocked, ends such
flights in "no path". Three suites, each drawn from a seeded generator (never picked one by
one), put surfaces in many bins at once:

- ``walls``: walls across the view at a slant of up to 40 degrees and walls along the course
  (their faces seen at a grazing angle), 1.2 to 8 m away with the demo rig (f B = 48 px m) and
  5 to 18 m with the long one (f B = 200 px m);
- ``poles``: rows of three to six poles 5 to 30 cm thick, 1.5 to 10 m away;
- ``clutter``: three to six boxes and poles per frame, 1.2 to 8 m away, across the view.

Every bin whose truth holds an obstacle covering at least the smallest obstacle the sensor
promises to see (a ``sectors.min_size_m`` square at its distance, as in the near and edge
suites) is scored: *read* when its reading is within 10 % of the truth, *too near* when it
reads nearer than that (safe, but a wrong figure), *unknown* when it reads unknown, *too far*
when it reads farther than 1.1 x the truth or clear.

Each unknown bin is also scored as ArduPilot receives it after the fill of
:mod:`avoidd.mavlink.fill` (the nearer neighbour's reading, or still nothing): within 10 %,
nearer, farther than 1.1 x the truth, or nothing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from avoidd.config import PerceptionConfig
from avoidd.evaluation.scenes import (
    FAR_RIG,
    NEAR_RIG,
    SceneCase,
    noisy_frame,
    suite_head,
    truth_bins,
)
from avoidd.mavlink.fill import fill_from_neighbours
from avoidd.perception.sectors import covered_bins
from avoidd.pipeline import HeadPipeline
from avoidd.sources.scene import Box, Pole, Scene, render_pair
from avoidd.vision.calibration import Calibration

_HEIGHT_M = 1.5
_MAX_RANGE_M = 20.0
_TOLERANCE = 0.10
SUITES = ("walls", "poles", "clutter")
"""The hole suites, in the order they are reported."""


@dataclass
class HoleResult:
    """One scene's bins, sorted by verdict.

    Attributes:
        name: The scene.
        suite: Which suite it belongs to.
        read: Bins within 10 % of the truth.
        too_near: ``(bin, truth m, read m)`` of bins nearer than 0.9 x the truth.
        unknown: ``(bin, truth m)`` of bins that read unknown.
        too_far: ``(bin, truth m, read m)`` of bins farther than 1.1 x the truth or clear.
        filled: ``(bin, truth m, sent m)`` of the unknown bins ArduPilot gets a reading for
            (:func:`~avoidd.mavlink.fill.fill_from_neighbours`).
    """

    name: str
    suite: str
    read: int = 0
    too_near: list[tuple[int, float, float]] = field(default_factory=list)
    unknown: list[tuple[int, float]] = field(default_factory=list)
    too_far: list[tuple[int, float, float]] = field(default_factory=list)
    filled: list[tuple[int, float, float]] = field(default_factory=list)

    @property
    def bins(self) -> int:
        """Bins scored."""
        return self.read + len(self.too_near) + len(self.unknown) + len(self.too_far)


def _wall(rng: np.random.Generator, nearest_m: float, farthest_m: float) -> tuple[Box, ...]:
    """A wall across the view (split into steps to slant it) or one along the course."""
    distance = float(rng.uniform(nearest_m, farthest_m))
    if rng.random() < 0.5:
        # Boxes are upright and axis-aligned: a slanted wall is a staircase of short ones,
        # each 0.3 m wide, stepping back by the slant's tangent.
        slant = math.radians(float(rng.uniform(-40.0, 40.0)))
        centre = float(rng.uniform(-0.4, 0.4)) * distance
        width = float(rng.uniform(4.0, 10.0))
        steps = max(1, int(width / 0.3))
        parts = []
        for k in range(steps):
            right = centre + (k - (steps - 1) / 2) * 0.3
            forward = distance + (right - centre) * math.tan(slant)
            if forward > 0.6 * nearest_m:
                parts.append(Box(forward + 0.15, right, 0.3, 0.3, 3.0))
        return tuple(parts)
    # Along the course: its inner face seen at a grazing angle.
    side = 1.0 if rng.random() < 0.5 else -1.0
    lateral = float(rng.uniform(0.8, 0.5 * distance + 1.0))
    length = float(rng.uniform(4.0, 12.0))
    start = float(rng.uniform(0.3, 0.8)) * distance
    return (Box(start + length / 2, side * (lateral + 0.15), length, 0.3, 3.0),)


def _pole_row(rng: np.random.Generator) -> tuple[Pole, ...]:
    """Three to six poles in a row across the view."""
    count = int(rng.integers(3, 7))
    distance = float(rng.uniform(1.5, 10.0))
    spacing = float(rng.uniform(0.6, 2.0)) * distance / 5.0 + 0.4
    first = -spacing * (count - 1) / 2 + float(rng.uniform(-0.5, 0.5))
    poles = []
    for k in range(count):
        diameter = float(rng.uniform(0.05, 0.3))
        forward = distance + float(rng.uniform(-0.5, 0.5)) + diameter / 2
        poles.append(Pole(forward, first + k * spacing, diameter, float(rng.uniform(2.5, 4.0))))
    return tuple(poles)


def _clutter(rng: np.random.Generator) -> tuple[Box | Pole, ...]:
    """Three to six boxes and poles spread across the view, none inside another."""
    obstacles: list[Box | Pole] = []
    placed: list[tuple[float, float, float]] = []
    wanted = int(rng.integers(3, 7))
    for _ in range(40):
        if len(obstacles) == wanted:
            break
        forward = float(rng.uniform(1.2, 8.0))
        right = forward * math.tan(math.radians(float(rng.uniform(-35.0, 35.0))))
        size = float(rng.uniform(0.1, 1.2))
        if any(math.hypot(forward - f, right - r) < (size + s) / 2 + 0.3 for f, r, s in placed):
            continue
        placed.append((forward, right, size))
        if rng.random() < 0.4:
            diameter = min(size, 0.3)
            obstacles.append(Pole(forward + diameter / 2, right, diameter, 3.0))
        else:
            depth = float(rng.uniform(0.3, 1.2))
            obstacles.append(
                Box(forward + depth / 2, right, depth, size, float(rng.uniform(1.2, 3.0)))
            )
    return tuple(obstacles)


def hole_suite(name: str, count: int = 24, seed: int = 5353) -> list[SceneCase]:
    """``count`` scenes of one hole suite (see the module docstring)."""
    if name not in SUITES:
        raise ValueError(f"hole suite {name!r}: one of {', '.join(SUITES)}")
    rng = np.random.default_rng([seed, SUITES.index(name)])
    cases = []
    for index in range(count):
        rig = NEAR_RIG
        obstacles: tuple[Box | Pole, ...]
        if name == "walls":
            far = index % 3 == 2
            rig = FAR_RIG if far else NEAR_RIG
            obstacles = _wall(rng, 5.0, 18.0) if far else _wall(rng, 1.2, 8.0)
        elif name == "poles":
            obstacles = _pole_row(rng)
        else:
            obstacles = _clutter(rng)
        mount_pitch = float(rng.choice([-10.0, 0.0]))
        scene = Scene(
            camera_height_m=_HEIGHT_M,
            camera_pitch_deg=mount_pitch,
            obstacles=obstacles,
            backdrop_m=45.0 if index % 2 == 0 else None,
            seed=int(rng.integers(1, 10_000)),
            vehicle_roll_deg=float(rng.uniform(-5.0, 5.0)),
            vehicle_pitch_deg=float(rng.uniform(-5.0, 5.0)),
        )
        long = "-long" if rig is FAR_RIG else ""
        cases.append(SceneCase(f"{name}-{index:02d}{long}", rig, scene, mount_pitch))
    return cases


def run_hole_case(case: SceneCase, suite_name: str, noise_std: float = 1.5) -> HoleResult:
    """Render one scene, run the pipeline and sort every occupied bin by its verdict."""
    rendered = render_pair(case.scene, case.rig)
    frame = noisy_frame(case, rendered, noise_std)
    perception = PerceptionConfig()
    disparities = 64 if case.rig is NEAR_RIG else 128
    pipeline = HeadPipeline(
        suite_head(case, disparities),
        Calibration(case.rig, None, Path("holes")),
        _MAX_RANGE_M,
        perception,
    )
    result = pipeline.process(frame)
    resolvable_px = case.rig.fx * pipeline.sectors.min_size_m
    occupied = truth_bins(rendered.truth, pipeline.mount, case.pose, perception, resolvable_px)
    verdict = HoleResult(case.name, suite_name)
    sent_m = fill_from_neighbours(
        result.scan.distance_m, covered_bins(pipeline.work_rig, pipeline.mount)
    )
    for index, truth_m in sorted(occupied.items()):
        if truth_m > _MAX_RANGE_M:
            continue
        read_m = float(result.scan.distance_m[index])
        if math.isnan(read_m):
            verdict.unknown.append((index, truth_m))
            if math.isfinite(sent_m[index]):
                verdict.filled.append((index, truth_m, float(sent_m[index])))
        elif read_m > truth_m * (1.0 + _TOLERANCE):
            verdict.too_far.append((index, truth_m, read_m))
        elif read_m < truth_m * (1.0 - _TOLERANCE):
            verdict.too_near.append((index, truth_m, read_m))
        else:
            verdict.read += 1
    return verdict


@dataclass(frozen=True)
class HoleSummary:
    """One suite's totals.

    Attributes:
        suite: The suite.
        scenes: Scenes run.
        bins: Bins with a surface, scored.
        read: Bins within 10 % of the truth.
        too_near: Bins nearer than 0.9 x the truth.
        unknown: Bins that read unknown.
        too_far: Bins farther than 1.1 x the truth, or clear.
        filled: Unknown bins ArduPilot gets a reading for after the fill.
        filled_read: Of those, readings within 10 % of the truth.
        filled_far: Of those, readings farther than 1.1 x the truth.
    """

    suite: str
    scenes: int
    bins: int
    read: int
    too_near: int
    unknown: int
    too_far: int
    filled: int = 0
    filled_read: int = 0
    filled_far: int = 0

    def share_pct(self, count: int) -> float:
        """``count`` as a percentage of the bins scored."""
        return 100.0 * count / self.bins if self.bins else 0.0

    def line(self) -> str:
        """The suite's figures on one line."""
        return (
            f"{self.suite}: {self.share_pct(self.read):.1f}% of {self.bins} bins read within "
            f"10%, {self.share_pct(self.unknown):.1f}% unknown ({self.unknown}), "
            f"{self.too_near} too near, {self.too_far} too far, over {self.scenes} scenes; "
            f"ArduPilot after the fill: {self.filled} of the {self.unknown} unknown carry a "
            f"reading ({self.filled_read} within 10%, {self.filled_far} farther), "
            f"{self.unknown - self.filled} nothing"
        )


def summarize(results: list[HoleResult]) -> list[HoleSummary]:
    """Totals per suite, in :data:`SUITES` order (suites without scenes left out)."""
    summaries = []
    for name in SUITES:
        mine = [r for r in results if r.suite == name]
        if mine:
            summaries.append(
                HoleSummary(
                    name,
                    len(mine),
                    sum(r.bins for r in mine),
                    sum(r.read for r in mine),
                    sum(len(r.too_near) for r in mine),
                    sum(len(r.unknown) for r in mine),
                    sum(len(r.too_far) for r in mine),
                    sum(len(r.filled) for r in mine),
                    sum(abs(m - t) <= _TOLERANCE * t for r in mine for _, t, m in r.filled),
                    sum(m > (1.0 + _TOLERANCE) * t for r in mine for _, t, m in r.filled),
                )
            )
    return summaries


def format_holes(results: list[HoleResult]) -> str:
    """A table of the scenes with a bin not read, then one line per suite."""
    lines = [
        f"{'hole scene':<22} {'bins':>5} {'read':>5}  unknown (bin: truth m); too far; too near"
    ]
    for r in results:
        unknown = ", ".join(f"{b}: {t:.2f}" for b, t in r.unknown)
        far = ", ".join(f"{b}: {t:.2f} read {m:.2f}" for b, t, m in r.too_far)
        near = ", ".join(f"{b}: {t:.2f} read {m:.2f}" for b, t, m in r.too_near)
        lines.append(
            f"{r.name:<22} {r.bins:>5} {r.read:>5}  {unknown or '-'}; {far or '-'}; {near or '-'}"
        )
    lines.extend(summary.line() for summary in summarize(results))
    return "\n".join(lines)
