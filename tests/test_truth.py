"""The simulation's ground truth (HIL_STATE_QUATERNION) as the world pose of an external run."""

from __future__ import annotations

import math
import time

import pytest

from avoidd.mavlink import codec as mav
from avoidd.sim.gcs import GroundStation
from avoidd.sim.truth import GroundTruth, euler_from_quaternion

LAT0_E7, LON0_E7, ALT0_MM = 473977420, 85455940, 488_000


def _hil_state(
    codec: mav.Codec,
    lat_e7: int = LAT0_E7,
    lon_e7: int = LON0_E7,
    alt_mm: int = ALT0_MM,
    velocity_cm_s: tuple[int, int, int] = (0, 0, 0),
    quaternion: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0),
) -> bytes:
    message = codec.build(
        "HIL_STATE_QUATERNION",
        0,
        list(quaternion),
        0.0,
        0.0,
        0.0,
        lat_e7,
        lon_e7,
        alt_mm,
        *velocity_cm_s,
        0,
        0,
        0,
        0,
        0,
    )
    return codec.pack(message)


def _yaw_quaternion(yaw_rad: float) -> tuple[float, float, float, float]:
    return (math.cos(yaw_rad / 2), 0.0, 0.0, math.sin(yaw_rad / 2))


def test_euler_from_quaternion_reads_roll_pitch_and_yaw() -> None:
    for roll, pitch, yaw in [(0.1, -0.2, 2.5), (-0.4, 0.3, -1.0), (0.0, 0.0, math.pi / 2)]:
        cr, sr = math.cos(roll / 2), math.sin(roll / 2)
        cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
        cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
        w = cr * cp * cy + sr * sp * sy
        x = sr * cp * cy - cr * sp * sy
        y = cr * sp * cy + sr * cp * sy
        z = cr * cp * sy - sr * sp * cy
        assert euler_from_quaternion(w, x, y, z) == pytest.approx((roll, pitch, yaw), abs=1e-9)


def test_truth_is_relative_to_the_start_and_carried_forward() -> None:
    gcs = GroundStation("udpin:127.0.0.1:9")  # never opened: fed its bytes directly
    truth = GroundTruth(gcs, offset_ne_m=(-3.0, 1.0))
    autopilot = mav.Codec(1, 1)
    assert not truth.anchor()  # nothing heard yet
    gcs._on_bytes(_hil_state(autopilot))
    assert truth.at(time.monotonic_ns()) is None  # not anchored: no start, no world position
    assert truth.anchor((0.5, -0.25))  # PX4's estimate puts the vehicle here, not at 0, 0
    # 1e-5 degree of latitude north is 1.11 m; 2.5 m up; flying north-east at 2 m/s, facing east.
    gcs._on_bytes(
        _hil_state(
            autopilot,
            lat_e7=LAT0_E7 + 100,
            alt_mm=ALT0_MM + 2500,
            velocity_cm_s=(200, 200, -50),
            quaternion=_yaw_quaternion(math.pi / 2),
        )
    )
    received_ns = gcs.newest["HIL_STATE_QUATERNION"].received_ns
    now = truth.at(received_ns)
    assert now is not None
    assert now.pose.north_m == pytest.approx(-3.0 + 0.5 + 1.113, abs=0.01)
    assert now.pose.east_m == pytest.approx(1.0 - 0.25, abs=1e-6)
    assert now.pose.down_m == pytest.approx(-2.5, abs=1e-6)
    assert now.pose.yaw_rad == pytest.approx(math.pi / 2, abs=1e-6)
    assert now.speed_m_s == pytest.approx(2.0 * math.sqrt(2.0), abs=1e-6)
    later = truth.pose_at(received_ns + 200_000_000)
    assert later is not None
    assert later.north_m - now.pose.north_m == pytest.approx(0.4, abs=1e-6)
    assert later.east_m - now.pose.east_m == pytest.approx(0.4, abs=1e-6)
    assert later.down_m - now.pose.down_m == pytest.approx(-0.1, abs=1e-6)
    # Truth older than the limit is none: the stream stopped.
    assert truth.at(received_ns + 600_000_000) is None


def test_only_the_autopilots_own_truth_counts() -> None:
    gcs = GroundStation("udpin:127.0.0.1:9")
    truth = GroundTruth(gcs)
    gcs._on_bytes(_hil_state(mav.Codec(1, 196)))  # another component of the system
    assert "HIL_STATE_QUATERNION" not in gcs.newest
    assert not truth.anchor()
    gcs._on_bytes(_hil_state(mav.Codec(1, 1)))
    assert truth.anchor()
