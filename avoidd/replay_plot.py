"""The picture of a replay: the nearest reading over time, and the truth where the input has it.

Drawn from the JSON lines ``avoidd replay`` writes (one record per frame): time from the first
frame's capture, the nearest obstacle avoidd read (a frame that read nothing near is a gap in
the line, marked along the bottom), and, for synthetic inputs, the true nearest obstacle.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any


@dataclass(frozen=True)
class NearestSeries:
    """The nearest distance per frame.

    Attributes:
        t_s: Seconds from the first frame's capture.
        nearest_m: The nearest reading (None: nothing read near).
        truth_m: The true nearest (None: the input has no truth, or nothing is near).
        has_truth: Whether any frame carried a truth.
    """

    t_s: list[float]
    nearest_m: list[float | None]
    truth_m: list[float | None]
    has_truth: bool


def series_of(records: Iterable[dict[str, Any]]) -> NearestSeries:
    """The nearest distance over time from replay records."""
    t_s: list[float] = []
    nearest_m: list[float | None] = []
    truth_m: list[float | None] = []
    has_truth = False
    first_ns: int | None = None
    for record in records:
        t_ns = int(record["t_capture_ns"])
        first_ns = t_ns if first_ns is None else first_ns
        t_s.append((t_ns - first_ns) / 1e9)
        nearest = record.get("nearest")
        nearest_m.append(None if nearest is None else float(nearest["distance_m"]))
        truth = record.get("truth")
        has_truth = has_truth or truth is not None
        value = None if truth is None else truth.get("nearest_m")
        truth_m.append(None if value is None else float(value))
    return NearestSeries(t_s, nearest_m, truth_m, has_truth)


def read_records(path: Path) -> list[dict[str, Any]]:
    """The records of a replay's JSON lines file."""
    with path.open(encoding="utf-8") as stream:
        return [json.loads(line) for line in stream if line.strip()]


def plot_nearest(series: NearestSeries, title: str, path: Path) -> None:
    """Draw the nearest distance over time to a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(figsize=(9, 4), dpi=110)
    read = [float("nan") if v is None else v for v in series.nearest_m]
    axes.plot(series.t_s, read, ".-", markersize=3, linewidth=1, label="nearest read")
    if series.has_truth:
        truth = [float("nan") if v is None else v for v in series.truth_m]
        axes.plot(series.t_s, truth, "-", color="black", linewidth=1, alpha=0.7, label="truth")
    nothing = [t for t, v in zip(series.t_s, series.nearest_m, strict=True) if v is None]
    if nothing:
        axes.plot(
            nothing,
            [0.0] * len(nothing),
            "|",
            color="tab:red",
            markersize=8,
            label=f"nothing read near ({len(nothing)} frames)",
        )
    axes.set_xlabel("time (s)")
    axes.set_ylabel("nearest obstacle (m)")
    axes.set_ylim(bottom=0.0)
    axes.set_title(title, fontsize=9)
    axes.grid(alpha=0.3)
    axes.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, borderaxespad=0.0)
    figure.tight_layout()
    figure.savefig(path)
    plt.close(figure)
