"""What avoidd knows of its vehicle: identity, mode, link state, attitude, position, clocks.

:class:`Vehicle` is fed every decoded message of the link. It adopts the first autopilot it hears
(or the configured system id), ignores every other system, and keeps asking the autopilot for the
streams it needs until each request is acknowledged.
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

from avoidd.config import MavlinkConfig
from avoidd.mavlink import codec as mav
from avoidd.mavlink.attitude import Attitude, AttitudeHistory
from avoidd.mavlink.clock import ClockSync
from avoidd.mavlink.geo import GlobalPoint, valid_lat_lon
from avoidd.mavlink.link import MavLink
from avoidd.mavlink.modes import FlightMode, decode_mode
from avoidd.mavlink.track_history import TrackHistory
from avoidd.mavlink.trust import Trust, is_signed
from avoidd.types import LocalPosition, Rangefinder

logger = logging.getLogger(__name__)

DEFAULT_SYSTEM_ID = 1
_REQUEST_RETRY_S = 1.0
_SILENT_MIN_NS = 1_000_000_000
"""An accepted stream silent for this long (or three intervals) is asked for again: an
autopilot that rebooted within the link timeout has forgotten every request."""
_LATE_TICK_NS = 500_000_000
"""A tick this long after the previous one (they come every 0.1 s) judges no silence."""
_QUIET_BACKOFF_MAX = 6
"""An accepted stream that never delivered is asked again after its silent time, then twice
as long each time, up to 2**6 times it (64 s for most streams)."""
_NOT_AUTOPILOTS = {mav.MAV_TYPE_GCS, mav.MAV_TYPE_ONBOARD_CONTROLLER}
_ORIGIN_RETRY_NS = 2_000_000_000
_HOME_AFTER_ARMING_NS = 1_000_000_000
"""Home is asked again this long after arming (both autopilots set it when they arm)."""
_GPS_GLOBAL_ORIGIN = 49
_HOME_POSITION = 242
_ORIGIN_ASKS_BEFORE_WARNING = 5
"""Unanswered requests for the origin or home (10 s) before avoidd says it is still waiting."""


class Announce(Protocol):
    """Reports an operator-visible event; ``key`` names its subject for coalescing."""

    def __call__(self, severity: int, text: str, key: str | None = None) -> None:
        """Report one event."""


@dataclass
class StreamRequest:
    """One message stream avoidd asks for.

    Attributes:
        name: Message name.
        msg_id: Message id.
        interval_us: Interval asked for.
        acked: The autopilot accepted the request (since the link came up or the last
            re-request).
        refused: The autopilot refused it.
        attempts: Requests sent since the last answer.
        acked_ns: When it was accepted (local monotonic).
        last_ns: When the last message of the stream arrived.
        quiet_asks: Times it was asked again because it was accepted but never delivered
            (the back-off step; reset when it delivers).
    """

    name: str
    msg_id: int
    interval_us: int
    acked: bool = False
    refused: bool = False
    attempts: int = 0
    acked_ns: int = 0
    last_ns: int = 0
    quiet_asks: int = 0

    def silent_ns(self) -> int:
        """How long it may stay silent once accepted before it is asked for again."""
        return max(_SILENT_MIN_NS, 3 * self.interval_us * 1000)


ADDRESSED_TO_US = frozenset(
    {
        "SET_POSITION_TARGET_LOCAL_NED",
        "SET_POSITION_TARGET_GLOBAL_INT",
        "COMMAND_LONG",
        "COMMAND_INT",
        "PARAM_REQUEST_LIST",
        "PARAM_REQUEST_READ",
        "PARAM_SET",
    }
)
"""Message types avoidd takes when addressed to its own component (goals, commands)."""


class Vehicle:
    """Tracks the autopilot on one link.

    Args:
        link: The link (messages are subscribed here; requests are sent on it).
        config: The MAVLink configuration.
        announce: Called with (severity, text) for operator-visible events.
    """

    def __init__(self, link: MavLink, config: MavlinkConfig, announce: Announce) -> None:
        self._link = link
        self._config = config
        self._announce = announce
        self.system_id: int | None = config.fixed_system_id
        self.component_id = config.autopilot_component_id
        self.mode: FlightMode | None = None
        self.last_heartbeat_ns: int | None = None
        self.link_up = False
        self.clock = ClockSync()
        self.attitude = AttitudeHistory()
        self.position: LocalPosition | None = None
        self.positions = TrackHistory()
        """The newest local positions and velocities, times on the autopilot's boot clock,
        for the planner's track velocity."""
        self.position_received_ns = 0
        """When the newest LOCAL_POSITION_NED arrived (local monotonic clock)."""
        self.rangefinder: Rangefinder | None = None
        self.origin: GlobalPoint | None = None
        """The local frame's origin (GPS_GLOBAL_ORIGIN), for global goals."""
        self.home_up_m: float | None = None
        """Home's height above the origin (HOME_POSITION z), for relative altitudes."""
        self.wants_origin = False
        """Ask for GPS_GLOBAL_ORIGIN and HOME_POSITION until both are known (global goals
        and missions need them)."""
        self._origin_asked_ns = -(10**18)
        self._origin_asks: dict[int, int] = {}  # unanswered requests in a row, by message id
        self._home_due_ns: int | None = None
        """Home is to be asked again from then on (set on arming, cleared by a new home)."""
        self.ignored: Counter[int] = Counter()
        self._said_ignored: set[int] = set()
        self.reboots = 0
        """Autopilot reboots seen (boot clock going back, or every stream silent)."""
        self.silent_streams = 0
        """Streams asked for again after going silent."""
        self.quiet_streams = 0
        """Requests sent again for accepted streams that never delivered."""
        self.late_ticks = 0
        """Ticks that came too late to judge silence (avoidd was not running)."""
        self._last_tick_ns: int | None = None
        self._late_before = False
        self.invalid: Counter[str] = Counter()
        """Messages dropped because a value was not a finite number, by type."""
        self.requests = [
            StreamRequest(name, mav.message_id(name), round(1e6 / hz))
            for name, hz in (
                ("ATTITUDE", config.streams.attitude_hz),
                ("LOCAL_POSITION_NED", config.streams.local_position_hz),
                ("DISTANCE_SENSOR", config.streams.distance_sensor_hz),
                ("SYSTEM_TIME", config.streams.system_time_hz),
            )
            if hz > 0
        ]
        self._pending: StreamRequest | None = None
        self._pending_sent_s = 0.0
        self.on_command: Callable[[mav.Message], None] | None = None
        """Receives the messages in ``ADDRESSED_TO_US`` sent to avoidd's own component."""
        self.on_autopilot: Callable[[mav.Message, int], None] | None = None
        """Also receives every message from the autopilot (mission protocol answers)."""
        self.ground_stations: set[int] = set()
        """Systems whose HEARTBEAT says MAV_TYPE_GCS (heard, not thereby trusted)."""
        self.refused_commands: Counter[str] = Counter()
        """Commands addressed to avoidd and not taken, by why: ``sender`` (not the vehicle's
        system nor a configured ground station), ``unsigned`` (no valid signature on a
        signed link)."""
        link.codec.system_id = self.system_id or DEFAULT_SYSTEM_ID
        link.subscribe(self.handle)

    # --- incoming ----------------------------------------------------------------------------

    def handle(self, message: mav.Message, received_ns: int) -> None:
        """Take one decoded message of the link."""
        source = message.get_srcSystem()
        kind = message.get_type()
        if self.system_id is None:
            if not self._is_autopilot_heartbeat(message):
                return
            self.system_id = source
            self._link.codec.system_id = source
            logger.info("MAVLink: adopted vehicle system %d", source)
        if kind == "HEARTBEAT" and message.type == mav.MAV_TYPE_GCS:
            self.ground_stations.add(source)
        if kind in ADDRESSED_TO_US and self._addressed_to_us(message):
            # Goals, commands and parameters for avoidd itself: see avoidd.mavlink.trust.
            self._command_for_us(message)
            return
        if source != self.system_id and not (
            kind == "HEARTBEAT" and self._other_autopilot(message, source)
        ):
            self.ignored[source] += 1
            return
        if message.get_srcComponent() != self.component_id:
            return
        for request in self.requests:
            if request.name == kind:
                request.last_ns = received_ns
                request.quiet_asks = 0
        handler = getattr(self, f"_on_{kind.lower()}", None)
        if handler is not None:
            handler(message, received_ns)
        if self.on_autopilot is not None:
            self.on_autopilot(message, received_ns)

    def handle_ground_station(self, message: mav.Message, received_ns: int) -> None:
        """Take one message that came in on the ground-station endpoint (:mod:`.gcs`).

        Only what is addressed to avoidd (goals, commands, parameters) is taken, under the
        same trust rule as on the autopilot's link, and a ground station's HEARTBEAT is noted.
        Nothing from there is ever the autopilot: its heartbeats, attitude, positions and
        mission answers come from the autopilot's link only (a sender there could otherwise
        be adopted as the autopilot or feed a false attitude).
        """
        del received_ns  # the same signature as the link's handlers
        kind = message.get_type()
        if kind == "HEARTBEAT" and message.type == mav.MAV_TYPE_GCS:
            self.ground_stations.add(message.get_srcSystem())
            return
        if self.system_id is None or kind not in ADDRESSED_TO_US:
            return
        if self._addressed_to_us(message):
            self._command_for_us(message)

    def _command_for_us(self, message: mav.Message) -> None:
        """A goal, command or parameter for avoidd: taken or refused (:mod:`.trust`)."""
        refusal = self.trust.refusal(message, self.system_id)
        if refusal is not None:
            self.ignored[message.get_srcSystem()] += 1
            self.refused_commands[refusal] += 1
        elif self.on_command is not None:
            self.on_command(message)

    @property
    def trust(self) -> Trust:
        """Who may command avoidd on this link (:mod:`avoidd.mavlink.trust`)."""
        return Trust(self._config.control, self._link.codec.signature_check is not None)

    def _other_autopilot(self, message: mav.Message, source: int) -> bool:
        """An autopilot of another system: follow it if ours went silent and the id is learned.

        An autopilot whose system id was changed (SYSID_THISMAV, MAV_SYS_ID) comes back from
        its reboot as another system. While the link is up, another autopilot is another
        vehicle and is ignored. A configured id is never changed: the mismatch is said once
        per system.

        Returns:
            True when avoidd now follows ``source``.
        """
        if self.link_up or not self._is_autopilot_heartbeat(message):
            return False
        previous = self.system_id
        if self._config.fixed_system_id is not None:
            if source not in self._said_ignored and len(self._said_ignored) < 16:
                self._said_ignored.add(source)
                logger.warning(
                    "MAVLink: an autopilot speaks as system %d, but mavlink.system_id is %s; "
                    "ignored (set mavlink.system_id to %d or 'auto')",
                    source,
                    previous,
                    source,
                )
                self._announce(
                    mav.MAV_SEVERITY_WARNING,
                    f"avoidd: ignoring autopilot {source}, configured {previous}",
                    "system",
                )
            return False
        self.system_id = source
        self._link.codec.system_id = source
        self._forget()
        self.mode = None
        self.clock = ClockSync()
        logger.warning(
            "MAVLink: the autopilot is now system %d (was %s); following it", source, previous
        )
        self._announce(mav.MAV_SEVERITY_WARNING, f"avoidd: autopilot now system {source}", "system")
        return True

    def _addressed_to_us(self, message: mav.Message) -> bool:
        codec = self._link.codec
        # Parameter reads go to every component (QGroundControl asks MAV_COMP_ID_ALL);
        # goals, sets and commands only to ours.
        reads = message.get_type() in ("PARAM_REQUEST_LIST", "PARAM_REQUEST_READ")
        components = (0, codec.component_id) if reads else (codec.component_id,)
        return bool(
            message.target_component in components and message.target_system in (0, codec.system_id)
        )

    def fresh_position(self, now_ns: int, max_age_ns: int = 500_000_000) -> LocalPosition | None:
        """The local position if it is recent (an EKF or GPS loss stops the stream)."""
        position = self.position
        if position is None or now_ns - position.t_ns > max_age_ns:
            return None
        return position

    def _is_autopilot_heartbeat(self, message: mav.Message) -> bool:
        """A heartbeat that may stand for the autopilot: adopt it, keep the link up.

        An autopilot's component and type; on a signed link also a valid signature (a
        heartbeat let through unsigned by ``signing.allow_unsigned`` is anyone's).
        """
        return bool(
            message.get_type() == "HEARTBEAT"
            and message.get_srcComponent() == self.component_id
            and message.autopilot != mav.MAV_AUTOPILOT_INVALID
            and message.type not in _NOT_AUTOPILOTS
            and (self._link.codec.signature_check is None or is_signed(message))
        )

    def _on_heartbeat(self, message: mav.Message, received_ns: int) -> None:
        if not self._is_autopilot_heartbeat(message):
            return
        self._link.autopilot_spoke()  # the link is the autopilot's: replies go where it speaks
        mode = decode_mode(
            message.autopilot,
            message.type,
            message.base_mode,
            message.custom_mode,
            message.system_status,
        )
        if mode != self.mode:
            previous = self.mode
            if previous is None or previous.name != mode.name:
                logger.info("vehicle %d: %s mode %s", self.system_id, mode.autopilot, mode.name)
            if (previous is not None and previous.failsafe) != mode.failsafe:
                logger.warning(
                    "vehicle %d: %s",
                    self.system_id,
                    "failsafe in effect (HEARTBEAT system_status CRITICAL or worse)"
                    if mode.failsafe
                    else "failsafe over",
                )
            if previous is not None and previous.armed != mode.armed:
                logger.info("vehicle %d: %s", self.system_id, "armed" if mode.armed else "disarmed")
                if mode.armed and self.home_up_m is not None:
                    # Arming moves home to where the vehicle stands (PX4 and ArduPilot): the
                    # home known from before may be another place or height.
                    self._home_due_ns = received_ns + _HOME_AFTER_ARMING_NS
            self.mode = mode
        self.last_heartbeat_ns = received_ns
        if not self.link_up:
            self.link_up = True
            for request in self.requests:
                request.acked = request.refused = False
                request.attempts = 0
            self._pending = None
            logger.info(
                "MAVLink link up: %s system %d, mode %s, %s",
                mode.autopilot,
                self.system_id,
                mode.name,
                "armed" if mode.armed else "disarmed",
            )
            self._announce(
                mav.MAV_SEVERITY_INFO, f"avoidd: link up, {mode.autopilot} {mode.name}", "link"
            )

    def _on_attitude(self, message: mav.Message, received_ns: int) -> None:
        if not all(math.isfinite(v) for v in (message.roll, message.pitch, message.yaw)):
            self.invalid["ATTITUDE"] += 1  # an attitude that is not a number is no attitude
            return
        self._observe_boot_ms(message.time_boot_ms, received_ns)
        t_ns = self.clock.to_local_ns(message.time_boot_ms)
        assert t_ns is not None
        self.attitude.add(Attitude(t_ns, message.roll, message.pitch, message.yaw))

    def _on_local_position_ned(self, message: mav.Message, received_ns: int) -> None:
        m = message
        if not all(math.isfinite(v) for v in (m.x, m.y, m.z, m.vx, m.vy, m.vz)):
            self.invalid["LOCAL_POSITION_NED"] += 1
            return
        self._observe_boot_ms(message.time_boot_ms, received_ns)
        t_ns = self.clock.to_local_ns(message.time_boot_ms)
        assert t_ns is not None
        m = message
        self.position = LocalPosition(t_ns, m.x, m.y, m.z, m.vx, m.vy, m.vz)
        # The track is fitted on the autopilot's own clock (positions and velocities were
        # measured on it; the mapping to avoidd's clock moves with delivery jitter).
        self.positions.add(int(message.time_boot_ms) * 1_000_000, m.x, m.y, m.vx, m.vy)
        self.position_received_ns = received_ns

    def _on_distance_sensor(self, message: mav.Message, received_ns: int) -> None:
        if message.orientation != mav.MAV_SENSOR_ROTATION_PITCH_270:
            return
        self._observe_boot_ms(message.time_boot_ms, received_ns)
        t_ns = self.clock.to_local_ns(message.time_boot_ms)
        assert t_ns is not None
        if message.min_distance <= message.current_distance <= message.max_distance:
            self.rangefinder = Rangefinder(t_ns, message.current_distance / 100.0)

    def _on_system_time(self, message: mav.Message, received_ns: int) -> None:
        self._observe_boot_ms(message.time_boot_ms, received_ns)

    def _on_gps_global_origin(self, message: mav.Message, received_ns: int) -> None:
        lat_deg, lon_deg = message.latitude / 1e7, message.longitude / 1e7
        if not valid_lat_lon(lat_deg, lon_deg):
            return
        origin = GlobalPoint(lat_deg, lon_deg, message.altitude / 1000.0)
        if origin != self.origin:
            logger.info(
                "vehicle %s: origin %.7f, %.7f, %.1f m AMSL",
                self.system_id,
                origin.lat_deg,
                origin.lon_deg,
                origin.alt_m,
            )
        self.origin = origin

    def _on_home_position(self, message: mav.Message, received_ns: int) -> None:
        if math.isfinite(message.z):
            self.home_up_m = -float(message.z)
            if self._home_due_ns is not None and received_ns >= self._home_due_ns:
                self._home_due_ns = None

    def _on_command_ack(self, message: mav.Message, received_ns: int) -> None:
        request = self._pending
        if request is None or message.command != mav.MAV_CMD_SET_MESSAGE_INTERVAL:
            return
        if message.target_system not in (0, self._link.codec.system_id):
            return
        self._pending = None
        if message.result == mav.MAV_RESULT_ACCEPTED:
            request.acked = True
            request.acked_ns = received_ns
            logger.info(
                "vehicle %d: streams %s every %d us",
                self.system_id,
                request.name,
                request.interval_us,
            )
        else:
            request.refused = True
            logger.warning(
                "vehicle %d: refused to stream %s (MAV_RESULT %d)",
                self.system_id,
                request.name,
                message.result,
            )

    # --- queries -----------------------------------------------------------------------------

    def attitude_at(self, t_ns: int) -> Attitude | None:
        """Vehicle attitude at a local monotonic time (None when not known well enough)."""
        return self.attitude.at(t_ns)

    def time_boot_ms(self, local_ns: int) -> int:
        """``time_boot_ms`` for a message about an event at ``local_ns``.

        On the autopilot's boot clock once it is known (so the autopilot can relate the reading
        to its own data), else on avoidd's monotonic clock; wrapped to 32 bits.
        """
        boot_ns = self.clock.to_autopilot_boot_ns(local_ns)
        return ((boot_ns if boot_ns is not None else local_ns) // 1_000_000) % (1 << 32)

    @property
    def streams_acknowledged(self) -> bool:
        """Whether every requested stream was acknowledged (or refused) since the link came up."""
        return all(r.acked or r.refused for r in self.requests)

    # --- periodic ----------------------------------------------------------------------------

    def tick(self, now_ns: int) -> None:
        """Update link state and (re)send stream requests; call a few times per second.

        A tick that comes late after one on time (the machine was too busy to run avoidd for
        a while) judges no silence: what the autopilot sent meanwhile may still wait in the
        socket, unread, and would look like a link down or streams stopped. The next tick
        judges, late or not (the socket was read in between).
        """
        last_ns, self._last_tick_ns = self._last_tick_ns, now_ns
        late = last_ns is not None and now_ns - last_ns > _LATE_TICK_NS
        judge = not late or self._late_before
        self._late_before = late
        if late:
            self.late_ticks += 1
        timeout_ns = int(self._config.link_timeout_s * 1e9)
        if (
            judge
            and self.link_up
            and (self.last_heartbeat_ns is None or now_ns - self.last_heartbeat_ns > timeout_ns)
        ):
            self.link_up = False
            logger.error(
                "MAVLink link down: no heartbeat from system %s for %.1f s",
                self.system_id,
                self._config.link_timeout_s,
            )
            self._announce(mav.MAV_SEVERITY_WARNING, "avoidd: link down", "link")
        if self.link_up:
            if judge and self._link.connected:  # a lost port or connection: said by the link
                self._check_silent_streams(now_ns)
            self._request_streams(now_ns / 1e9)
            self._request_origin(now_ns)

    def _observe_boot_ms(self, time_boot_ms: int, received_ns: int) -> None:
        if self.clock.observe_boot_ms(time_boot_ms, received_ns):
            self._restart("its boot clock went back")

    def _restart(self, why: str) -> None:
        """The autopilot rebooted: forget its state and ask for every stream again."""
        self.reboots += 1
        self._forget()
        logger.warning(
            "vehicle %s rebooted (%s); asking for its streams again", self.system_id, why
        )
        self._announce(mav.MAV_SEVERITY_WARNING, "avoidd: autopilot rebooted", "autopilot")

    def _forget(self) -> None:
        """Forget what the autopilot said and what it was asked for."""
        self.attitude.clear()
        self.position = None
        self.positions.clear()
        self.rangefinder = None
        self.origin = None
        self.home_up_m = None
        self._home_due_ns = None
        for request in self.requests:
            request.acked = request.refused = False
            request.attempts = request.quiet_asks = 0
        self._pending = None

    def _check_silent_streams(self, now_ns: int) -> None:
        """Ask again for accepted streams that went silent (an autopilot that rebooted)."""
        # Only streams that delivered since they were accepted: an autopilot may accept a
        # stream it has nothing for (DISTANCE_SENSOR without a rangefinder).
        delivering = [r for r in self.requests if r.acked and r.last_ns >= r.acked_ns]
        silent = [r for r in delivering if now_ns - r.last_ns > r.silent_ns()]
        if silent and len(silent) == len(delivering):
            self._restart(f"{', '.join(r.name for r in silent)} stopped")
            return
        for request in silent:
            request.acked = False
            request.attempts = 0
            self.silent_streams += 1
            logger.warning(
                "vehicle %s: %s went silent for %.1f s; asking again",
                self.system_id,
                request.name,
                (now_ns - max(request.last_ns, request.acked_ns)) / 1e9,
            )
        self._ask_again_for_quiet_streams(now_ns)

    def _ask_again_for_quiet_streams(self, now_ns: int) -> None:
        """Ask again, with back-off, for accepted streams that never delivered.

        An autopilot that reboots between acknowledging a request and sending the first
        message has forgotten it; one that accepts a stream it has nothing for (DISTANCE_SENSOR
        without a rangefinder) is asked again rarely and harmlessly.
        """
        for request in self.requests:
            if not request.acked or request.last_ns >= request.acked_ns:
                continue
            wait_ns = request.silent_ns() << min(request.quiet_asks, _QUIET_BACKOFF_MAX)
            if now_ns - request.acked_ns <= wait_ns:
                continue
            request.acked = False
            request.attempts = 0
            request.quiet_asks += 1
            self.quiet_streams += 1
            logger.log(
                logging.INFO if request.quiet_asks == 1 else logging.DEBUG,
                "vehicle %s: %s accepted %.1f s ago but never sent; asking again "
                "(then less and less often)",
                self.system_id,
                request.name,
                (now_ns - request.acked_ns) / 1e9,
            )

    def _request_streams(self, now_s: float) -> None:
        if self._pending is not None and now_s - self._pending_sent_s < _REQUEST_RETRY_S:
            return
        # Round robin over the unanswered requests, one outstanding at a time: COMMAND_ACK does
        # not say which message interval it answers.
        waiting = [r for r in self.requests if not (r.acked or r.refused)]
        if not waiting or self.system_id is None:
            self._pending = None
            return
        after = self.requests.index(self._pending) if self._pending is not None else -1
        request = next((r for r in waiting if self.requests.index(r) > after), waiting[0])
        request.attempts += 1
        if request.attempts > 1 and request.attempts % 5 == 1:
            logger.warning(
                "vehicle %d: no answer to the %s stream request after %d tries",
                self.system_id,
                request.name,
                request.attempts - 1,
            )
        self._pending = request
        self._pending_sent_s = now_s
        self._link.send(
            self._link.codec.set_message_interval(
                self.system_id, self.component_id, request.msg_id, request.interval_us
            )
        )

    def _request_origin(self, now_ns: int) -> None:
        """Ask for the origin and home (MAV_CMD_REQUEST_MESSAGE) every 2 s until both are known.

        Home is asked again from a second after each arming until a new one arrives.
        """
        home_due = self._home_due_ns is not None and now_ns >= self._home_due_ns
        wanted = [
            msg_id
            for msg_id, known in (
                (_GPS_GLOBAL_ORIGIN, self.origin is not None),
                (_HOME_POSITION, self.home_up_m is not None and not home_due),
            )
            if not known
        ]
        for msg_id in [m for m in self._origin_asks if m not in wanted]:
            del self._origin_asks[msg_id]  # answered
        if not self.wants_origin or not wanted or self.system_id is None:
            return
        if now_ns - self._origin_asked_ns < _ORIGIN_RETRY_NS:
            return
        self._origin_asked_ns = now_ns
        for msg_id in wanted:
            asks = self._origin_asks[msg_id] = self._origin_asks.get(msg_id, 0) + 1
            if asks == _ORIGIN_ASKS_BEFORE_WARNING:
                name = "GPS_GLOBAL_ORIGIN" if msg_id == _GPS_GLOBAL_ORIGIN else "HOME_POSITION"
                logger.warning(
                    "vehicle %s: no %s after %d requests; goals given as latitude and longitude "
                    "or above home wait for it (has the autopilot a position and an origin?)",
                    self.system_id,
                    name,
                    asks,
                )
            self._link.send(
                self._link.codec.build(
                    "COMMAND_LONG",
                    self.system_id,
                    self.component_id,
                    mav.MAV_CMD_REQUEST_MESSAGE,
                    0,
                    float(msg_id),
                    0.0,
                    0.0,
                    0.0,
                    0.0,
                    0.0,
                    0.0,
                )
            )

    async def run(self, period_s: float = 0.1) -> None:
        """Call :meth:`tick` forever."""
        while True:
            self.tick(time.monotonic_ns())
            await asyncio.sleep(period_s)
