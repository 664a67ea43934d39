"""Another sender with avoidd's own identity on the link: two daemons as one system and component.

Two avoidd on one link (a router, or two ``udpout`` to one ground station that forwards) send
as the same system and component 196: the autopilot takes both streams for one sensor and a
ground station cannot tell them apart. avoidd's HEARTBEAT carries a random instance number in
``custom_mode`` (free for a component that is no autopilot), so a heartbeat of avoidd's system
and component with another number is another instance, and its own echoed back (a looped
serial line, a router sending back) is not.
"""

from __future__ import annotations

import logging
import secrets
from collections.abc import Callable

from avoidd.mavlink import codec as mav
from avoidd.mavlink.link import MavLink

logger = logging.getLogger(__name__)

Announce = Callable[[int, str, str | None], None]
"""Reports an operator-visible event (severity, text, key), as the daemon's announcer does."""

MAX_TWINS = 16
"""Other instances told apart; more are counted together."""


def instance_id() -> int:
    """A random non-zero 32-bit number for this run's HEARTBEAT ``custom_mode``."""
    return secrets.randbits(31) | 1


class TwinWatch:
    """Says so when another sender speaks as avoidd's system and component.

    Args:
        link: The link (its codec has the ids; its messages are watched).
        instance: This run's number, as its HEARTBEAT carries it.
        announce: Where the warning goes besides the log (STATUSTEXT).

    Attributes:
        twins: Heartbeats heard from each other instance, by its number.
    """

    def __init__(self, link: MavLink, instance: int, announce: Announce) -> None:
        self._codec = link.codec
        self._instance = instance
        self._announce = announce
        self.twins: dict[int, int] = {}
        link.subscribe(self.handle)

    def handle(self, message: mav.Message, received_ns: int) -> None:
        """Look at one decoded message of the link."""
        if message.get_type() != "HEARTBEAT":
            return
        codec = self._codec
        if (message.get_srcSystem(), message.get_srcComponent()) != (
            codec.system_id,
            codec.component_id,
        ):
            return
        other = int(message.custom_mode)
        if other == self._instance:
            return  # our own, echoed back
        if other not in self.twins and len(self.twins) >= MAX_TWINS:
            other = -1
        if other in self.twins:
            self.twins[other] += 1
            return
        self.twins[other] = 1
        logger.warning(
            "MAVLink: another sender speaks as system %d component %d, as avoidd does (two "
            "avoidd on one link?); the autopilot cannot tell them apart: give each its own "
            "mavlink.component_id (e.g. 197) or its own link",
            codec.system_id,
            codec.component_id,
        )
        self._announce(
            mav.MAV_SEVERITY_WARNING,
            f"avoidd: another {codec.system_id}/{codec.component_id} on the link",
            "twin",
        )
