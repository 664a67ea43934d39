"""Goals from MAVLink and the mission protocol, without sockets: global to local through the
origin (against an independent great-circle computation), refusals and their MAV_RESULT, the
mission download with lost, repeated and stray answers, retries, give-up and refresh."""

from __future__ import annotations

import math
from typing import Any

import pytest

from avoidd.daemon import goals
from avoidd.daemon.mission_follow import MissionFollower
from avoidd.mavlink import codec as mav
from avoidd.mavlink.geo import GlobalPoint, north_east_m
from avoidd.mavlink.mission import BACKOFF_NS, REFRESH_NS, RETRIES, MissionClient, MissionItem
from avoidd.planner.core import Goal
from tests.helpers import great_circle_ne

ORIGIN = GlobalPoint(47.3977419, 8.5455938, 488.0)
FRAME = goals.Frame(ORIGIN, home_up_m=0.4, altitude_m=2.0)
S = 1_000_000_000


@pytest.mark.parametrize(
    ("d_lat", "d_lon"), [(0.001, 0.0), (0.0, 0.002), (-0.004, 0.003), (0.02, -0.03)]
)
def test_global_to_local_agrees_with_great_circle_within_a_thousandth(
    d_lat: float, d_lon: float
) -> None:
    lat, lon = ORIGIN.lat_deg + d_lat, ORIGIN.lon_deg + d_lon
    north_m, east_m = north_east_m(ORIGIN, lat, lon)
    truth_n, truth_e = great_circle_ne(ORIGIN.lat_deg, ORIGIN.lon_deg, lat, lon)
    assert math.hypot(north_m - truth_n, east_m - truth_e) <= 1e-3 * math.hypot(truth_n, truth_e)


def test_across_the_antimeridian_is_a_short_hop() -> None:
    origin = GlobalPoint(10.0, 179.9999, 0.0)
    _, east_m = north_east_m(origin, 10.0, -179.9999)
    assert 21.0 < east_m < 22.5  # 0.0002 degrees of longitude at 10 degrees north


class _Msg:
    """A stand-in for a decoded message (only what the goal functions read)."""

    def __init__(self, kind: str, **fields: Any) -> None:
        self._kind = kind
        self.__dict__.update(fields)

    def get_type(self) -> str:
        return self._kind


def _reposition(frame_id: int, lat: float, lon: float, alt: float) -> _Msg:
    return _Msg("COMMAND_INT", frame=frame_id, x=round(lat * 1e7), y=round(lon * 1e7), z=alt)


def test_reposition_altitudes_amsl_above_home_and_keep_current() -> None:
    lat = ORIGIN.lat_deg + 0.001
    amsl = goals.reposition(
        _reposition(mav.MAV_FRAME_GLOBAL_INT, lat, ORIGIN.lon_deg, 498.0), FRAME
    )
    assert isinstance(amsl, Goal)
    assert amsl.altitude_m == pytest.approx(10.0)
    assert amsl.north_m == pytest.approx(111.32, abs=0.05)
    assert amsl.east_m == pytest.approx(0.0, abs=1e-6)
    relative = goals.reposition(
        _reposition(mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, lat, ORIGIN.lon_deg, 10.0), FRAME
    )
    assert isinstance(relative, Goal)
    assert relative.altitude_m == pytest.approx(10.4)  # home is 0.4 m above the origin
    keep = goals.reposition(
        _reposition(mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, lat, ORIGIN.lon_deg, math.nan), FRAME
    )
    assert isinstance(keep, Goal)
    assert keep.altitude_m == 2.0


def test_refusals_say_why_with_the_result_a_ground_station_understands() -> None:
    lat, lon = ORIGIN.lat_deg + 0.001, ORIGIN.lon_deg
    no_origin = goals.Frame(None, None, 2.0)
    cases = [
        (
            _reposition(mav.MAV_FRAME_GLOBAL_INT, lat, lon, 498.0),
            no_origin,
            mav.MAV_RESULT_TEMPORARILY_REJECTED,
        ),
        (
            _reposition(mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, lat, lon, 10.0),
            goals.Frame(ORIGIN, None, 2.0),
            mav.MAV_RESULT_TEMPORARILY_REJECTED,
        ),
        (_reposition(mav.MAV_FRAME_GLOBAL_INT, 0.0, 0.0, 498.0), FRAME, mav.MAV_RESULT_DENIED),
        (_reposition(mav.MAV_FRAME_GLOBAL_INT, 95.0, lon, 498.0), FRAME, mav.MAV_RESULT_DENIED),
        (_reposition(11, lat, lon, 10.0), FRAME, mav.MAV_RESULT_DENIED),  # terrain frame
        (
            _reposition(mav.MAV_FRAME_GLOBAL_INT, lat, lon, 488.2),
            FRAME,
            mav.MAV_RESULT_DENIED,
        ),  # 0.2 m up
        (
            _reposition(mav.MAV_FRAME_GLOBAL_INT, lat + 0.2, lon, 498.0),
            FRAME,
            mav.MAV_RESULT_DENIED,
        ),  # 22 km
    ]
    for message, frame, result in cases:
        refusal = goals.reposition(message, frame)
        assert isinstance(refusal, goals.Refusal), (message.__dict__, refusal)
        assert refusal.result == result
        assert refusal.reason


def test_the_lowest_goal_is_measured_from_home_when_home_is_known() -> None:
    """PX4's local origin can sit 2 m above or below the ground (its estimator's start): a
    goal 2.5 m above home with home 2 m below the origin is 0.5 m above the origin, and fine;
    one 0.3 m above home with home 3 m above the origin is 3.3 m above it, and too low."""
    relative = mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
    lat, lon = ORIGIN.lat_deg + 0.001, ORIGIN.lon_deg
    low_home = goals.Frame(ORIGIN, home_up_m=-2.0, altitude_m=1.0)
    taken = goals.reposition(_reposition(relative, lat, lon, 2.5), low_home)
    assert isinstance(taken, Goal) and taken.altitude_m == pytest.approx(0.5)
    high_home = goals.Frame(ORIGIN, home_up_m=3.0, altitude_m=5.0)
    refused = goals.reposition(_reposition(relative, lat, lon, 0.3), high_home)
    assert isinstance(refused, goals.Refusal) and "0.5 m above ground" in refused.reason
    local = _Msg("X", coordinate_frame=mav.MAV_FRAME_LOCAL_NED, type_mask=0x0FF8, x=1, y=0, z=-1.0)
    assert isinstance(goals.local_target(local, goals.Frame(None, -2.0, 1.0)), Goal)
    assert isinstance(goals.local_target(local, high_home), goals.Refusal)
    assert isinstance(goals.local_target(local), Goal)  # no home: above the origin


def test_local_target_needs_local_ned_and_position_bits() -> None:
    ok = _Msg(
        "X", coordinate_frame=mav.MAV_FRAME_LOCAL_NED, type_mask=0x0FF8, x=3.0, y=-2.0, z=-4.0
    )
    assert goals.local_target(ok) == Goal(3.0, -2.0, 4.0, "GCS goal")
    body = _Msg("X", coordinate_frame=8, type_mask=0x0FF8, x=3.0, y=-2.0, z=-4.0)
    velocity_only = _Msg("X", coordinate_frame=1, type_mask=0x0FC7, x=3.0, y=-2.0, z=-4.0)
    nan = _Msg("X", coordinate_frame=1, type_mask=0x0FF8, x=math.nan, y=0.0, z=-4.0)
    for message in (body, velocity_only, nan):
        assert isinstance(goals.local_target(message), goals.Refusal)


# --- the mission protocol -----------------------------------------------------------------


def _waypoint(seq: int, d_lat: float, alt: float = 5.0, command: int = 16) -> MissionItem:
    lat, lon = round((ORIGIN.lat_deg + d_lat) * 1e7), round(ORIGIN.lon_deg * 1e7)
    return MissionItem(seq, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, command, lat, lon, alt)


class _Autopilot:
    """Answers the client's requests like an autopilot, with scripted losses and repeats."""

    def __init__(self, items: list[MissionItem]) -> None:
        self.items = items
        self.codec = mav.Codec(1, 1)
        self.drops: list[tuple[str, int]] = []
        self.repeat = False
        self.acks = 0
        self.asked: list[tuple[str, int]] = []

    def answer(self, sent: list[Any]) -> list[Any]:
        replies = []
        for message in sent:
            kind = message.get_type()
            if kind == "MISSION_ACK":
                self.acks += 1
                continue
            seq = -1 if kind == "MISSION_REQUEST_LIST" else int(message.seq)
            self.asked.append((kind, seq))
            name = "MISSION_COUNT" if seq < 0 else "MISSION_ITEM_INT"
            if (name, seq) in self.drops:
                self.drops.remove((name, seq))
                continue
            if seq < 0:
                reply = self.codec.build("MISSION_COUNT", 1, 196, len(self.items), 0)
            else:
                i = self.items[seq]
                reply = self.codec.build(
                    "MISSION_ITEM_INT",
                    1,
                    196,
                    seq,
                    i.frame,
                    i.command,
                    0,
                    1,
                    0,
                    0,
                    0,
                    0,
                    i.x,
                    i.y,
                    i.z,
                    0,
                )
            replies += [reply, reply] if self.repeat else [reply]
        return replies


def _run(client: MissionClient, autopilot: _Autopilot, start_ns: int, seconds: float) -> int:
    """Tick every 100 ms for ``seconds``, delivering answers at once; returns the end time."""
    now_ns = start_ns
    for _ in range(round(seconds * 10)):
        for reply in autopilot.answer(client.tick(now_ns, 1, 1)):
            client.handle(reply, now_ns)
        now_ns += S // 10
    return now_ns


def test_download_survives_lost_and_repeated_answers_and_acks_once() -> None:
    items = [
        _waypoint(0, 0.0, 0.0),
        _waypoint(1, 0.0001),
        _waypoint(2, 0.0002),
        _waypoint(3, 0.0003),
    ]
    autopilot = _Autopilot(items)
    autopilot.drops = [("MISSION_COUNT", -1), ("MISSION_ITEM_INT", 2), ("MISSION_ITEM_INT", 2)]
    autopilot.repeat = True
    client = MissionClient(mav.Codec(1, 196))
    _run(client, autopilot, 0, 5.0)
    assert client.items == tuple(items)
    assert client.version == 1
    assert autopilot.acks == 1
    # Each loss cost exactly one more request for the same thing, after the timeout.
    assert autopilot.asked.count(("MISSION_REQUEST_LIST", -1)) == 2
    assert autopilot.asked.count(("MISSION_REQUEST_INT", 2)) == 3
    assert autopilot.asked.count(("MISSION_REQUEST_INT", 1)) == 1


def test_download_gives_up_after_its_retries_and_tries_again_after_the_backoff() -> None:
    autopilot = _Autopilot([_waypoint(0, 0.0)])
    autopilot.drops = [("MISSION_COUNT", -1)] * (RETRIES + 1)
    client = MissionClient(mav.Codec(1, 196))
    now_ns = _run(client, autopilot, 0, RETRIES + 2.5)
    assert client.items is None and client.failures == 1
    assert autopilot.asked.count(("MISSION_REQUEST_LIST", -1)) == RETRIES + 1
    _run(client, autopilot, now_ns, BACKOFF_NS / S)
    assert client.items == (autopilot.items[0],)


def test_a_changed_mission_is_read_again_and_bumps_the_version_only_when_different() -> None:
    autopilot = _Autopilot([_waypoint(0, 0.0), _waypoint(1, 0.0001)])
    client = MissionClient(mav.Codec(1, 196))
    current = autopilot.codec.build("MISSION_CURRENT", 0, 2, 0, 0)
    client.handle(current, 0)
    now_ns = _run(client, autopilot, 0, 2.0)
    assert client.version == 1
    # The periodic refresh reads the same mission: no new version.
    now_ns = _run(client, autopilot, now_ns, REFRESH_NS / S + 1.0)
    assert client.version == 1 and autopilot.acks == 2
    # A new mission is announced by MISSION_CURRENT's total: read at once.
    autopilot.items = [*autopilot.items, _waypoint(2, 0.0002)]
    client.handle(autopilot.codec.build("MISSION_CURRENT", 0, 3, 0, 0), now_ns)
    _run(client, autopilot, now_ns, 1.0)
    assert client.version == 2 and client.items is not None and len(client.items) == 3


def test_follower_skips_ardupilot_home_and_non_waypoints_and_waits_for_the_origin() -> None:
    items = [
        _waypoint(0, 0.0, 0.0),  # ArduPilot's home
        _waypoint(1, 0.0001, command=22),  # NAV_TAKEOFF: not flown by avoidd
        _waypoint(2, 0.0002),
        _waypoint(3, 0.0003, alt=0.0),  # at ground level: skipped
        _waypoint(4, 0.0004),
    ]
    autopilot = _Autopilot(items)
    client = MissionClient(mav.Codec(1, 196))
    _run(client, autopilot, 0, 2.0)
    follower = MissionFollower(client)
    assert follower.new_mission(ardupilot=True)
    assert not follower.new_mission(ardupilot=True)
    waiting = follower.goal(goals.Frame(None, None, None))
    assert isinstance(waiting, goals.Refusal)
    first = follower.goal(FRAME)
    assert isinstance(first, Goal) and first.label == "waypoint 2"
    assert first.north_m == pytest.approx(0.0002 * 1e7 * 0.011131884502145034)
    follower.advance()
    second = follower.goal(FRAME)
    assert isinstance(second, Goal) and second.label == "waypoint 4"
    follower.advance()
    assert follower.goal(FRAME) is None


def test_every_refusal_reason_fits_a_statustext() -> None:
    prefix = len("avoidd: goal refused: ")
    lat, lon = ORIGIN.lat_deg, ORIGIN.lon_deg
    reasons = [
        goals.reposition(_reposition(f, la, lo, alt), fr)
        for f, la, lo, alt, fr in [
            (mav.MAV_FRAME_GLOBAL_INT, lat, lon, 500.0, goals.Frame(None, None, None)),
            (mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, lat, lon, 5.0, goals.Frame(ORIGIN, None, 1.0)),
            (mav.MAV_FRAME_GLOBAL_INT, lat, lon, math.nan, goals.Frame(ORIGIN, None, None)),
            (mav.MAV_FRAME_GLOBAL_INT, 0.0, 0.0, 500.0, FRAME),
            (10, lat, lon, 5.0, FRAME),
            (mav.MAV_FRAME_GLOBAL_INT, lat, lon, 480.0, FRAME),
            (mav.MAV_FRAME_GLOBAL_INT, lat + 1.0, lon, 500.0, FRAME),
        ]
    ]
    assert all(isinstance(r, goals.Refusal) for r in reasons)
    assert max(prefix + len(r.reason) for r in reasons if isinstance(r, goals.Refusal)) <= 50
