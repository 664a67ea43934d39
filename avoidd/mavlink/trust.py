"""Who may command avoidd: which senders' goals and parameter sets are taken, and which may weaken.

The rule (docs/mavlink.md, "Who may command avoidd"): a goal, command or parameter set
addressed to avoidd is taken from the vehicle's own system and from the configured ground
stations (``mavlink.control.ground_stations``); on a signed link only when its signature is
valid (a message let through unsigned by ``signing.allow_unsigned`` commands nothing). A
message that is not signed may only make avoidd more cautious, unless
``mavlink.control.unsigned_may_weaken`` says otherwise: on an unsigned link a system id proves
nothing.
"""

from __future__ import annotations

from dataclasses import dataclass

from avoidd.config.mavlink import ControlConfig
from avoidd.mavlink.codec import Message


def is_signed(message: Message) -> bool:
    """Whether ``message`` carried a signature that checked (pymavlink's ``_signed``)."""
    return bool(getattr(message, "_signed", False))


@dataclass(frozen=True)
class Trust:
    """The trust rule of one link.

    Attributes:
        control: ``mavlink.control``.
        signed_link: The link signs and checks signatures.
    """

    control: ControlConfig
    signed_link: bool

    def refusal(self, message: Message, vehicle_system: int | None) -> str | None:
        """Why a command from ``message``'s sender is not taken (None: it is taken)."""
        source = message.get_srcSystem()
        if source != vehicle_system and source not in self.control.ground_stations:
            return "sender"
        if self.signed_link and not is_signed(message):
            return "unsigned"
        return None

    def may_weaken(self, message: Message) -> bool:
        """Whether ``message`` may make avoidd less cautious (signed, or configured so)."""
        return self.control.unsigned_may_weaken or is_signed(message)
