"""How the 72 five-degree bins are laid out in OBSTACLE_DISTANCE for each autopilot.

avoidd's own scan has bin ``i`` centred on bearing ``5 i`` (bin 0 straight ahead). What goes
on the wire is chosen for the autopilot that reads it, because the two read it differently:

- ArduPilot (``AP_Proximity_MAV``) folds the bins into eight 45-degree sectors (sector 0 from
  -22.5 to +22.5 degrees) while walking the array, and stores a sector each time the walk
  leaves it: a sector whose bins sit at both ends of the array keeps only its last run. With
  bin 0 ahead that is the front sector, whose right half (bins 0 to 4) was overwritten by its
  left half (bins 68 to 71). Starting the array at -20 degrees (``angle_offset``) puts every
  sector in one run of nine bins: message bin ``j`` holds bearing ``5 j - 20``.
- PX4 (collision prevention) keeps 36 bins of 10 degrees and fills each from the one message
  bin at its angle: five-degree bins in between would go unread. avoidd sends PX4 ten-degree
  bins, each the most cautious of the three five-degree bins that overlap it (the nearest
  reading; else unknown if any is unknown; else clear), so nothing seen is skipped.
- Any other autopilot gets the ArduPilot layout: a reader that follows the message
  definition honours ``angle_offset``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from avoidd.mavlink.modes import PX4
from avoidd.types import SECTOR_COUNT

UNKNOWN_CM = 65535


@dataclass(frozen=True)
class WireLayout:
    """One way of laying out the scan in OBSTACLE_DISTANCE.

    Attributes:
        name: For logs.
        increment_deg: Width of a message bin (``increment_f``).
        angle_offset_deg: Bearing of message bin 0 (``angle_offset``), positive right.
    """

    name: str
    increment_deg: float
    angle_offset_deg: float

    @property
    def bins(self) -> int:
        """Message bins in use (the rest of the 72 slots are unused: UINT16_MAX)."""
        return round(360.0 / self.increment_deg)

    def bearing_deg(self, index: int) -> float:
        """Bearing of message bin ``index``."""
        return (self.angle_offset_deg + index * self.increment_deg) % 360.0

    def arrange(self, distances_cm: list[int], max_cm: int) -> list[int]:
        """The 72 message values for a scan's 72 values (bin ``i`` at ``5 i`` degrees).

        Args:
            distances_cm: avoidd's bins, as :func:`avoidd.mavlink.messages.sectors_to_cm`
                gives them (65535 unknown, ``max_cm + 1`` clear).
            max_cm: The message's maximum distance.

        Returns:
            72 values in message order.
        """
        values = np.asarray(distances_cm, dtype=np.int64)
        if self.increment_deg == 5.0:
            shift = round(self.angle_offset_deg / 5.0)
            return [int(v) for v in np.roll(values, -shift)]
        step = round(self.increment_deg / 5.0)
        out = np.full(SECTOR_COUNT, UNKNOWN_CM, dtype=np.int64)
        first = round(self.angle_offset_deg / 5.0)
        for index in range(self.bins):
            centre = first + index * step
            covered = values[[(centre + k) % SECTOR_COUNT for k in range(-step + 1, step)]]
            readings = covered[covered <= max_cm]
            if readings.size:
                out[index] = readings.min()
            elif (covered == UNKNOWN_CM).any():
                out[index] = UNKNOWN_CM
            else:
                out[index] = max_cm + 1
        return [int(v) for v in out]


ARDUPILOT_LAYOUT = WireLayout("ArduPilot: 5 deg from -20 deg", 5.0, -20.0)
PX4_LAYOUT = WireLayout("PX4: 10 deg from 0 deg", 10.0, 0.0)


def layout_for(autopilot: str | None) -> WireLayout:
    """The layout for an autopilot ("ArduPilot", "PX4", another name, or None if unknown)."""
    return PX4_LAYOUT if autopilot == PX4 else ARDUPILOT_LAYOUT


def read_bins(distances_cm: list[int], increment_deg: float, angle_offset_deg: float) -> list[int]:
    """An OBSTACLE_DISTANCE's values back in avoidd's order (bin ``i`` at ``5 i`` degrees).

    The reader's side of :meth:`WireLayout.arrange`: each message bin fills the five-degree
    bins whose centre it covers (a ten-degree bin fills two; the rest stay unknown).

    Args:
        distances_cm: The message's 72 values.
        increment_deg: Its ``increment_f`` (or ``increment``), a multiple of 5.
        angle_offset_deg: Its ``angle_offset``.

    Returns:
        72 values.
    """
    out = [UNKNOWN_CM] * SECTOR_COUNT
    step = round(increment_deg / 5.0)
    first = round(angle_offset_deg / 5.0)
    for index in range(round(360.0 / increment_deg)):
        for k in range(step):
            out[(first + index * step + k) % SECTOR_COUNT] = int(distances_cm[index])
    return out
