"""Top-down plot of a simulated flight: world, path coloured by speed, closest approach, time marks.

The map is cut to the flight (the path, the start and the goal, a few metres round them), so a
wall 50 m long does not shrink the path to a line; the legend and the colour bar sit outside
it. The closest approach is marked with its edge distance and time, steps nearer than the
clearance rule are ringed in red, and a mark every few seconds tells the time along the path.
The lockstep run's rows and the real-time and SITL runs' samples draw the same picture.
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from avoidd.sim.obstacles import Obstacle, SimCylinder
from avoidd.sim.world import World

if TYPE_CHECKING:
    from matplotlib.axes import Axes

    from avoidd.sim.external import ExternalRun, ExternalSummary
    from avoidd.sim.lockstep import LockstepRun
    from avoidd.sim.summary import Summary

_PAD_M = 4.0
"""The map reaches this far beyond the path, the start and the goal."""


@dataclass(frozen=True)
class FlightTrack:
    """What the picture shows of one flight.

    Attributes:
        title: The line above the map.
        world: The world (obstacles drawn where they stand at the start).
        t_s: Time of each step.
        north_m: North of each step.
        east_m: East of each step.
        speed_m_s: Horizontal speed of each step.
        clearance_m: Edge distance to the nearest obstacle at each step.
        needed_m: The clearance rule (steps nearer are ringed).
        goal_ne_m: The goal (None: none).
    """

    title: str
    world: World
    t_s: Sequence[float]
    north_m: Sequence[float]
    east_m: Sequence[float]
    speed_m_s: Sequence[float]
    clearance_m: Sequence[float]
    needed_m: float
    goal_ne_m: tuple[float, float] | None


class Step(Protocol):
    """One step of a flight as a lockstep row or a position sample gives it."""

    t_s: float
    north_m: float
    east_m: float
    speed_m_s: float
    clearance_m: float


def _track(
    title: str,
    world: World,
    steps: Sequence[Step],
    needed_m: float,
    goal: tuple[float, float] | None,
) -> FlightTrack:
    return FlightTrack(
        title,
        world,
        [s.t_s for s in steps],
        [s.north_m for s in steps],
        [s.east_m for s in steps],
        [s.speed_m_s for s in steps],
        [s.clearance_m for s in steps],
        needed_m,
        goal,
    )


def _verdict(passed: bool, failures: Sequence[str]) -> str:
    return "passed" if passed else "FAILED: " + "; ".join(failures)


def plot_run(run: LockstepRun, summary: Summary, path: Path) -> None:
    """Draw a lockstep run to a PNG (east to the right, north up)."""
    verdict = _verdict(summary.passed, summary.failures)
    title = f"{summary.name} (seed {summary.seed}): {summary.end_state}, {verdict}"
    needed_m = run.scenario.avoidance.margin_m - 0.1
    goal = None if run.goal is None else (run.goal.north_m, run.goal.east_m)
    plot_track(_track(title, run.world, run.rows, needed_m, goal), path)


def plot_external(run: ExternalRun, summary: ExternalSummary, path: Path) -> None:
    """Draw a real-time or SITL run (its position samples) to a PNG."""
    end = summary.states[-1].split(" ", 1)[-1] if summary.states else "-"
    title = f"{summary.scenario} ({summary.mode}): {end}, "
    title += _verdict(summary.passed, summary.failures)
    needed_m = run.scenario.avoidance.margin_m - 0.1
    track = _track(title, run.world, summary.samples, needed_m, (run.goal[0], run.goal[1]))
    plot_track(track, path)


def _extent(track: FlightTrack) -> tuple[float, float, float, float]:
    """West, east, south, north of the map: the path and the goal, padded."""
    east = list(track.east_m) or [0.0]
    north = list(track.north_m) or [0.0]
    if track.goal_ne_m is not None:
        north.append(track.goal_ne_m[0])
        east.append(track.goal_ne_m[1])
    return (
        min(east) - _PAD_M,
        max(east) + _PAD_M,
        min(north) - _PAD_M,
        max(north) + _PAD_M,
    )


def _time_step_s(duration_s: float) -> float:
    """A round spacing of the time marks: about ten along the flight."""
    for step in (1.0, 2.0, 5.0, 10.0, 20.0, 30.0, 60.0):
        if duration_s / step <= 12:
            return step
    return 120.0


def plot_track(
    track: FlightTrack, path: Path
) -> tuple[tuple[float, float, float, float], list[str]]:
    """Draw a flight to a PNG (east to the right, north up).

    Returns:
        The map's extent (west, east, south, north) and the legend's entries.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(figsize=(7.5, 7.5), dpi=110)
    _draw_world(axes, track.world)
    east, north = list(track.east_m), list(track.north_m)
    path_points = axes.scatter(east, north, c=list(track.speed_m_s), s=6, cmap="viridis", zorder=3)
    figure.colorbar(path_points, ax=axes, label="speed (m/s)", shrink=0.8, pad=0.02)
    close = [k for k, c in enumerate(track.clearance_m) if c < track.needed_m]
    if close:
        axes.scatter(
            [east[k] for k in close],
            [north[k] for k in close],
            s=30,
            facecolors="none",
            edgecolors="red",
            zorder=4,
            label=f"edge clearance < {track.needed_m:.1f} m",
        )
    if track.t_s:
        _time_marks(axes, track)
        nearest = min(range(len(track.t_s)), key=lambda k: track.clearance_m[k])
        clearance = track.clearance_m[nearest]
        if track.world.moves:
            _movers(axes, track, track.t_s[nearest])
        if math.isfinite(clearance):
            axes.plot(
                east[nearest],
                north[nearest],
                "x",
                color="red",
                markersize=11,
                markeredgewidth=2,
                zorder=6,
                label=f"closest: {clearance:.2f} m at {track.t_s[nearest]:.1f} s",
            )
        axes.plot(east[0], north[0], "o", color="white", markeredgecolor="black", zorder=5)
        axes.plot([], [], "o", color="white", markeredgecolor="black", label="start")
    if track.goal_ne_m is not None:
        axes.plot(
            track.goal_ne_m[1], track.goal_ne_m[0], "r*", markersize=14, zorder=5, label="goal"
        )
    west_m, east_m, south_m, north_m = _extent(track)
    axes.set_xlim(west_m, east_m)
    axes.set_ylim(south_m, north_m)
    axes.set_aspect("equal")
    axes.set_xlabel("east (m)")
    axes.set_ylabel("north (m)")
    figure.suptitle(textwrap.fill(track.title, 90), fontsize=9)
    labels: list[str] = []
    if axes.get_legend_handles_labels()[0]:
        # Below the map, clear of the path and of the colour bar.
        legend = axes.legend(
            loc="upper center", bbox_to_anchor=(0.5, -0.09), ncol=2, fontsize=8, frameon=False
        )
        labels = [text.get_text() for text in legend.get_texts()]
    axes.grid(alpha=0.3)
    figure.tight_layout()
    figure.savefig(path)
    plt.close(figure)
    return (west_m, east_m, south_m, north_m), labels


def _time_marks(axes: Axes, track: FlightTrack) -> None:
    """A small black tick with its time every few seconds along the path."""
    step_s = _time_step_s(track.t_s[-1] - track.t_s[0])
    next_s = math.ceil(track.t_s[0] / step_s) * step_s
    for k, t in enumerate(track.t_s):
        if t + 1e-9 < next_s:
            continue
        axes.plot(track.east_m[k], track.north_m[k], "k.", markersize=5, zorder=5)
        axes.annotate(
            f"{next_s:g} s",
            (track.east_m[k], track.north_m[k]),
            textcoords="offset points",
            xytext=(4, 4),
            fontsize=7,
            zorder=5,
        )
        next_s += step_s


def _draw_world(axes: Axes, world: World) -> None:
    """The obstacles where they stand at the start (above the ground: lighter)."""
    for obstacle in world.obstacles:
        shade = "0.25" if obstacle.bottom_m == 0.0 else "0.6"
        _draw_obstacle(axes, obstacle, {"color": shade})


def _movers(axes: Axes, track: FlightTrack, closest_s: float) -> None:
    """The moving obstacles' tracks (dotted) and where they were at the closest approach."""
    moving = [k for k, o in enumerate(track.world.obstacles) if o.motion is not None]
    times = track.t_s[:: max(len(track.t_s) // 200, 1)]
    for k in moving:
        placed = [track.world.at(t)[k] for t in times]
        axes.plot(
            [o.east_m for o in placed], [o.north_m for o in placed], ":", color="0.4", linewidth=1
        )
    style = {"fill": False, "edgecolor": "red", "linewidth": 1.2, "zorder": 4}
    then = track.world.at(closest_s)
    for n, k in enumerate(moving):
        _draw_obstacle(axes, then[k], style | ({} if n else {"label": "movers at the closest"}))


def _draw_obstacle(axes: Axes, obstacle: Obstacle, style: dict[str, Any]) -> None:
    """One obstacle's footprint."""
    from matplotlib.patches import Circle, Polygon

    if isinstance(obstacle, SimCylinder):
        patch: Circle | Polygon = Circle(
            (obstacle.east_m, obstacle.north_m), obstacle.radius_m, **style
        )
    else:
        c, s = math.cos(obstacle.yaw_rad), math.sin(obstacle.yaw_rad)
        corners = []
        for a, b in ((1, 1), (1, -1), (-1, -1), (-1, 1)):
            along, across = a * obstacle.half_length_m, b * obstacle.half_width_m
            corners.append(
                (
                    obstacle.east_m + along * s + across * c,
                    obstacle.north_m + along * c - across * s,
                )
            )
        patch = Polygon(corners, closed=True, **style)
    axes.add_patch(patch)
