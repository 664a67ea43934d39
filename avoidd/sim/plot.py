"""Top-down plot of a simulated flight: world, path coloured by speed, clearance violations."""

from __future__ import annotations

import math
from pathlib import Path

from avoidd.sim.lockstep import LockstepRun
from avoidd.sim.summary import Summary
from avoidd.sim.world import SimBox, SimCylinder


def plot_run(run: LockstepRun, summary: Summary, path: Path) -> None:
    """Draw the run to a PNG (east to the right, north up)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle, Polygon

    figure, axes = plt.subplots(figsize=(7, 7), dpi=110)
    for obstacle in run.world.obstacles:  # where they stand at the start
        shade = "0.25" if obstacle.bottom_m == 0.0 else "0.6"  # above the ground: lighter
        if isinstance(obstacle, SimCylinder):
            axes.add_patch(
                Circle((obstacle.east_m, obstacle.north_m), obstacle.radius_m, color=shade)
            )
        elif isinstance(obstacle, SimBox):
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
            axes.add_patch(Polygon(corners, closed=True, color=shade))
    east = [r.east_m for r in run.rows]
    north = [r.north_m for r in run.rows]
    speed = [r.speed_m_s for r in run.rows]
    path_points = axes.scatter(east, north, c=speed, s=6, cmap="viridis", zorder=3)
    figure.colorbar(path_points, ax=axes, label="speed (m/s)", shrink=0.8)
    needed = run.scenario.avoidance.margin_m - 0.1
    close = [r for r in run.rows if r.clearance_m < needed]
    if close:
        axes.scatter(
            [r.east_m for r in close],
            [r.north_m for r in close],
            s=30,
            facecolors="none",
            edgecolors="red",
            zorder=4,
            label=f"edge clearance < {needed:.1f} m",
        )
    if run.goal is not None:
        axes.plot(run.goal.east_m, run.goal.north_m, "r*", markersize=14, label="goal")
    axes.plot(east[:1], north[:1], "go", label="start")
    axes.set_aspect("equal")
    axes.set_xlabel("east (m)")
    axes.set_ylabel("north (m)")
    verdict = "passed" if summary.passed else "FAILED: " + "; ".join(summary.failures)
    axes.set_title(f"{summary.name} (seed {summary.seed}): {summary.end_state}, {verdict}")
    axes.legend(loc="lower right", fontsize=8)
    axes.grid(alpha=0.3)
    figure.tight_layout()
    figure.savefig(path)
    plt.close(figure)
