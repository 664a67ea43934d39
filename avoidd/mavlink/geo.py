"""Global positions (latitude, longitude, altitude) to the autopilot's local NED frame.

Both autopilots put the origin of LOCAL_POSITION_NED at their EKF origin, which they report as
GPS_GLOBAL_ORIGIN. Over the few kilometres a local planner flies, a flat projection around the
origin is as good as the autopilot's own: this one uses ArduPilot's constants
(``Location::get_distance_NE``: 0.011131884502145034 m per 1e-7 degree of latitude, longitude
scaled by the cosine of the mean latitude), so avoidd and ArduPilot agree to the centimetre.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

METRES_PER_DEG_E7 = 0.011131884502145034
"""Metres per 1e-7 degree of latitude (ArduPilot's LOCATION_SCALING_FACTOR)."""


@dataclass(frozen=True)
class GlobalPoint:
    """A position on the earth.

    Attributes:
        lat_deg: Latitude, degrees.
        lon_deg: Longitude, degrees.
        alt_m: Altitude above mean sea level, metres.
    """

    lat_deg: float
    lon_deg: float
    alt_m: float


def valid_lat_lon(lat_deg: float, lon_deg: float) -> bool:
    """Whether a latitude and longitude are finite and on the earth (not the 0, 0 "unset")."""
    finite = math.isfinite(lat_deg) and math.isfinite(lon_deg)
    on_earth = finite and abs(lat_deg) <= 90.0 and abs(lon_deg) <= 180.0
    return on_earth and not (lat_deg == 0.0 and lon_deg == 0.0)


def north_east_m(origin: GlobalPoint, lat_deg: float, lon_deg: float) -> tuple[float, float]:
    """Horizontal offset of a point from the origin: metres north and east.

    Args:
        origin: The local frame's origin.
        lat_deg: The point's latitude.
        lon_deg: The point's longitude.

    Returns:
        (north_m, east_m).
    """
    d_lon_deg = math.remainder(lon_deg - origin.lon_deg, 360.0)  # across the antimeridian
    mean_lat_rad = math.radians((lat_deg + origin.lat_deg) / 2.0)
    north_m = (lat_deg - origin.lat_deg) * 1e7 * METRES_PER_DEG_E7
    east_m = d_lon_deg * 1e7 * METRES_PER_DEG_E7 * max(math.cos(mean_lat_rad), 0.01)
    return north_m, east_m


def offset_lat_lon(origin: GlobalPoint, north_m: float, east_m: float) -> tuple[float, float]:
    """The latitude and longitude of a point given north and east of the origin.

    The exact inverse of :func:`north_east_m` (the same flat projection).

    Args:
        origin: The local frame's origin.
        north_m: Metres north of it.
        east_m: Metres east of it.

    Returns:
        (lat_deg, lon_deg).
    """
    lat_deg = origin.lat_deg + north_m / (1e7 * METRES_PER_DEG_E7)
    mean_lat_rad = math.radians((lat_deg + origin.lat_deg) / 2.0)
    scale = 1e7 * METRES_PER_DEG_E7 * max(math.cos(mean_lat_rad), 0.01)
    lon_deg = math.remainder(origin.lon_deg + east_m / scale, 360.0)
    return lat_deg, lon_deg
