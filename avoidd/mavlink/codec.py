"""The one wrapper around pymavlink's generated MAVLink 2 codec (dialect ardupilotmega).

Building a message (``heartbeat``, ``obstacle_distance`` ...) has no side effect; only
:meth:`Codec.pack` advances the link's sequence number and signing timestamp, so exactly one task
per link (its sender) may call it.
"""

from __future__ import annotations

import logging
import os
from collections import Counter
from collections.abc import Callable, Iterable
from typing import Any

os.environ["MAVLINK20"] = "1"

from pymavlink.dialects.v20 import ardupilotmega as dialect

from avoidd.mavlink.signing import SIGNING_KEY_BYTES, SignatureCheck, Stream, wall_timestamp


class _PacketNotes(logging.Filter):
    """Drops and counts pymavlink's per-packet INFO lines ('sig mismatch', 'old timestamp').

    pymavlink logs one of these for every packet its signing check refuses or notes: a peer
    with a wrong key made 700 lines in 11 s. avoidd counts the refused messages itself
    (``signature_rejects``, in the periodic stats line); here only their kinds are counted.
    Warnings and errors pass.

    Attributes:
        counts: Lines dropped, by pymavlink's message template.
    """

    def __init__(self) -> None:
        super().__init__()
        self.counts: Counter[str] = Counter()

    def filter(self, record: logging.LogRecord) -> bool:
        if record.levelno > logging.INFO:
            return True
        self.counts[str(record.msg)] += 1
        return False


PYMAVLINK_NOTES = _PacketNotes()
"""The filter on pymavlink's dialect logger (also used by ``mavutil`` connections)."""
logging.getLogger(dialect.__name__).addFilter(PYMAVLINK_NOTES)

MAV_TYPE_ONBOARD_CONTROLLER = int(dialect.MAV_TYPE_ONBOARD_CONTROLLER)
MAV_TYPE_GCS = int(dialect.MAV_TYPE_GCS)
MAV_TYPE_QUADROTOR = int(dialect.MAV_TYPE_QUADROTOR)
MAV_AUTOPILOT_INVALID = int(dialect.MAV_AUTOPILOT_INVALID)
MAV_AUTOPILOT_ARDUPILOTMEGA = int(dialect.MAV_AUTOPILOT_ARDUPILOTMEGA)
MAV_AUTOPILOT_PX4 = int(dialect.MAV_AUTOPILOT_PX4)
MAV_MODE_FLAG_SAFETY_ARMED = int(dialect.MAV_MODE_FLAG_SAFETY_ARMED)
MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = int(dialect.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED)
MAV_STATE_ACTIVE = int(dialect.MAV_STATE_ACTIVE)
MAV_STATE_STANDBY = int(dialect.MAV_STATE_STANDBY)
MAV_STATE_CRITICAL = int(dialect.MAV_STATE_CRITICAL)
MAV_STATE_EMERGENCY = int(dialect.MAV_STATE_EMERGENCY)
MAV_STATE_FLIGHT_TERMINATION = int(dialect.MAV_STATE_FLIGHT_TERMINATION)
MAV_STATE_BOOT = int(dialect.MAV_STATE_BOOT)
MAV_FRAME_BODY_FRD = int(dialect.MAV_FRAME_BODY_FRD)
MAV_FRAME_LOCAL_NED = int(dialect.MAV_FRAME_LOCAL_NED)
MAV_DISTANCE_SENSOR_UNKNOWN = int(dialect.MAV_DISTANCE_SENSOR_UNKNOWN)
MAV_COMP_ID_AUTOPILOT1 = int(dialect.MAV_COMP_ID_AUTOPILOT1)
MAV_COMP_ID_OBSTACLE_AVOIDANCE = int(dialect.MAV_COMP_ID_OBSTACLE_AVOIDANCE)
MAV_CMD_SET_MESSAGE_INTERVAL = int(dialect.MAV_CMD_SET_MESSAGE_INTERVAL)
MAV_RESULT_ACCEPTED = int(dialect.MAV_RESULT_ACCEPTED)
MAV_RESULT_UNSUPPORTED = int(dialect.MAV_RESULT_UNSUPPORTED)
MAV_RESULT_DENIED = int(dialect.MAV_RESULT_DENIED)
MAV_RESULT_TEMPORARILY_REJECTED = int(dialect.MAV_RESULT_TEMPORARILY_REJECTED)
MAV_CMD_REQUEST_MESSAGE = int(dialect.MAV_CMD_REQUEST_MESSAGE)
MAV_CMD_DO_REPOSITION = int(dialect.MAV_CMD_DO_REPOSITION)
MAV_CMD_NAV_WAYPOINT = int(dialect.MAV_CMD_NAV_WAYPOINT)
MAV_FRAME_GLOBAL = int(dialect.MAV_FRAME_GLOBAL)
MAV_FRAME_GLOBAL_INT = int(dialect.MAV_FRAME_GLOBAL_INT)
MAV_FRAME_GLOBAL_RELATIVE_ALT = int(dialect.MAV_FRAME_GLOBAL_RELATIVE_ALT)
MAV_FRAME_GLOBAL_RELATIVE_ALT_INT = int(dialect.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT)
MAV_MISSION_ACCEPTED = int(dialect.MAV_MISSION_ACCEPTED)
MAV_MISSION_TYPE_MISSION = int(dialect.MAV_MISSION_TYPE_MISSION)
MAV_SENSOR_ROTATION_PITCH_270 = int(dialect.MAV_SENSOR_ROTATION_PITCH_270)
MAV_SEVERITY_CRITICAL = int(dialect.MAV_SEVERITY_CRITICAL)
MAV_SEVERITY_WARNING = int(dialect.MAV_SEVERITY_WARNING)
MAV_SEVERITY_NOTICE = int(dialect.MAV_SEVERITY_NOTICE)
MAV_SEVERITY_INFO = int(dialect.MAV_SEVERITY_INFO)
MAV_PARAM_TYPE_REAL32 = int(dialect.MAV_PARAM_TYPE_REAL32)

STATUSTEXT_MAX_CHARS = 50

Message = Any
"""A pymavlink message object (untyped; read fields by name)."""


def message_id(name: str) -> int:
    """The numeric id of a message by its name (``"ATTITUDE"`` -> 30).

    Raises:
        KeyError: No such message in the dialect.
    """
    msg_id = getattr(dialect, f"MAVLINK_MSG_ID_{name}", None)
    if msg_id is None:
        raise KeyError(name)
    return int(msg_id)


def result_name(result: int) -> str:
    """A MAV_RESULT value by name (``MAV_RESULT_ACCEPTED``), or the number if unknown."""
    entry = dialect.enums["MAV_RESULT"].get(result)
    return str(entry.name) if entry is not None else str(result)


def message_name(msg_id: int) -> str:
    """The name of a message id, or ``"MSG n"`` for one the dialect lacks."""
    cls = dialect.mavlink_map.get(msg_id)
    return str(cls.msgname) if cls is not None else f"MSG {msg_id}"


class Codec:
    """Builds, packs and decodes messages for one link.

    Args:
        system_id: System id of the messages it packs (the vehicle's).
        component_id: Component id of the messages it packs.
    """

    def __init__(self, system_id: int, component_id: int) -> None:
        self._mav = dialect.MAVLink(None, srcSystem=system_id, srcComponent=component_id)
        self._mav.robust_parsing = True
        self.parse_errors = 0
        self.signature_rejects = 0
        self.signature_check: SignatureCheck | None = None
        """The check of incoming signatures, once signing is enabled."""
        self.instance = 0
        """This run's instance number, sent in HEARTBEAT ``custom_mode`` (0: none)."""

    @property
    def system_id(self) -> int:
        """System id used when packing."""
        return int(self._mav.srcSystem)

    @system_id.setter
    def system_id(self, value: int) -> None:
        self._mav.srcSystem = value

    @property
    def component_id(self) -> int:
        """Component id used when packing."""
        return int(self._mav.srcComponent)

    # --- signing -----------------------------------------------------------------------------

    def enable_signing(
        self,
        key: bytes,
        timestamp_10us: int,
        allow_unsigned: Callable[[int], bool],
        link_id: int = 0,
        streams: dict[Stream, int] | None = None,
    ) -> None:
        """Sign every packed message and reject incoming ones without a valid signature.

        Args:
            key: The 32-byte secret key.
            timestamp_10us: Starting signing timestamp (10 us units since 2015-01-01 UTC).
            allow_unsigned: Given a message id, whether to accept it unsigned or badly signed.
            link_id: The link id carried in the signature.
            streams: The newest timestamp accepted per signed sender, shared with whoever
                keeps it across restarts (:class:`~avoidd.mavlink.signing.TimestampStore`);
                a new record when None.
        """
        if len(key) != SIGNING_KEY_BYTES:
            raise ValueError(f"a MAVLink signing key has {SIGNING_KEY_BYTES} bytes, not {len(key)}")
        signing = self._mav.signing
        signing.secret_key = key
        signing.timestamp = timestamp_10us
        signing.link_id = link_id
        signing.sign_outgoing = True
        signing.allow_unsigned_callback = lambda _mav, msg_id: allow_unsigned(msg_id)
        self.signature_check = SignatureCheck(key, signing, {} if streams is None else streams)
        self._mav.check_signature = self.signature_check

    @property
    def signing_state(self) -> Any:
        """The signing state of the link, pymavlink's (key, allow-list, timestamp)."""
        return self._mav.signing

    @property
    def signing_timestamp(self) -> int:
        """The current signing timestamp (10 us units since 2015-01-01), 0 when not signing."""
        return int(self._mav.signing.timestamp) if self._mav.signing.sign_outgoing else 0

    # --- building ----------------------------------------------------------------------------

    def heartbeat(self, system_status: int) -> Message:
        """A HEARTBEAT of an onboard controller (no autopilot).

        ``custom_mode``, free for a component that is no autopilot, carries :attr:`instance`
        (see :mod:`avoidd.mavlink.twins`).
        """
        return self._mav.heartbeat_encode(
            MAV_TYPE_ONBOARD_CONTROLLER, MAV_AUTOPILOT_INVALID, 0, self.instance, system_status
        )

    def obstacle_distance(
        self,
        time_usec: int,
        distances_cm: list[int],
        min_cm: int,
        max_cm: int,
        increment_deg: float = 5.0,
        angle_offset_deg: float = 0.0,
    ) -> Message:
        """An OBSTACLE_DISTANCE in BODY_FRD: 72 values, bin ``j`` at ``offset + j * increment``.

        ``increment`` (the integer field) is 0, so readers take ``increment_f``.
        """
        return self._mav.obstacle_distance_encode(
            time_usec,
            MAV_DISTANCE_SENSOR_UNKNOWN,
            distances_cm,
            0,
            min_cm,
            max_cm,
            increment_deg,
            angle_offset_deg,
            MAV_FRAME_BODY_FRD,
        )

    def statustext(self, severity: int, text: str) -> Message:
        """A STATUSTEXT, cut to the 50 characters one message carries."""
        payload = text.encode("ascii", "replace")[:STATUSTEXT_MAX_CHARS]
        return self._mav.statustext_encode(severity, payload)

    def set_message_interval(
        self, target_system: int, target_component: int, msg_id: int, interval_us: int
    ) -> Message:
        """A COMMAND_LONG MAV_CMD_SET_MESSAGE_INTERVAL (interval -1 stops the stream)."""
        return self._mav.command_long_encode(
            target_system,
            target_component,
            MAV_CMD_SET_MESSAGE_INTERVAL,
            0,
            float(msg_id),
            float(interval_us),
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
        )

    def distance_sensor(
        self,
        time_boot_ms: int,
        min_cm: int,
        max_cm: int,
        current_cm: int,
        orientation: int,
        horizontal_fov_rad: float = 0.0,
        vertical_fov_rad: float = 0.0,
        quaternion: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0),
        signal_quality: int = 0,
        sensor_id: int = 0,
    ) -> Message:
        """A DISTANCE_SENSOR (covariance unknown, sensor type unknown).

        ``signal_quality`` is 0 for unknown, else 1 (worst) to 100 (best).
        """
        return self._mav.distance_sensor_encode(
            time_boot_ms,
            min_cm,
            max_cm,
            current_cm,
            MAV_DISTANCE_SENSOR_UNKNOWN,
            sensor_id,
            orientation,
            255,  # covariance unknown
            horizontal_fov_rad,
            vertical_fov_rad,
            list(quaternion),
            signal_quality,
        )

    def obstacle_distance_3d(
        self,
        time_boot_ms: int,
        point_frd_m: Iterable[float],
        min_m: float,
        max_m: float,
        obstacle_id: int = 65535,
    ) -> Message:
        """An OBSTACLE_DISTANCE_3D: one obstacle point in BODY_FRD, metres (id unknown)."""
        x, y, z = (float(v) for v in point_frd_m)
        return self._mav.obstacle_distance_3d_encode(
            time_boot_ms,
            MAV_DISTANCE_SENSOR_UNKNOWN,
            MAV_FRAME_BODY_FRD,
            obstacle_id,
            x,
            y,
            z,
            min_m,
            max_m,
        )

    def build(self, name: str, *fields: Any) -> Message:
        """Build any message of the dialect by name and fields (used by the mock autopilot)."""
        encoder = getattr(self._mav, f"{name.lower()}_encode")
        return encoder(*fields)

    # --- packing and decoding ----------------------------------------------------------------

    def pack(self, message: Message) -> bytes:
        """Serialise a message, taking the next sequence number (and signing it when enabled)."""
        signing = self._mav.signing
        if signing.sign_outgoing:
            # The signing timestamp follows the wall clock when that is ahead, and otherwise
            # counts up by one per message, so it never goes back.
            signing.timestamp = max(signing.timestamp, wall_timestamp())
        data = bytes(message.pack(self._mav))
        # pymavlink's pack() stamps the current sequence number but only its send() advances
        # it; receivers count lost packets from gaps in it, so advance it here.
        self._mav.seq = (self._mav.seq + 1) % 256
        return data

    def decode(self, data: bytes | Iterable[int]) -> list[Message]:
        """Decode every complete message in ``data`` (partial ones are kept for the next call).

        Bytes that do not form a valid message are counted in ``parse_errors``, and messages
        refused by signing in ``signature_rejects``; neither ever raises.
        """
        messages, errors, rejects = _decode(self._mav, data)
        self.parse_errors += errors
        self.signature_rejects += rejects
        return messages

    def parser(self) -> Parser:
        """A decoder of its own for one more sender, checking signatures as this codec does."""
        return Parser(self)


class Parser:
    """Decodes the bytes of one sender.

    Its partial frame is its own, so garbage from one sender cannot swallow another's frames
    (as it does in a shared parser when it starts like a MAVLink 2 frame). Signatures are
    checked by the link's one :class:`~avoidd.mavlink.signing.SignatureCheck`, whose record of
    each signed sender's newest timestamp is shared by every parser: a frame captured from one
    address and sent again from another is still a replay.

    Args:
        codec: The link's codec: its key, allow-list and signature check are used as they are
            when each chunk is decoded.

    Attributes:
        parse_errors: Bad chunks or frames.
        signature_rejects: Messages refused for a missing or wrong signature.
    """

    def __init__(self, codec: Codec) -> None:
        self._codec = codec
        self._mav = dialect.MAVLink(None)
        self._mav.robust_parsing = True
        self.parse_errors = 0
        self.signature_rejects = 0

    def decode(self, data: bytes) -> list[Message]:
        """Decode every complete message in ``data``, as :meth:`Codec.decode` does."""
        shared, own = self._codec.signing_state, self._mav.signing
        own.secret_key = shared.secret_key
        own.allow_unsigned_callback = shared.allow_unsigned_callback
        check = self._codec.signature_check
        if check is not None:
            self._mav.check_signature = check
        messages, errors, rejects = _decode(self._mav, data)
        self.parse_errors += errors
        self.signature_rejects += rejects
        return messages


def _decode(parser: Any, data: bytes | Iterable[int]) -> tuple[list[Message], int, int]:
    """Messages decoded by a pymavlink parser, and the counts of bad data and rejected ones."""
    messages: list[Message] = []
    try:
        parsed = parser.parse_buffer(bytes(data))
    except Exception:
        # Garbage on a link must never take the link down: count it and go on.
        return messages, 1, 0
    errors = rejects = 0
    for message in parsed or ():
        if message.get_type() == "BAD_DATA":
            if "signature" in str(getattr(message, "reason", "")).lower():
                rejects += 1
            else:
                errors += 1
        else:
            messages.append(message)
    return messages, errors, rejects
