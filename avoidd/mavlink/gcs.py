"""A ground-station endpoint of avoidd's own, for a bench (or a vehicle) without a MAVLink router.

``mavlink.gcs_connection`` (e.g. ``udpin:127.0.0.1:14551``) opens a second link that behaves
like one endpoint of a router between the autopilot and one ground station:

- what a ground station sends there reaches the autopilot unchanged (raw bytes, signatures
  kept), and what is addressed to avoidd (goals, commands, parameters) is also decoded and
  taken exactly as on the autopilot's link: the same trust rule (the vehicle's own system and
  ``mavlink.control.ground_stations``, signatures on a signed link), the same answers. Nothing
  else from there is read: the autopilot's state comes from its own link only;
- everything avoidd sends (HEARTBEAT, STATUSTEXT, COMMAND_ACK, PARAM_VALUE, the obstacle
  messages) and everything the adopted autopilot sends goes to the ground station.

A ``udpin`` endpoint answers the last sender it heard: one ground station at a time (``avoidd
goto``, or QGroundControl/Mission Planner pointed at it), and anyone who can reach the port can
be that sender, so keep it on loopback or a trusted network. Nothing is sent before one spoke.
At most :data:`MAX_DATAGRAMS_PER_S` are taken a second.
"""

from __future__ import annotations

import logging
import time
from collections import Counter

from avoidd.config.connection import LinkSpec
from avoidd.mavlink.link import Handler, MavLink
from avoidd.mavlink.transport import Transport, create_transport

logger = logging.getLogger(__name__)

MAX_DATAGRAMS_PER_S = 500
"""What the endpoint takes from ground stations per second; the rest is dropped unread, so a
flood there can neither fill the autopilot's link (a serial line's buffer, which avoidd's own
OBSTACLE_DISTANCE needs) nor take the event loop (a ground station sends tens a second, a
parameter download a few hundred)."""


class GcsEndpoint:
    """The ground-station endpoint: bytes both ways, and avoidd's messages decoded on the way in.

    Args:
        spec: Where ground stations reach avoidd.
        link: The autopilot's link (forwarded to and from).
        handle: Takes every message decoded from the ground station (the vehicle tracker's
            handler, which passes what is addressed to avoidd on under the trust rule).
    """

    def __init__(self, spec: LinkSpec, link: MavLink, handle: Handler) -> None:
        self.spec = spec
        self._link = link
        self._handle = handle
        self._parser = link.codec.parser()
        self.transport: Transport = create_transport(spec, self._on_bytes)
        self.counts: Counter[str] = Counter()
        """``to_autopilot``, ``to_gcs``, ``dropped`` and ``over_budget`` datagrams, and the
        ``decoded`` messages."""
        self._heard = False
        self._window_s = 0.0
        self._in_window = 0
        link.mirror(self._to_gcs)

    async def open(self) -> None:
        """Start listening (or connecting).

        Raises:
            LinkError: The endpoint cannot start (a bad address, a busy port).
        """
        await self.transport.open()
        logger.info("MAVLink ground-station endpoint %s open", self.spec)

    async def close(self) -> None:
        """Stop forwarding and close the endpoint."""
        self._link.unmirror(self._to_gcs)
        await self.transport.close()

    def _on_bytes(self, data: bytes) -> None:
        now_s = time.monotonic()
        if now_s - self._window_s >= 1.0:
            self._window_s, self._in_window = now_s, 0
        self._in_window += 1
        if self._in_window > MAX_DATAGRAMS_PER_S:
            self.counts["over_budget"] += 1
            return
        if not self._heard:
            self._heard = True
            logger.info("MAVLink ground-station endpoint %s: a ground station spoke", self.spec)
        self.counts["to_autopilot" if self._link.send_raw(data) else "dropped"] += 1
        received_ns = time.monotonic_ns()
        for message in self._parser.decode(data):
            self.counts["decoded"] += 1
            try:
                self._handle(message, received_ns)
            except Exception:
                logger.exception("MAVLink ground-station endpoint: handler failed on %s", message)

    def _to_gcs(self, data: bytes) -> None:
        if self.transport.connected:
            self.counts["to_gcs" if self.transport.send(data) else "dropped"] += 1

    def counters(self) -> dict[str, int]:
        """What went through, for logs and tests."""
        return dict(self.counts)
