"""The one wrapper around pymavlink's generated MAVLink 2 codec (dialect ardupilotmega)."""

from __future__ import annotations

import os
from typing import Any

os.environ["MAVLINK20"] = "1"

from pymavlink.dialects.v20 import ardupilotmega as dialect

MAV_TYPE_ONBOARD_CONTROLLER = int(dialect.MAV_TYPE_ONBOARD_CONTROLLER)
MAV_AUTOPILOT_INVALID = int(dialect.MAV_AUTOPILOT_INVALID)
MAV_STATE_ACTIVE = int(dialect.MAV_STATE_ACTIVE)
MAV_STATE_CRITICAL = int(dialect.MAV_STATE_CRITICAL)
MAV_STATE_BOOT = int(dialect.MAV_STATE_BOOT)
MAV_FRAME_BODY_FRD = int(dialect.MAV_FRAME_BODY_FRD)
MAV_DISTANCE_SENSOR_UNKNOWN = int(dialect.MAV_DISTANCE_SENSOR_UNKNOWN)
MAV_COMP_ID_OBSTACLE_AVOIDANCE = int(dialect.MAV_COMP_ID_OBSTACLE_AVOIDANCE)
MAV_SEVERITY_CRITICAL = int(dialect.MAV_SEVERITY_CRITICAL)
MAV_SEVERITY_WARNING = int(dialect.MAV_SEVERITY_WARNING)
MAV_SEVERITY_NOTICE = int(dialect.MAV_SEVERITY_NOTICE)
MAV_SEVERITY_INFO = int(dialect.MAV_SEVERITY_INFO)

STATUSTEXT_MAX_CHARS = 50

Message = Any
"""A decoded pymavlink message (untyped; read fields by name)."""


class Codec:
    """Encodes avoidd's messages and decodes incoming bytes for one link.

    The codec keeps the link's sequence counter, so only one task may encode with it.

    Args:
        system_id: avoidd's system id (the vehicle's).
        component_id: avoidd's component id (196, obstacle avoidance).
    """

    def __init__(self, system_id: int, component_id: int) -> None:
        self._mav = dialect.MAVLink(None, srcSystem=system_id, srcComponent=component_id)
        self._mav.robust_parsing = True
        self.parse_errors = 0

    def heartbeat(self, system_status: int) -> bytes:
        """A HEARTBEAT of an onboard controller (no autopilot)."""
        message = self._mav.heartbeat_encode(
            MAV_TYPE_ONBOARD_CONTROLLER, MAV_AUTOPILOT_INVALID, 0, 0, system_status
        )
        return bytes(message.pack(self._mav))

    def obstacle_distance(
        self, time_usec: int, distances_cm: list[int], min_cm: int, max_cm: int
    ) -> bytes:
        """An OBSTACLE_DISTANCE of 72 bins of 5 degrees, bin 0 centred ahead, BODY_FRD."""
        message = self._mav.obstacle_distance_encode(
            time_usec,
            MAV_DISTANCE_SENSOR_UNKNOWN,
            distances_cm,
            0,
            min_cm,
            max_cm,
            5.0,
            0.0,
            MAV_FRAME_BODY_FRD,
        )
        return bytes(message.pack(self._mav))

    def statustext(self, severity: int, text: str) -> bytes:
        """A STATUSTEXT, cut to the 50 characters one message carries."""
        payload = text.encode("ascii", "replace")[:STATUSTEXT_MAX_CHARS]
        message = self._mav.statustext_encode(severity, payload)
        return bytes(message.pack(self._mav))

    def decode(self, data: bytes) -> list[Message]:
        """Decode every complete message in ``data`` (partial ones are kept for the next call)."""
        messages: list[Message] = []
        try:
            parsed = self._mav.parse_buffer(data)
        except Exception:
            # Garbage on a link must never take the link down: count it and go on.
            self.parse_errors += 1
            return messages
        for message in parsed or ():
            if message.get_type() == "BAD_DATA":
                self.parse_errors += 1
            else:
                messages.append(message)
        return messages
