"""Pure parts of the MAVLink side: mode decoding, clock sync, attitude history, signing state."""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import pytest

from avoidd.config import MavlinkConfig
from avoidd.errors import ConfigError
from avoidd.mavlink import codec as mav
from avoidd.mavlink.attitude import Attitude, AttitudeHistory
from avoidd.mavlink.clock import ClockSync
from avoidd.mavlink.link import MavLink
from avoidd.mavlink.mock_autopilot import _mode_fields
from avoidd.mavlink.modes import decode_mode
from avoidd.mavlink.signing import load_key, parse_key
from avoidd.mavlink.vehicle import Vehicle

COPTER = mav.MAV_TYPE_QUADROTOR


# The numbers below are the autopilots' own, written out (not taken from the table the decoder
# uses): ArduCopter's custom_mode values (ArduPilot's mode.h, MAVLink docs), and PX4's
# custom_mode with the main mode in bits 16-23 and the sub mode in bits 24-31 (px4_custom_mode.h).
# HEARTBEAT fields: autopilot 3 = ArduPilot, 12 = PX4; type 2 = quadrotor, 1 = fixed wing,
# 10 = ground rover; base_mode bit 1 = custom mode enabled, bit 128 = armed.
ARDUPILOT_ID, PX4_ID = 3, 12
CUSTOM, ARMED = 1, 128


@pytest.mark.parametrize(
    ("vehicle_type", "custom_mode", "name"),
    [
        (2, 0, "STABILIZE"),
        (2, 1, "ACRO"),
        (2, 2, "ALT_HOLD"),
        (2, 3, "AUTO"),
        (2, 4, "GUIDED"),
        (2, 5, "LOITER"),
        (2, 6, "RTL"),
        (2, 7, "CIRCLE"),
        (2, 9, "LAND"),
        (2, 16, "POSHOLD"),
        (2, 17, "BRAKE"),
        (2, 20, "GUIDED_NOGPS"),  # attitude targets only, no velocity: not guided for us
        (2, 21, "SMART_RTL"),
        (1, 15, "GUIDED"),  # ArduPlane numbers its modes differently
        (1, 10, "AUTO"),
        (10, 15, "GUIDED"),  # and so does Rover
        (10, 4, "HOLD"),
        (2, 250, "MODE 250"),
    ],
)
def test_ardupilot_modes_by_vehicle_type(vehicle_type: int, custom_mode: int, name: str) -> None:
    mode = decode_mode(ARDUPILOT_ID, vehicle_type, CUSTOM | ARMED, custom_mode)
    assert (mode.autopilot, mode.name, mode.armed) == ("ArduPilot", name, True)
    assert mode.guided == (name == "GUIDED")
    assert mode.vehicle_type == vehicle_type


PX4_MODES = [
    (0x0001_0000, "MANUAL"),
    (0x0002_0000, "ALTCTL"),
    (0x0003_0000, "POSCTL"),
    (0x0204_0000, "TAKEOFF"),  # AUTO (4) with its sub modes
    (0x0304_0000, "LOITER"),
    (0x0404_0000, "MISSION"),
    (0x0504_0000, "RTL"),
    (0x0604_0000, "LAND"),
    (0x0005_0000, "ACRO"),
    (0x0006_0000, "OFFBOARD"),
    (0x0007_0000, "STABILIZED"),
]


@pytest.mark.parametrize(("custom_mode", "name"), PX4_MODES)
def test_px4_modes_from_main_and_sub_mode(custom_mode: int, name: str) -> None:
    mode = decode_mode(PX4_ID, 2, CUSTOM, custom_mode)
    assert (mode.autopilot, mode.name, mode.armed) == ("PX4", name, False)
    assert mode.guided == (name == "OFFBOARD")


@pytest.mark.parametrize("custom_mode", [0x0104_0000, 0x0009_0000, 0x0004_0000])
def test_px4_modes_without_a_name_are_no_other_mode(custom_mode: int) -> None:
    # AUTO.READY (main 4, sub 1) is missing from pymavlink's table, main mode 9 does not exist,
    # and AUTO needs a sub mode: each comes out as its number, never as a mode it is not.
    mode = decode_mode(PX4_ID, 2, CUSTOM | ARMED, custom_mode)
    assert (mode.autopilot, mode.name, mode.armed, mode.guided) == (
        "PX4",
        f"MODE {custom_mode}",
        True,
        False,
    )


@pytest.mark.parametrize(
    ("system_status", "failsafe"),
    [
        (mav.MAV_STATE_STANDBY, False),
        (mav.MAV_STATE_ACTIVE, False),
        (mav.MAV_STATE_CRITICAL, True),
        (mav.MAV_STATE_EMERGENCY, True),
        (mav.MAV_STATE_FLIGHT_TERMINATION, True),
    ],
)
def test_a_failsafe_is_read_from_the_heartbeat_system_status(
    system_status: int, failsafe: bool
) -> None:
    mode = decode_mode(PX4_ID, 2, CUSTOM | ARMED, 0x0003_0000, system_status)
    assert (mode.name, mode.failsafe) == ("POSCTL", failsafe)


def test_without_the_custom_mode_flag_no_mode_is_read() -> None:
    mode = decode_mode(ARDUPILOT_ID, 2, ARMED, 4)  # custom_mode 4 would be GUIDED
    assert (mode.name, mode.guided, mode.armed) == ("NO CUSTOM MODE", False, True)


@pytest.mark.parametrize(
    ("flavour", "name", "custom_mode"),
    [
        ("ardupilot", "GUIDED", 4),
        ("ardupilot", "LOITER", 5),
        ("ardupilot", "SMART_RTL", 21),
        ("px4", "OFFBOARD", 0x0006_0000),
        ("px4", "POSCTL", 0x0003_0000),
        ("px4", "MISSION", 0x0404_0000),
    ],
)
def test_the_mock_sends_the_autopilots_numbers(flavour: str, name: str, custom_mode: int) -> None:
    base, custom = _mode_fields(flavour, 2, name, armed=True)
    assert custom == custom_mode and base & CUSTOM and base & ARMED
    base, custom = _mode_fields(flavour, 2, name, armed=False)
    assert custom == custom_mode and base & CUSTOM and not base & ARMED


def test_clock_sync_takes_the_fastest_message_and_follows_a_reboot() -> None:
    clock = ClockSync()
    assert clock.to_autopilot_boot_ns(5_000_000_000) is None  # not synced yet
    true_offset_ns = 123_456_000_000  # autopilot booted 123.456 s before us... in its clock
    delays_ns = [4_000_000, 900_000, 7_000_000, 2_500_000]
    for i, delay_ns in enumerate(delays_ns):
        local_send_ns = 10_000_000_000 + i * 20_000_000
        boot_ms = (local_send_ns + true_offset_ns) // 1_000_000
        assert not clock.observe_boot_ms(boot_ms, local_send_ns + delay_ns)
    assert clock.offset_ns is not None
    assert true_offset_ns - 1_000_000 <= clock.offset_ns <= true_offset_ns
    assert clock.offset_ns == true_offset_ns - 900_000  # the fastest message wins
    assert clock.to_autopilot_boot_ns(11_000_000_000) == 11_000_000_000 + clock.offset_ns
    # A message delayed by half a second is late, not a reboot.
    late_ms = (10_100_000_000 + true_offset_ns) // 1_000_000
    assert not clock.observe_boot_ms(late_ms, 10_600_000_000)
    # A reboot: the autopilot's clock restarts near zero. One such message could be a late
    # read; still so 0.2 s later, it is a reboot, and the estimate follows at once.
    assert not clock.observe_boot_ms(50, 20_000_000_000)
    assert clock.observe_boot_ms(250, 20_200_000_000)
    assert clock.offset_ns == 250_000_000 - 20_200_000_000


def test_clock_sync_sees_a_reboot_after_a_short_uptime() -> None:
    # ArduPilot SITL reboots in under 3 s: its clock goes back by little, but by more than
    # any delay in transit explains.
    clock = ClockSync()
    for i in range(10):
        clock.observe_boot_ms(2_000 + 100 * i, 10_000_000_000 + i * 100_000_000)
    assert not clock.observe_boot_ms(800, 11_500_000_000)  # 2.8 s up -> 0.8 s up, 0.5 s later
    assert clock.observe_boot_ms(1_000, 11_700_000_000)  # and still so 0.2 s on


def test_a_burst_of_stamps_read_late_by_a_busy_machine_is_no_reboot() -> None:
    # The autopilot stamps a message every 20 ms; avoidd's loop stalls for 1.5 s and then reads
    # the 75 queued messages at once: they look 1.5 s late, but the boot clock never went back.
    clock = ClockSync()
    offset_ns = 60_000_000_000
    for i in range(100):
        sent_ns = 10_000_000_000 + i * 20_000_000
        assert not clock.observe_boot_ms((sent_ns + offset_ns) // 1_000_000, sent_ns + 1_000_000)
    stalled_until_ns = 12_000_000_000 + 1_500_000_000
    for i in range(100, 175):
        sent_ns = 10_000_000_000 + i * 20_000_000
        assert not clock.observe_boot_ms((sent_ns + offset_ns) // 1_000_000, stalled_until_ns)
    # The messages after the burst are on time again.
    for i in range(175, 200):
        sent_ns = 10_000_000_000 + i * 20_000_000
        assert not clock.observe_boot_ms((sent_ns + offset_ns) // 1_000_000, sent_ns + 1_000_000)
    assert clock.offset_ns == offset_ns - 1_000_000  # the fast messages still set the estimate
    # A real reboot right after is still seen.
    assert not clock.observe_boot_ms(400, 14_100_000_000)
    assert clock.observe_boot_ms(600, 14_300_000_000)


def test_attitude_interpolates_and_wraps_yaw() -> None:
    history = AttitudeHistory(span_ns=1_000_000_000, max_gap_ns=100_000_000)
    history.add(Attitude(0, 0.0, 0.1, math.pi - 0.1))
    history.add(Attitude(20_000_000, 0.2, 0.3, -math.pi + 0.1))
    mid = history.at(10_000_000)
    assert mid is not None
    assert mid.roll_rad == pytest.approx(0.1)
    assert mid.pitch_rad == pytest.approx(0.2)
    assert abs(abs(mid.yaw_rad) - math.pi) < 1e-9  # through +-180, not through 0
    quarter = history.at(5_000_000)
    assert quarter is not None and quarter.yaw_rad == pytest.approx(math.pi - 0.05)


def test_attitude_refuses_what_it_cannot_vouch_for() -> None:
    history = AttitudeHistory(span_ns=1_000_000_000, max_gap_ns=100_000_000)
    assert history.at(0) is None
    history.add(Attitude(1_000_000_000, 0.1, 0.0, 0.0))
    history.add(Attitude(1_500_000_000, 0.3, 0.0, 0.0))  # a 500 ms gap: a lost link
    assert history.at(900_000_000) is None  # before the history
    assert history.at(1_200_000_000) is None  # inside a gap too wide to interpolate
    held = history.at(1_550_000_000)
    assert held is not None and held.roll_rad == 0.3  # just after the newest: held
    assert history.at(1_700_000_000) is None  # too far after the newest
    history.add(Attitude(1_250_000_000, 0.2, 0.0, 0.0))  # late arrival goes in its place
    assert history.at(1_250_000_000) is not None
    history.add(Attitude(2_600_000_000, 0.0, 0.0, 0.0))
    assert len(history) == 1  # everything older than the span is gone


def test_signing_keys_raw_hex_and_bad(tmp_path: Path) -> None:
    raw = bytes(range(32))
    assert parse_key(raw, "k") == raw
    assert parse_key((raw.hex() + "\n").encode(), "k") == raw
    with pytest.raises(ConfigError, match="sha256sum"):
        parse_key(b"secret passphrase", "k")
    path = tmp_path / "key"
    path.write_text(raw.hex())
    assert load_key(path, None) == raw
    with pytest.raises(ConfigError, match="cannot read the signing key"):
        load_key(tmp_path / "missing", None)


def test_signing_key_from_systemd_credentials(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    (tmp_path / "mavlink-key").write_bytes(bytes(32))
    monkeypatch.setenv("CREDENTIALS_DIRECTORY", str(tmp_path))
    assert load_key(None, "mavlink-key") == bytes(32)
    monkeypatch.delenv("CREDENTIALS_DIRECTORY")
    with pytest.raises(ConfigError, match="LoadCredential"):
        load_key(None, "mavlink-key")


async def test_vehicle_adopts_the_autopilot_and_ignores_others() -> None:
    config = MavlinkConfig(connection="udpout:127.0.0.1:9")
    link = MavLink(config.link, mav.Codec(1, 196))
    events: list[str] = []
    vehicle = Vehicle(link, config, lambda severity, text, key=None: events.append(text))

    def heartbeat(system: int, component: int, kind: int, autopilot: int, custom: int) -> None:
        sender = mav.Codec(system, component)
        base = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        message = sender.build("HEARTBEAT", kind, autopilot, base, custom, 4)
        for decoded in link.codec.decode(sender.pack(message)):
            vehicle.handle(decoded, 1_000)

    heartbeat(255, 190, mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0)  # a ground station
    heartbeat(3, 196, mav.MAV_TYPE_ONBOARD_CONTROLLER, mav.MAV_AUTOPILOT_INVALID, 0)
    assert vehicle.system_id is None and vehicle.mode is None
    heartbeat(3, 1, COPTER, mav.MAV_AUTOPILOT_ARDUPILOTMEGA, 4)
    assert vehicle.system_id == 3 and link.codec.system_id == 3
    assert vehicle.mode is not None and vehicle.mode.name == "GUIDED"
    assert vehicle.link_up and events == ["avoidd: link up, ArduPilot GUIDED"]
    heartbeat(4, 1, COPTER, mav.MAV_AUTOPILOT_ARDUPILOTMEGA, 6)  # another vehicle
    assert vehicle.system_id == 3 and vehicle.mode.name == "GUIDED"
    assert vehicle.ignored[4] == 1
    vehicle.tick(1_000 + 4_000_000_000)  # no heartbeat for 4 s > 3 s timeout
    assert not vehicle.link_up and events[-1] == "avoidd: link down"


async def test_a_late_tick_judges_no_silence_until_the_socket_was_read() -> None:
    # avoidd did not run for 4 s (a busy machine): the autopilot's heartbeats of that time may
    # still wait in the socket. The late tick leaves the link up; a tick on time after it, with
    # still nothing heard, says it is down.
    config = MavlinkConfig(connection="udpout:127.0.0.1:9")
    link = MavLink(config.link, mav.Codec(1, 196))
    vehicle = Vehicle(link, config, lambda severity, text, key=None: None)
    sender = mav.Codec(3, 1)
    beat = sender.build("HEARTBEAT", COPTER, mav.MAV_AUTOPILOT_ARDUPILOTMEGA, 1, 4, 4)
    for decoded in link.codec.decode(sender.pack(beat)):
        vehicle.handle(decoded, 1_000)
    assert vehicle.link_up
    vehicle.tick(100_000_000)
    vehicle.tick(4_100_000_000)  # 4 s late
    assert vehicle.link_up and vehicle.late_ticks == 1
    vehicle.tick(4_200_000_000)
    assert not vehicle.link_up
    # A loop so slow that every tick is late still judges, every other tick.
    for decoded in link.codec.decode(sender.pack(beat)):
        vehicle.handle(decoded, 4_300_000_000)
    assert vehicle.link_up
    vehicle.tick(5_000_000_000)
    vehicle.tick(8_000_000_000)  # late after late: judged
    assert not vehicle.link_up and vehicle.late_ticks == 3


async def test_vehicle_with_a_fixed_system_id_never_adopts_another() -> None:
    config = MavlinkConfig(connection="udpout:127.0.0.1:9", system_id=9)
    link = MavLink(config.link, mav.Codec(9, 196))
    vehicle = Vehicle(link, config, lambda severity, text, key=None: None)
    sender = mav.Codec(2, 1)
    message = sender.build("HEARTBEAT", COPTER, mav.MAV_AUTOPILOT_PX4, 1, 6 << 16, 4)
    for decoded in link.codec.decode(sender.pack(message)):
        vehicle.handle(decoded, 0)
    assert vehicle.system_id == 9 and vehicle.mode is None and vehicle.ignored[2] == 1


class _OpenLink:
    """The link as the vehicle sees it: connected, recording what is sent."""

    connected = True

    def __init__(self) -> None:
        self.codec = mav.Codec(1, 196)
        self.sent: list[bytes] = []

    def send(self, data: bytes) -> bool:
        self.sent.append(data)
        return True

    def subscribe(self, handler: object) -> None:
        pass


def test_an_accepted_stream_that_never_delivers_is_asked_again_less_and_less_often() -> None:
    # DISTANCE_SENSOR accepted by an autopilot without a rangefinder: asked again 1 s after it
    # was accepted, then after 2, 4, ... up to 64 s; never taken for a reboot.
    link = _OpenLink()
    config = MavlinkConfig(connection="udpout:127.0.0.1:9")
    vehicle = Vehicle(link, config, lambda severity, text, key=None: None)  # type: ignore[arg-type]
    vehicle.system_id, vehicle.link_up = 1, True
    quiet = next(r for r in vehicle.requests if r.name == "DISTANCE_SENSOR")
    step_ns, s_ns = 100_000_000, 1_000_000_000
    asked_s: list[float] = []
    for t_ns in range(0, 300 * s_ns, step_ns):
        vehicle.last_heartbeat_ns = t_ns
        for other in vehicle.requests:
            if other is not quiet and other.acked:
                other.last_ns = t_ns  # the other streams deliver
        before = quiet.quiet_asks
        vehicle.tick(t_ns)
        if quiet.quiet_asks > before:
            asked_s.append(t_ns / s_ns)
        pending = vehicle._pending
        if pending is not None:  # the autopilot accepts each request at once
            pending.acked, pending.acked_ns = True, t_ns
            vehicle._pending = None
    gaps_s = [round(b - a) for a, b in itertools.pairwise(asked_s)]
    assert gaps_s[:5] == [2, 4, 8, 16, 32] and len(gaps_s) >= 7
    assert set(gaps_s[5:]) == {64}
    assert vehicle.reboots == 0 and vehicle.silent_streams == 0
    assert vehicle.quiet_streams == len(asked_s)
    # Once it delivers, the back-off starts over.
    autopilot = mav.Codec(1, 1)
    reading = autopilot.build("DISTANCE_SENSOR", 0, 10, 4000, 150, 0, 0, 25, 0)
    for decoded in link.codec.decode(autopilot.pack(reading)):
        vehicle.handle(decoded, 300 * s_ns)
    assert quiet.quiet_asks == 0 and quiet.last_ns == 300 * s_ns


def test_an_origin_that_never_comes_is_said_once_after_ten_seconds(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """avoidd asks for GPS_GLOBAL_ORIGIN and HOME_POSITION every 2 s until they come; an
    operator hears once that goals wait for them, not once per request, and never for one
    that came."""
    link = _OpenLink()
    config = MavlinkConfig(connection="udpout:127.0.0.1:9")
    vehicle = Vehicle(link, config, lambda severity, text, key=None: None)  # type: ignore[arg-type]
    vehicle.system_id, vehicle.link_up, vehicle.wants_origin = 1, True, True
    sender = mav.Codec(1, 1)
    home = sender.build("HOME_POSITION", 0, 0, 0, 0.0, 0.0, -1.5, [1, 0, 0, 0], 0, 0, 0, 0)
    step_ns, s_ns = 100_000_000, 1_000_000_000
    for t_ns in range(0, 40 * s_ns, step_ns):
        vehicle.last_heartbeat_ns = t_ns
        if t_ns == 4 * s_ns:  # home answers the second request; the origin never comes
            for decoded in link.codec.decode(sender.pack(home)):
                vehicle.handle(decoded, t_ns)
        vehicle.tick(t_ns)
    warnings = [
        r.getMessage()
        for r in caplog.records
        if r.levelname == "WARNING" and "stream request" not in r.getMessage()  # unanswered
    ]
    assert len(warnings) == 1, warnings
    assert "no GPS_GLOBAL_ORIGIN after 5 requests" in warnings[0]
    assert vehicle.home_up_m == pytest.approx(1.5) and vehicle.origin is None
