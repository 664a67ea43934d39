"""OBSTACLE_DISTANCE as each autopilot reads it: a model of ArduPilot's sector folding, PX4's
ten-degree bins, and what is sent (or not) when nothing is fresh."""

from __future__ import annotations

import math

import numpy as np
import pytest

from avoidd.mavlink.layout import ARDUPILOT_LAYOUT, PX4_LAYOUT, WireLayout, layout_for
from avoidd.mavlink.modes import ARDUPILOT, PX4

UNKNOWN = 65535
MIN_CM, MAX_CM = 20, 2000
PLAIN = WireLayout("bin 0 ahead", 5.0, 0.0)


def ardupilot_sectors(values: list[int], layout: WireLayout) -> dict[int, float]:
    """What AP_Proximity_MAV keeps per 45-degree sector after one message.

    Walking the array, invalid bins (0, 65535, outside [min, max]) are skipped; the nearest
    reading of a run of bins in one sector is stored when the walk moves to another sector,
    overwriting what that sector held (its last run wins).
    """
    stored: dict[int, float] = {}
    current: int | None = None
    nearest = math.inf
    for index, value in enumerate(values[: layout.bins]):
        if value in (0, UNKNOWN) or not MIN_CM <= value <= MAX_CM:
            continue
        bearing = layout.bearing_deg(index)
        sector = int(((bearing + 22.5) % 360.0) // 45.0)
        if sector != current:
            if current is not None:
                stored[current] = nearest
            current, nearest = sector, math.inf
        nearest = min(nearest, value / 100.0)
    if current is not None:
        stored[current] = nearest
    return stored


def _scan(readings: dict[int, int], default: int = MAX_CM + 1) -> list[int]:
    values = [default] * 72
    for index, value in readings.items():
        values[index] = value
    return values


def test_the_plain_layout_loses_the_right_half_of_the_front_sector() -> None:
    # The failure the layout exists for: 1.5 m at +10 deg (bin 2), 6 m at -10 deg (bin 70),
    # and a reading in another sector in between (8 m behind, bin 36).
    scan = _scan({2: 150, 36: 800, 70: 600})
    assert ardupilot_sectors(PLAIN.arrange(scan, MAX_CM), PLAIN)[0] == 6.0  # model sees it
    assert ardupilot_sectors(ARDUPILOT_LAYOUT.arrange(scan, MAX_CM), ARDUPILOT_LAYOUT)[0] == 1.5


@pytest.mark.parametrize("seed", range(20))
def test_every_ardupilot_sector_gets_its_nearest_reading(seed: int) -> None:
    rng = np.random.default_rng(seed)
    scan = [int(v) for v in rng.integers(MIN_CM, MAX_CM + 1, 72)]
    for index in rng.choice(72, 20, replace=False):
        scan[int(index)] = int(rng.choice([UNKNOWN, MAX_CM + 1]))
    stored = ardupilot_sectors(ARDUPILOT_LAYOUT.arrange(scan, MAX_CM), ARDUPILOT_LAYOUT)
    for sector in range(8):
        # avoidd's bins whose centre lies in this sector (bearing 5 i).
        members = [i for i in range(72) if int(((5 * i + 22.5) % 360) // 45) == sector]
        readings = [scan[i] for i in members if MIN_CM <= scan[i] <= MAX_CM]
        if readings:
            assert stored[sector] == min(readings) / 100.0
        else:
            assert sector not in stored


def test_ardupilot_layout_is_a_rotation_of_the_scan() -> None:
    scan = list(range(100, 172))
    message = ARDUPILOT_LAYOUT.arrange(scan, MAX_CM)
    for index in range(72):
        bearing = ARDUPILOT_LAYOUT.bearing_deg(index)
        assert message[index] == scan[round(bearing / 5.0) % 72]


def test_px4_gets_ten_degree_bins_each_the_most_cautious_of_its_overlap() -> None:
    # PX4 fills each of its 10-degree bins from the one message bin at that angle: a reading
    # only in a 5-degree bin between two of them must not vanish.
    scan = _scan({1: 300, 10: UNKNOWN, 20: 500, 21: 400})
    message = PX4_LAYOUT.arrange(scan, MAX_CM)
    assert PX4_LAYOUT.bins == 36 and message[36:] == [UNKNOWN] * 36
    assert message[0] == 300 and message[1] == 300  # bin 1 (+5 deg) overlaps 0 and 10 deg
    assert message[5] == UNKNOWN  # 50 deg: one of its three bins unknown, none a reading
    assert message[10] == 400  # 100 deg: min of 500 and 400
    assert message[20] == MAX_CM + 1  # all clear
    for index in range(36):
        assert PX4_LAYOUT.bearing_deg(index) == 10.0 * index


def test_layout_follows_the_autopilot() -> None:
    assert layout_for(PX4) is PX4_LAYOUT
    assert layout_for(ARDUPILOT) is ARDUPILOT_LAYOUT
    assert layout_for(None) is ARDUPILOT_LAYOUT
