"""Downloading the autopilot's mission with the MAVLink mission protocol.

avoidd asks with MISSION_REQUEST_LIST, the autopilot answers MISSION_COUNT, avoidd asks for each
item with MISSION_REQUEST_INT and the autopilot answers MISSION_ITEM_INT; avoidd ends with
MISSION_ACK. Any step without an answer within :data:`TIMEOUT_NS` is asked again, up to
:data:`RETRIES` times; then the download is abandoned and tried again after
:data:`BACKOFF_NS`. Repeated or stray answers are ignored. The mission is downloaded again every
:data:`REFRESH_NS` and at once when MISSION_CURRENT's item count changes (someone uploaded a new
mission); :attr:`MissionClient.version` counts the missions that differed from the one before.

The client is sans-I/O: messages in (:meth:`MissionClient.handle`), messages out (the return of
:meth:`MissionClient.tick`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

from avoidd.mavlink import codec as mav
from avoidd.mavlink.codec import Message

logger = logging.getLogger(__name__)

TIMEOUT_NS = 1_000_000_000
RETRIES = 5
BACKOFF_NS = 10_000_000_000
REFRESH_NS = 15_000_000_000
MAX_ITEMS = 1000


@dataclass(frozen=True)
class MissionItem:
    """One mission item as MISSION_ITEM_INT carries it.

    Attributes:
        seq: Its index.
        frame: MAV_FRAME of x, y, z.
        command: MAV_CMD (16: NAV_WAYPOINT).
        x: Latitude in 1e-7 degrees (global frames), or metres.
        y: Longitude in 1e-7 degrees, or metres.
        z: Altitude in metres (meaning given by the frame).
    """

    seq: int
    frame: int
    command: int
    x: int
    y: int
    z: float


class MissionClient:
    """Keeps a copy of the autopilot's mission.

    Args:
        codec: Builds the outgoing messages (avoidd's own system and component).
    """

    def __init__(self, codec: mav.Codec) -> None:
        self._codec = codec
        self.items: tuple[MissionItem, ...] | None = None
        """The last complete download (None before the first)."""
        self.version = 0
        """Bumped whenever a download differs from the previous one."""
        self.failures = 0
        """Downloads abandoned after their retries."""
        self._target = (0, 0)
        self._busy = False
        self._count = 0
        self._received: dict[int, MissionItem] = {}
        self._asked_ns = 0
        self._tries = 0
        self._next_download_ns: int | None = None
        self._last_total: int | None = None

    @property
    def downloading(self) -> bool:
        """Whether a download is in progress."""
        return self._busy

    def handle(self, message: Message, now_ns: int) -> None:
        """Take a message from the autopilot (others are the caller's to filter out)."""
        kind = message.get_type()
        if kind == "MISSION_CURRENT":
            total = int(getattr(message, "total", 0) or 0)
            if self._last_total is not None and total != self._last_total and not self._busy:
                logger.info(
                    "mission: the autopilot's mission changed (%d items); reading it", total
                )
                self._next_download_ns = now_ns
            self._last_total = total
            return
        if getattr(message, "mission_type", 0) != mav.MAV_MISSION_TYPE_MISSION or not self._busy:
            return
        if not self._for_us(message):
            return
        if kind == "MISSION_COUNT" and self._count < 0:
            count = int(message.count)
            if count > MAX_ITEMS:
                logger.warning(
                    "mission: %d items is more than %d; not following it", count, MAX_ITEMS
                )
                self._abandon(now_ns)
                return
            self._count = count
            self._tries = 0
            self._asked_ns = -(10**18)  # ask for the first item on the next tick
        elif kind == "MISSION_ITEM_INT" and self._count >= 0:
            seq = int(message.seq)
            if seq != len(self._received) or seq >= self._count:
                return  # a repeat, or an answer to an older request
            self._received[seq] = MissionItem(
                seq,
                int(message.frame),
                int(message.command),
                int(message.x),
                int(message.y),
                float(message.z),
            )
            self._tries = 0
            self._asked_ns = -(10**18)
        elif kind == "MISSION_ACK" and int(message.type) != mav.MAV_MISSION_ACCEPTED:
            logger.warning(
                "mission: the autopilot ended the download (MAV_MISSION_RESULT %d)",
                int(message.type),
            )
            self._abandon(now_ns)

    def _for_us(self, message: Message) -> bool:
        return bool(
            message.target_system in (0, self._codec.system_id)
            and message.target_component in (0, self._codec.component_id)
        )

    def tick(self, now_ns: int, target_system: int, target_component: int) -> list[Message]:
        """What to send now to the autopilot at ``target_system``/``target_component``."""
        if not self._busy:
            due = self._next_download_ns
            if due is not None and now_ns < due:
                return []
            self._begin(target_system, target_component)
        if self._count >= 0 and len(self._received) == self._count:
            return [self._finish(now_ns)]
        if now_ns - self._asked_ns < TIMEOUT_NS:
            return []
        if self._tries >= RETRIES + 1:
            what = "MISSION_COUNT" if self._count < 0 else f"item {len(self._received)}"
            logger.warning("mission: no %s after %d tries; trying again later", what, self._tries)
            self._abandon(now_ns)
            return []
        self._tries += 1
        self._asked_ns = now_ns
        system, component = self._target
        kind = mav.MAV_MISSION_TYPE_MISSION
        if self._count < 0:
            return [self._codec.build("MISSION_REQUEST_LIST", system, component, kind)]
        seq = len(self._received)
        return [self._codec.build("MISSION_REQUEST_INT", system, component, seq, kind)]

    def _begin(self, target_system: int, target_component: int) -> None:
        self._busy = True
        self._target = (target_system, target_component)
        self._count = -1
        self._received = {}
        self._tries = 0
        self._asked_ns = -(10**18)

    def _finish(self, now_ns: int) -> Message:
        items = tuple(self._received[i] for i in range(self._count))
        if items != self.items:
            self.version += 1
            logger.info("mission: %d items read from the autopilot", len(items))
        self.items = items
        self._busy = False
        self._next_download_ns = now_ns + REFRESH_NS
        system, component = self._target
        return self._codec.build(
            "MISSION_ACK",
            system,
            component,
            mav.MAV_MISSION_ACCEPTED,
            mav.MAV_MISSION_TYPE_MISSION,
        )

    def _abandon(self, now_ns: int) -> None:
        self._busy = False
        self.failures += 1
        self._next_download_ns = now_ns + BACKOFF_NS

    def reset(self) -> None:
        """Forget the mission (the autopilot rebooted or was replaced): read it again now."""
        self._busy = False
        self.items = None
        self._last_total = None
        self._next_download_ns = None
