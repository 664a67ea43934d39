"""Unknown bins for an autopilot that reads them as nothing: the nearer neighbour's reading.

ArduPilot (``AP_Proximity_MAV``) skips a bin of 65535, so an unknown bin holds nothing for it:
where every bin of one of its 45-degree sectors is unknown, its avoidance flies into that
sector as if it were empty. A bin inside a head's view that could not be vouched for, beside
a bin that measured a surface at ``d``, has evidence of a surface about there, and ``d`` is
nearer than the nothing ArduPilot would read. Such a bin is sent with the nearer of its two
neighbours' readings. Nothing else changes: a bin with no reading beside it stays unknown
(never clear), a clear neighbour lends nothing, a filled bin lends nothing to the next (the
fill never spreads), and a bin outside every view stays unknown. Readings the temporal filter
holds from earlier scans are already in the scan it gets (``perception.temporal.hold_ms``).

PX4 reads 65535 as "no data" and blocks the bin with ``CP_GO_NO_DATA`` 0: it gets the scan
unchanged.
"""

from __future__ import annotations

import numpy as np

from avoidd.types import BoolArray, FloatArray


def fill_from_neighbours(distance_m: FloatArray, in_view: BoolArray) -> FloatArray:
    """The scan's distances with each unknown bin in view beside a reading given the nearer one.

    Args:
        distance_m: (72,) metres per bin: NaN unknown, ``inf`` clear (bins wrap round).
        in_view: (72,) the bins some head's field of view covers.

    Returns:
        A new (72,) array; the input is left as it is.
    """
    measured = np.where(np.isfinite(distance_m), distance_m, np.inf)
    nearer = np.minimum(np.roll(measured, 1), np.roll(measured, -1))
    take = np.isnan(distance_m) & in_view & np.isfinite(nearer)
    return np.where(take, nearer, distance_m).astype(distance_m.dtype)
