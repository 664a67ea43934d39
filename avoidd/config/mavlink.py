"""The MAVLink section: connection, identity, outputs, requested streams and signing."""

from __future__ import annotations

import math
from typing import Annotated, Literal

from pydantic import AfterValidator, Field, field_validator, model_validator

from avoidd.config.base import ConfigPath, Strict
from avoidd.config.connection import LinkSpec, parse_address, parse_connection
from avoidd.errors import ConfigError


class ObstacleDistanceConfig(Strict):
    """OBSTACLE_DISTANCE output: rate and the sensor's range in centimetres.

    Attributes:
        rate_hz: Most messages per second. Each new scan is sent as soon as it is made (its
            capture time in ``time_usec``); without a new one the last message goes again
            after 0.2 s, or one period if that is longer (both autopilots drop the data
            0.5 s after the last one: keep it at 5 Hz or more).
        min_distance_cm: The nearest range the message claims to measure. Leave it out: it then
            follows from the heads (the nearest range the least capable one measures, see
            ``avoidd check-config``); a value below that is refused, since it would claim
            ranges the rig cannot measure.
        max_distance_cm: Readings at or beyond this are sent as clear. A rig that resolves
            less far lowers it (see ``heads[].disparity_error_px``, ``avoidd check-config``).
        fill_from_neighbours: For ArduPilot (and any autopilot but PX4), which reads an unknown
            bin as nothing: an unknown bin inside a head's view beside a reading is sent with
            the nearer neighbour's reading (``avoidd.mavlink.fill``). PX4 reads unknown as
            "no data" and always gets the scan unchanged.
    """

    rate_hz: float = Field(15.0, ge=1.0, le=50.0)
    min_distance_cm: int | None = Field(None, ge=1, le=65533)
    max_distance_cm: int = Field(2000, ge=2, le=65533)
    fill_from_neighbours: bool = True

    @model_validator(mode="after")
    def _range(self) -> ObstacleDistanceConfig:
        if self.min_distance_cm is not None and self.max_distance_cm <= self.min_distance_cm:
            raise ValueError("max_distance_cm must be greater than min_distance_cm")
        return self

    def range_cm(
        self, rig_min_range_m: float, rig_max_range_m: float = math.inf
    ) -> tuple[int, int]:
        """The ``(min, max)`` distances to send.

        Args:
            rig_min_range_m: The nearest range every head measures.
            rig_max_range_m: The farthest range every head resolves (the maximum is cut to
                it: a clear bin claims nothing nearer than the maximum).
        """
        derived = max(1, math.ceil(rig_min_range_m * 100.0 - 1e-6))
        minimum = self.min_distance_cm if self.min_distance_cm is not None else derived
        maximum = self.max_distance_cm
        if math.isfinite(rig_max_range_m):
            maximum = min(maximum, math.floor(rig_max_range_m * 100.0 + 1e-6))
        return minimum, max(maximum, minimum + 1)


def _off_or_rate(value: float) -> float:
    if 0.0 < value < 0.1:
        raise ValueError("a stream rate is 0 (not asked) or from 0.1 to 1000 Hz")
    return value


StreamRate = Annotated[float, Field(ge=0.0, le=1000.0), AfterValidator(_off_or_rate)]
"""0 (not asked), or 0.1 to 1000 Hz."""


class StreamsConfig(Strict):
    """Rates at which avoidd asks the autopilot for vehicle state (0 = do not ask).

    Each is requested with MAV_CMD_SET_MESSAGE_INTERVAL, repeated until acknowledged, and again
    whenever the link comes back (an autopilot forgets requested intervals when it reboots).

    Attributes:
        attitude_hz: ATTITUDE, for levelling each frame's points (50 Hz: the attitude at capture
            time is interpolated).
        local_position_hz: LOCAL_POSITION_NED, for the planner, obstacle memory and recordings.
        distance_sensor_hz: DISTANCE_SENSOR from the autopilot (a downward rangefinder gives the
            height).
        system_time_hz: SYSTEM_TIME, for mapping the autopilot's boot time onto avoidd's clock.
    """

    attitude_hz: StreamRate = 50.0
    local_position_hz: StreamRate = 10.0
    distance_sensor_hz: StreamRate = 10.0
    system_time_hz: StreamRate = 1.0


def _known_message(value: str) -> str:
    # Imported here, as before: loading the config alone need not load the generated dialect.
    # The same test as avoidd.mavlink.codec.message_id, which config (the bottom layer) must
    # not import.
    from pymavlink.dialects.v20 import ardupilotmega

    if getattr(ardupilotmega, f"MAVLINK_MSG_ID_{value}", None) is None:
        raise ValueError(f"'{value}' is not a MAVLink message name (e.g. RADIO_STATUS)")
    return value


class SigningConfig(Strict):
    """MAVLink 2 signing. Give the key as ``key_file`` or as a systemd credential name.

    Attributes:
        key_file: File holding the 32-byte key (raw, or 64 hex digits).
        key_credential: Name of a credential in ``$CREDENTIALS_DIRECTORY`` (systemd
            ``LoadCredential=NAME:/path``); preferred in production.
        allow_unsigned: Messages accepted without a valid signature.
        timestamp_file: Where the signing timestamp is kept across restarts (needed on boards
            without a real-time clock); its folder must exist.
        link_id: Link id carried in our signatures.
    """

    key_file: ConfigPath | None = None
    key_credential: str | None = Field(None, pattern=r"^[A-Za-z0-9_.-]+$")
    # pydantic copies a mutable default per instance; ruff cannot see that Strict is a model.
    allow_unsigned: list[Annotated[str, AfterValidator(_known_message)]] = ["RADIO_STATUS"]  # noqa: RUF012
    timestamp_file: ConfigPath | None = None
    link_id: int = Field(0, ge=0, le=255)

    @model_validator(mode="after")
    def _one_key(self) -> SigningConfig:
        if (self.key_file is None) == (self.key_credential is None):
            raise ValueError("give exactly one of key_file and key_credential")
        return self


class DistanceSensorConfig(Strict):
    """DISTANCE_SENSOR per head: its nearest obstacle, oriented by its mount.

    A head's mount must point along one of the orientations DISTANCE_SENSOR can name: yaw
    within 2.5 degrees of a multiple of 45, pitch within 30 degrees of level.

    Attributes:
        enabled: Send it (to autopilots other than ArduPilot and PX4 once heard from, or with
            the next key).
        rate_hz: Messages per second per head.
        alongside_obstacle_distance: Also send it to ArduPilot and PX4. Both take a horizontal
            DISTANCE_SENSOR into the same proximity map as OBSTACLE_DISTANCE: ArduPilot keeps
            whichever of the two wrote a 45-degree sector last, so they fight over it, and PX4
            spreads the one reading over the head's whole field of view. Off by default.
    """

    enabled: bool = False
    rate_hz: float = Field(10.0, ge=1.0, le=50.0)
    alongside_obstacle_distance: bool = False


class ObstacleDistance3dConfig(Strict):
    """OBSTACLE_DISTANCE_3D: the nearest ``max_points`` obstacle points (BODY_FRD, metres).

    Attributes:
        enabled: Send OBSTACLE_DISTANCE_3D.
        rate_hz: Messages per second (each message is one point; a cycle sends up to
            ``max_points``).
        max_points: The nearest points sent per cycle.
    """

    enabled: bool = False
    rate_hz: float = Field(10.0, ge=1.0, le=50.0)
    max_points: int = Field(16, ge=1, le=72)


class ControlConfig(Strict):
    """Who may command avoidd over MAVLink: goals, parameter sets, avoidance on and off.

    Goals and parameter sets are taken from the vehicle's own system (the autopilot, and what
    it forwards of its own components) and from the ground stations listed here; on a signed
    link only with a valid signature. Anyone may read the parameters. See docs/mavlink.md
    ("Who may command avoidd").

    Attributes:
        ground_stations: System ids of the ground stations allowed to command avoidd
            (255: QGroundControl, Mission Planner and MAVProxy by default).
        unsigned_may_weaken: Also take, from a message that is not signed, parameter sets
            that make avoidd less cautious: switching avoidance on, a smaller margin or
            radius, more speed, acceleration or yaw rate. Off (the default), such a message
            may only make avoidd more cautious: on an unsigned link anyone who can send to
            it can claim a ground station's id.
    """

    ground_stations: list[Annotated[int, Field(ge=1, le=255)]] = [255]  # noqa: RUF012
    unsigned_may_weaken: bool = False


class MavlinkConfig(Strict):
    """The MAVLink link and avoidd's identity on it.

    Attributes:
        connection: Where the autopilot is (see ``avoidd.config.connection``). Only ``run``
            needs it; replay and the other offline commands work without it (and without
            the whole ``mavlink`` section).
        system_id: The vehicle's system id, or "auto" to learn it from the first autopilot
            heartbeat (avoidd uses 1 until then). Messages of other systems are ignored.
        autopilot_component_id: Component id of the autopilot (1).
        heartbeat_hz: avoidd's own HEARTBEAT rate (0.5 to 10 Hz; autopilots and ground
            stations expect 1 Hz).
        link_timeout_s: The link is down when no autopilot heartbeat came for this long.
        component_id: avoidd's own component id (196 is MAV_COMP_ID_OBSTACLE_AVOIDANCE;
            goals addressed to avoidd use it).
        control: Who may command avoidd (goals, parameters).
        autopilot_address: On a ``udpin`` link, the only address (``HOST`` or
            ``HOST:PORT``) heard as the autopilot: every other sender is ignored from its
            first datagram on, and nothing is sent to it. Without it the first sender of a
            heartbeat avoidd adopts becomes the autopilot (see docs/mavlink.md, "Links").
        gcs_connection: A ground-station endpoint of avoidd's own, as a MAVLink router's
            (e.g. ``udpin:127.0.0.1:14551``): a ground station or ``avoidd goto`` there talks
            to the autopilot through avoidd and sends avoidd goals; it hears avoidd and the
            autopilot (``avoidd.mavlink.gcs``). None: no endpoint (use a router).
    """

    connection: str | None = None
    gcs_connection: str | None = None
    autopilot_address: str | None = None
    system_id: int | Literal["auto"] = "auto"
    component_id: int = Field(196, ge=1, le=255)
    autopilot_component_id: int = Field(1, ge=1, le=255)
    heartbeat_hz: float = Field(1.0, ge=0.5, le=10.0)
    link_timeout_s: float = Field(3.0, ge=0.5, le=60.0)
    obstacle_distance: ObstacleDistanceConfig = ObstacleDistanceConfig()
    distance_sensor: DistanceSensorConfig = DistanceSensorConfig()
    obstacle_distance_3d: ObstacleDistance3dConfig = ObstacleDistance3dConfig()
    streams: StreamsConfig = StreamsConfig()
    signing: SigningConfig | None = None
    control: ControlConfig = ControlConfig()

    @field_validator("system_id", mode="before")
    @classmethod
    def _system_id(cls, value: object) -> object:
        # One clear line instead of one per member of the union; "7" and true are refused.
        if value == "auto":
            return value
        if isinstance(value, int) and not isinstance(value, bool) and 1 <= value <= 255:
            return value
        raise ValueError("a system id is a number from 1 to 255 (no quotes), or auto")

    @field_validator("connection", "gcs_connection")
    @classmethod
    def _connection(cls, value: str | None) -> str | None:
        if value is not None:
            parse_connection(value)
        return value

    @field_validator("autopilot_address")
    @classmethod
    def _address(cls, value: str | None) -> str | None:
        if value is not None:
            parse_address(value)
        return value

    @model_validator(mode="after")
    def _gcs_apart(self) -> MavlinkConfig:
        if self.gcs_connection is not None and self.gcs_connection == self.connection:
            raise ValueError(
                "gcs_connection is the autopilot's own connection; give the ground stations "
                "another port (e.g. udpin:127.0.0.1:14551)"
            )
        return self

    @model_validator(mode="after")
    def _address_needs_udpin(self) -> MavlinkConfig:
        if self.autopilot_address is not None and self.connection is not None:
            kind = parse_connection(self.connection).kind
            if kind != "udpin":
                raise ValueError(
                    f"autopilot_address is for a udpin connection; {kind} has one peer "
                    "already (remove autopilot_address)"
                )
        return self

    @property
    def link(self) -> LinkSpec:
        """The parsed connection string.

        Raises:
            ConfigError: No connection is configured.
        """
        if self.connection is None:
            raise ConfigError(
                [
                    "mavlink.connection: not set; the daemon needs the autopilot's link, "
                    "e.g. connection: udpout:127.0.0.1:14550 (see docs/configuration.md)"
                ]
            )
        return parse_connection(self.connection)

    @property
    def fixed_system_id(self) -> int | None:
        """The configured system id, or None when it is learned."""
        return None if self.system_id == "auto" else int(self.system_id)
