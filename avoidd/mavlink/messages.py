"""What avoidd's scans become on the wire: centimetre bins with the MAVLink special values."""

from __future__ import annotations

import numpy as np

from avoidd.types import SectorScan

UNKNOWN_CM = 65535


def sectors_to_cm(scan: SectorScan, min_cm: int, max_cm: int) -> list[int]:
    """OBSTACLE_DISTANCE values of a scan.

    Unknown bins become 65535, clear bins ``max_cm + 1``, readings are clamped into
    ``[min_cm, max_cm]`` (so a reading is never 0).

    Args:
        scan: The scan in metres (NaN unknown, ``inf`` clear).
        min_cm: The sensor's minimum distance.
        max_cm: The sensor's maximum distance.

    Returns:
        72 integers.
    """
    metres = scan.distance_m.astype(np.float64)
    out = np.full(metres.shape, UNKNOWN_CM, dtype=np.int64)
    finite = np.isfinite(metres)
    out[finite] = np.clip(np.rint(metres[finite] * 100.0), min_cm, max_cm)
    out[np.isposinf(metres)] = max_cm + 1
    return [int(v) for v in out]


def unknown_cm() -> list[int]:
    """72 unknown bins (stale or missing data)."""
    return [UNKNOWN_CM] * 72
