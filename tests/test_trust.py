"""Who may command avoidd: the trust rule, bounded parameters, and signing state across restarts."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from avoidd.config import AvoidanceConfig, ControlConfig
from avoidd.daemon.params import Outcome, ParamTable
from avoidd.mavlink import codec as mav
from avoidd.mavlink.signing import (
    EPOCH_2015_S,
    NEW_STREAM_WINDOW,
    RESTART_STEP_S,
    UNITS_PER_S,
    TimestampStore,
    wall_timestamp,
)
from avoidd.mavlink.trust import Trust

KEY = bytes(range(32))
NOW_S = EPOCH_2015_S + 11 * 365 * 86400  # a board whose clock is right


# --- parameters --------------------------------------------------------------------------------


def test_unsigned_sets_may_only_make_avoidd_more_cautious() -> None:
    table = ParamTable(AvoidanceConfig(), None)
    for name, value in (
        ("AVD_ENABLE", 1.0),
        ("AVD_MARGIN", 0.6),
        ("AVD_MAX_SPEED", 5.0),
        ("AVD_MAX_ACCEL", 4.0),
        ("AVD_YAW_RATE", 90.0),
    ):
        assert table.set(name, value, may_weaken=False) is Outcome.WEAKENS, name
    assert table.config == AvoidanceConfig()
    # The cautious way is always open, and a parameter that is neither way is free.
    for name, value in (
        ("AVD_MARGIN", 2.0),
        ("AVD_RADIUS", 0.8),
        ("AVD_MAX_SPEED", 1.0),
        ("AVD_MAX_ACCEL", 1.0),
        ("AVD_YAW_RATE", 30.0),
        ("AVD_ACCEPT_RAD", 3.0),
        ("AVD_ENABLE", 0.0),
    ):
        assert table.set(name, value, may_weaken=False) is Outcome.SET, name
    assert table.config.margin_m == 2.0 and table.config.max_speed_m_s == 1.0
    assert table.set("AVD_RADIUS", 0.6, may_weaken=False) is Outcome.WEAKENS
    # Back down from 2.0 is less cautious again: refused unsigned, taken signed.
    assert table.set("AVD_MARGIN", 1.0, may_weaken=False) is Outcome.WEAKENS
    assert table.set("AVD_MARGIN", 1.0, may_weaken=True) is Outcome.SET
    assert table.set("AVD_ENABLE", 1.0, may_weaken=True) is Outcome.SET
    assert table.config.enabled


def test_the_margin_and_radius_have_floors_whoever_asks() -> None:
    config = AvoidanceConfig(vehicle_radius_m=0.4, margin_m=1.0, min_margin_m=0.7)
    table = ParamTable(config, None)
    assert table.bounds("AVD_RADIUS") == (0.4, 5.0)
    assert table.bounds("AVD_MARGIN") == (0.7, 10.0)
    assert table.set("AVD_MARGIN", 0.0, may_weaken=True) is Outcome.RANGE
    assert table.set("AVD_MARGIN", 0.69, may_weaken=True) is Outcome.RANGE
    assert table.set("AVD_RADIUS", 0.05, may_weaken=True) is Outcome.RANGE
    assert table.set("AVD_MARGIN", 0.7, may_weaken=True) is Outcome.SET
    assert table.set("AVD_RADIUS", 0.4, may_weaken=True) is Outcome.SET
    assert table.set("AVD_NOPE", 1.0, may_weaken=True) is Outcome.UNKNOWN
    assert table.set("AVD_MARGIN", float("nan"), may_weaken=True) is Outcome.RANGE
    assert table.set("AVD_MARGIN", True, may_weaken=True) is Outcome.RANGE


def test_a_margin_below_its_own_floor_is_a_config_error() -> None:
    with pytest.raises(ValueError, match=r"margin_m 0\.2 is below min_margin_m 0\.5"):
        AvoidanceConfig(margin_m=0.2)
    assert AvoidanceConfig(margin_m=0.2, min_margin_m=0.2).margin_m == 0.2


def test_a_saved_file_never_switches_avoidance_on_nor_below_the_floors(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    path = tmp_path / "params.json"
    # What an earlier version let a stranger save.
    path.write_text(json.dumps({"AVD_ENABLE": 1.0, "AVD_MARGIN": 0.0, "AVD_RADIUS": 0.05}))
    table = ParamTable(AvoidanceConfig(params_file=path), path)
    assert not table.config.enabled
    assert table.config.margin_m == 1.0 and table.config.vehicle_radius_m == 0.5
    text = caplog.text
    assert "AVD_ENABLE=1.0" in text and "never switches avoidance on" in text
    assert "AVD_MARGIN=0.0" in text and "out of range" in text
    # A configuration that enables avoidance takes a saved "off", and other saved values.
    path.write_text(json.dumps({"AVD_ENABLE": 0.0, "AVD_MAX_SPEED": 5.0}))
    table = ParamTable(AvoidanceConfig(enabled=True, params_file=path), path)
    assert not table.config.enabled and table.config.max_speed_m_s == 5.0
    path.write_text(json.dumps({"AVD_ENABLE": 1.0}))
    assert ParamTable(AvoidanceConfig(enabled=True, params_file=path), path).config.enabled


# --- senders -----------------------------------------------------------------------------------


def _decoded(sender: mav.Codec, receiver: mav.Codec, message: mav.Message) -> mav.Message:
    (decoded,) = receiver.decode(sender.pack(message))
    return decoded


def _param_set(sender: mav.Codec) -> mav.Message:
    return sender.build("PARAM_SET", 7, 196, b"AVD_ENABLE", 1.0, 9)


def test_only_the_vehicle_and_configured_ground_stations_command_and_signed_ones_weaken() -> None:
    receiver = mav.Codec(7, 196)
    unsigned = Trust(ControlConfig(), signed_link=False)
    gcs, stranger, autopilot = mav.Codec(255, 190), mav.Codec(99, 1), mav.Codec(7, 1)
    assert unsigned.refusal(_decoded(stranger, receiver, _param_set(stranger)), 7) == "sender"
    assert unsigned.refusal(_decoded(gcs, receiver, _param_set(gcs)), 7) is None
    from_autopilot = _decoded(autopilot, receiver, _param_set(autopilot))
    assert unsigned.refusal(from_autopilot, 7) is None
    assert not unsigned.may_weaken(from_autopilot)
    assert Trust(ControlConfig(unsigned_may_weaken=True), False).may_weaken(from_autopilot)
    # Another ground station id only when configured.
    other = mav.Codec(200, 190)
    message = _decoded(other, receiver, _param_set(other))
    assert unsigned.refusal(message, 7) == "sender"
    assert Trust(ControlConfig(ground_stations=[200]), False).refusal(message, 7) is None

    # A signed link: a signed frame commands and may weaken; one let through unsigned does
    # not command at all.
    receiver.enable_signing(KEY, wall_timestamp(), lambda msg_id: msg_id == 23)  # PARAM_SET
    signed_trust = Trust(ControlConfig(), signed_link=True)
    gcs.enable_signing(KEY, wall_timestamp(), lambda _msg_id: False, link_id=3)
    signed = _decoded(gcs, receiver, _param_set(gcs))
    assert signed_trust.refusal(signed, 7) is None and signed_trust.may_weaken(signed)
    plain = mav.Codec(255, 190)
    let_through = _decoded(plain, receiver, _param_set(plain))
    assert signed_trust.refusal(let_through, 7) == "unsigned"
    assert not signed_trust.may_weaken(let_through)


# --- signatures --------------------------------------------------------------------------------


def _signed_pair(link_id: int = 0) -> tuple[mav.Codec, mav.Codec]:
    sender = mav.Codec(255, 190)
    sender.enable_signing(KEY, wall_timestamp(), lambda _msg_id: False, link_id=link_id)
    receiver = mav.Codec(7, 196)
    receiver.enable_signing(KEY, wall_timestamp(), lambda _msg_id: False)
    return sender, receiver


def _forge(frame: bytes, timestamp: int) -> bytes:
    """The frame with another timestamp and its old signature (no key needed)."""
    return frame[:-12] + timestamp.to_bytes(6, "little") + frame[-6:]


def test_a_forged_frame_cannot_make_a_senders_genuine_frames_old() -> None:
    # pymavlink's own check recorded a frame's timestamp before checking its signature: one
    # forged frame a year ahead made every genuine frame after it "old".
    sender, receiver = _signed_pair()
    heartbeat = sender.build("HEARTBEAT", mav.MAV_TYPE_GCS, 8, 0, 0, 4)
    genuine = sender.pack(heartbeat)
    forged = _forge(genuine, wall_timestamp() + 365 * 86400 * UNITS_PER_S)
    assert receiver.decode(forged) == []
    assert receiver.signature_check is not None and receiver.signature_check.mismatches == 1
    assert len(receiver.decode(genuine)) == 1
    assert len(receiver.decode(sender.pack(heartbeat))) == 1
    assert receiver.signature_rejects == 1


def test_a_captured_frame_is_a_replay_from_any_address() -> None:
    sender, receiver = _signed_pair()
    frame = sender.pack(sender.build("PARAM_SET", 7, 196, b"AVD_ENABLE", 1.0, 9))
    first, second = receiver.parser(), receiver.parser()  # two senders' addresses
    assert len(first.decode(frame)) == 1
    assert second.decode(frame) == [] and first.decode(frame) == []
    check = receiver.signature_check
    assert check is not None and check.replays == 2
    # A new sender more than a minute behind us is refused; within the minute it is taken.
    late = mav.Codec(255, 191)
    late.enable_signing(KEY, 0, lambda _msg_id: False)
    message = late.build("HEARTBEAT", mav.MAV_TYPE_GCS, 8, 0, 0, 4)
    ours = wall_timestamp() + 10 * NEW_STREAM_WINDOW  # (packing follows the wall clock)
    receiver.signing_state.timestamp = ours
    late.signing_state.timestamp = ours - NEW_STREAM_WINDOW - UNITS_PER_S
    assert receiver.decode(late.pack(message)) == [] and check.stale == 1
    late.signing_state.timestamp = ours - NEW_STREAM_WINDOW + UNITS_PER_S
    assert len(receiver.decode(late.pack(message))) == 1


# --- timestamps across restarts ----------------------------------------------------------------


def test_three_quick_restarts_never_run_a_minute_ahead_of_the_clock(tmp_path: Path) -> None:
    path = tmp_path / "signing-timestamp"
    starts = []
    for k in range(3):  # three restarts within five seconds of each other
        now_s = NOW_S + 5.0 * k
        starts.append(TimestampStore(path).start(now_s))
    assert starts == sorted(set(starts))  # never back
    for k, start in enumerate(starts):
        ahead_s = (start - wall_timestamp(NOW_S + 5.0 * k)) / UNITS_PER_S
        assert ahead_s <= RESTART_STEP_S, (k, ahead_s)
    # Ten restarts at once (a crash loop): each a few seconds on, far from a minute.
    for _ in range(10):
        last = TimestampStore(path).start(NOW_S + 10.0)
    assert (last - wall_timestamp(NOW_S + 10.0)) / UNITS_PER_S <= 10 * RESTART_STEP_S + 1


def test_the_timestamp_in_use_survives_a_restart_without_a_clock(tmp_path: Path) -> None:
    path = tmp_path / "signing-timestamp"
    store = TimestampStore(path)
    first = store.start(NOW_S)
    assert first == wall_timestamp(NOW_S)
    used = first + 7 * UNITS_PER_S  # seven seconds of signing later...
    store.keep(used, force=True)
    # ...it reboots without a real-time clock: the wall clock says 1970.
    restarted = TimestampStore(path).start(0.0)
    assert used < restarted <= used + RESTART_STEP_S * UNITS_PER_S
    assert wall_timestamp(0.0) == 0


def test_an_earlier_versions_file_is_read_as_its_timestamp_in_use(tmp_path: Path) -> None:
    path = tmp_path / "signing-timestamp"
    in_use = wall_timestamp(NOW_S)
    path.write_text(f"{in_use + 60 * UNITS_PER_S}\n")  # its mark was a minute ahead
    start = TimestampStore(path).start(0.0)
    assert start == in_use + int(RESTART_STEP_S * UNITS_PER_S)
    record = json.loads(path.read_text())
    assert record == {"timestamp": start, "streams": {}}
    path.write_text("not a number\n")
    assert TimestampStore(path).start(NOW_S) == wall_timestamp(NOW_S)


def test_senders_newest_timestamps_survive_a_restart(tmp_path: Path) -> None:
    path = tmp_path / "signing-timestamp"
    sender, _ = _signed_pair(link_id=2)
    frame = sender.pack(sender.build("PARAM_SET", 7, 196, b"AVD_MARGIN", 2.0, 9))

    def daemon() -> tuple[mav.Codec, TimestampStore]:
        receiver = mav.Codec(7, 196)
        store = TimestampStore(path)
        receiver.enable_signing(KEY, store.start(), lambda _m: False, 0, store.streams)
        return receiver, store

    receiver, store = daemon()
    assert len(receiver.decode(frame)) == 1
    store.keep(receiver.signing_timestamp, force=True)
    sent_at = int.from_bytes(frame[-12:-6], "little")
    assert json.loads(path.read_text())["streams"] == {"2:255:190": sent_at}
    receiver, _ = daemon()  # restarted
    assert receiver.decode(frame) == []
    assert receiver.signature_check is not None and receiver.signature_check.replays == 1
    # The sender's next frame is taken.
    assert len(receiver.decode(sender.pack(sender.build("HEARTBEAT", 6, 8, 0, 0, 4)))) == 1
