"""The obstacle messages to the autopilot: the merged fresh scan and the paced send loops."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import time
from collections.abc import Callable, Coroutine, Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from avoidd.config import MavlinkConfig
from avoidd.daemon.head import Head
from avoidd.logrepeat import RepeatLimiter
from avoidd.mavlink.codec import Message
from avoidd.mavlink.fill import fill_from_neighbours
from avoidd.mavlink.layout import layout_for
from avoidd.mavlink.link import MavLink
from avoidd.mavlink.messages import (
    DistanceSensorHead,
    nearest_points,
    sectors_to_cm,
    unknown_cm,
)
from avoidd.mavlink.modes import ARDUPILOT, PX4
from avoidd.mavlink.vehicle import Vehicle
from avoidd.perception.sectors import covered_bins, merge_scans
from avoidd.types import SECTOR_COUNT, SectorScan

logger = logging.getLogger(__name__)

_NOTHING_KNOWN_SAID_AFTER_NS = 1_000_000_000
"""Fresh data without a known bin is logged once it has lasted this long."""


async def every(rate_hz: float, send: Callable[[], None]) -> None:
    """Call ``send`` at ``rate_hz`` without drift (skipping ahead after a stall), forever.

    Args:
        rate_hz: Calls per second.
        send: What to call; it must not block.
    """
    period_s = 1.0 / rate_hz
    next_s = time.monotonic()
    while True:
        send()
        next_s += period_s
        delay_s = next_s - time.monotonic()
        if delay_s < -period_s:
            next_s = time.monotonic()
            delay_s = 0.0
        await asyncio.sleep(max(delay_s, 0.0))


REPEAT_S = 0.2
"""Without a new scan, the last message goes again after this long (both autopilots drop the
data 0.5 s after the last message)."""


async def when_ready(
    ready: asyncio.Event, rate_hz: float, send: Callable[[], bool], repeat_s: float = REPEAT_S
) -> None:
    """Call ``send`` as soon as ``ready`` is set, at most ``rate_hz`` times a second, forever.

    Without ``ready`` being set, ``send`` is called again ``repeat_s`` (at least one period)
    after a call that sent fresh data, and one period after one that did not (no data: the
    "I don't know" an autopilot must keep hearing goes out at the full rate, as before).

    Args:
        ready: Set when there is something new to send; cleared here before each call.
        rate_hz: Most calls per second.
        send: What to call; it must not block; True when it sent fresh data.
        repeat_s: Longest time between calls after fresh data.
    """
    period_s = 1.0 / rate_hz
    repeat_s = max(repeat_s, period_s)
    last_s = -math.inf
    wait_for_s = period_s
    while True:
        wait_s = last_s + wait_for_s - time.monotonic()
        if wait_s > 0.0 and not ready.is_set():
            # asyncio.timeout, not wait_for: on Python 3.11 wait_for can swallow a
            # cancellation that lands as the event is set, and this loop would never end
            # (a daemon stop hung for 30 s once in CI).
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(wait_s):
                    await ready.wait()
        early_s = last_s + period_s - time.monotonic()
        if early_s > 0.0:
            await asyncio.sleep(early_s)  # the rate limit
        ready.clear()
        wait_for_s = repeat_s if send() else period_s
        last_s = time.monotonic()


def current_scan(heads: Sequence[Head], now_ns: int, max_age_ns: int) -> SectorScan | None:
    """The fresh scans of all heads merged into one, or None if no head is fresh.

    Args:
        heads: The daemon's heads.
        now_ns: The current monotonic time.
        max_age_ns: Age beyond which a head's scan (or a bin's reading) is left out.

    Returns:
        The merged scan, or None.
    """
    fresh = [s for h in heads if (s := h.fresh_scan(now_ns, max_age_ns)) is not None]
    return merge_scans(fresh) if fresh else None


class Outputs:
    """Sends what the heads see: OBSTACLE_DISTANCE, DISTANCE_SENSOR and OBSTACLE_DISTANCE_3D.

    Args:
        config: The ``mavlink`` section (rates, ranges, which messages are enabled).
        max_age_ms: Data older than this is never sent (``pipeline.max_age_ms``).
        heads: The heads whose scans are sent.
        link: Where to send (its codec builds the messages).
        vehicle: The autopilot's clock, to stamp messages with.
    """

    def __init__(
        self,
        config: MavlinkConfig,
        max_age_ms: int,
        heads: Sequence[Head],
        link: MavLink,
        vehicle: Vehicle,
    ) -> None:
        self.config = config
        self.max_age_ns = max_age_ms * 1_000_000
        self.heads = heads
        self.link = link
        self.vehicle = vehicle
        self.withheld = 0
        """OBSTACLE_DISTANCE messages not sent for want of fresh data."""
        self.last_sent: tuple[int, Message] | None = None
        """The last OBSTACLE_DISTANCE sent and when (monotonic ns), for the debug view."""
        self._last_usec = 0
        self.last_was_fresh = False
        """Whether the last OBSTACLE_DISTANCE built carried a fresh scan (not "no data")."""
        self._last_autopilot: str | None = None
        self._blind_log = RepeatLimiter(logger)
        self._nothing_known_since_ns: int | None = None
        nearest_m = max((head.pipeline.min_range_m for head in heads), default=0.0)
        farthest_m = min((head.pipeline.resolved_range_m for head in heads), default=math.inf)
        self.min_cm, self.max_cm = config.obstacle_distance.range_cm(nearest_m, farthest_m)
        """The range the messages claim: what the least capable head measures and resolves."""
        self.in_view = np.zeros(SECTOR_COUNT, dtype=np.bool_)
        """The bins some head's field of view covers."""
        for head in heads:
            self.in_view |= covered_bins(head.pipeline.work_rig, head.pipeline.mount)
        self._scan_ready = asyncio.Event()
        for head in heads:
            head.on_result = self._scan_ready.set

    def current_scan(self, now_ns: int) -> SectorScan | None:
        """The heads' fresh scans merged (see :func:`current_scan`)."""
        return current_scan(self.heads, now_ns, self.max_age_ns)

    def loops(self) -> dict[str, Coroutine[Any, Any, None]]:
        """The send loops the configuration enables, by task name, in start order."""
        loops: dict[str, Coroutine[Any, Any, None]] = {}
        if self.config.distance_sensor.enabled:
            loops["distance"] = self.distance_sensor()
        if self.config.obstacle_distance_3d.enabled:
            loops["obstacle-3d"] = self.obstacle_distance_3d()
        loops["send"] = self.obstacle_distance()
        return loops

    def autopilot(self) -> str | None:
        """The autopilot on the link ("ArduPilot", "PX4", another), or None before it spoke."""
        mode = self.vehicle.mode
        return mode.autopilot if self.vehicle.link_up and mode is not None else None

    def obstacle_distance_message(self, now_ns: int) -> Message | None:
        """The OBSTACLE_DISTANCE to send now, or None when nothing should be sent.

        With fresh data: the merged scan in the autopilot's layout (see
        :mod:`avoidd.mavlink.layout`). Without any: all bins unknown for PX4, which reads
        65535 as "no data"; nothing for ArduPilot, which takes a message of unknown bins as a
        healthy sensor with a clear view (without messages it reports "PRX1: No Data" within
        0.5 s and fails pre-arm); nothing either for an autopilot not yet heard from. Fresh
        data of which no bin is known is no data either. For any autopilot but PX4, an unknown
        bin in view beside a reading is sent with the nearer neighbour's reading
        (:mod:`avoidd.mavlink.fill`).
        ``time_usec`` is the capture time on avoidd's monotonic clock, never going back
        (ArduPilot and PX4 both time the data from its arrival and do not read it).
        """
        autopilot = self.autopilot()
        layout = layout_for(autopilot)
        scan = self.current_scan(now_ns)
        if scan is not None and autopilot != PX4 and bool(np.isnan(scan.distance_m).all()):
            # Fresh, but not one bin known (a view without texture): as good as no data.
            # Said once it lasts (the temporal filter's first frames know nothing yet).
            since_ns = self._nothing_known_since_ns
            if since_ns is None:
                self._nothing_known_since_ns = now_ns
            elif now_ns - since_ns >= _NOTHING_KNOWN_SAID_AFTER_NS:
                self._blind_log.report(
                    logging.WARNING,
                    "nothing known",
                    "fresh data but no bin measured (views without texture?); "
                    "OBSTACLE_DISTANCE withheld, which ArduPilot would read as a clear view",
                )
            scan = None
        elif scan is not None:
            self._nothing_known_since_ns = None
            self._blind_log.clear("bins measured again; OBSTACLE_DISTANCE sent again")
        self.last_was_fresh = scan is not None
        if scan is None:
            if autopilot != PX4:
                self.withheld += 1
                return None
            distances, t_ns = unknown_cm(), now_ns
        else:
            if autopilot != PX4 and self.config.obstacle_distance.fill_from_neighbours:
                # ArduPilot reads an unknown bin as nothing: the nearer neighbour's reading.
                scan = replace(scan, distance_m=fill_from_neighbours(scan.distance_m, self.in_view))
            distances, t_ns = sectors_to_cm(scan, self.min_cm, self.max_cm), scan.t_capture_ns
        self._last_usec = max(self._last_usec, t_ns // 1000)
        return self.link.codec.obstacle_distance(
            self._last_usec,
            layout.arrange(distances, self.max_cm),
            self.min_cm,
            self.max_cm,
            layout.increment_deg,
            layout.angle_offset_deg,
        )

    async def obstacle_distance(self) -> None:
        """Send OBSTACLE_DISTANCE as each new scan is made (see :meth:`obstacle_distance_message`).

        At most ``rate_hz`` a second; without a new scan the message goes again after
        :data:`REPEAT_S`, so a scan never waits for a send tick and the autopilot never goes
        without a message for its 0.5 s timeout. Without fresh data (PX4's all-unknown
        message) it goes at the full ``rate_hz``, as before.
        """

        def send() -> bool:
            now_ns = time.monotonic_ns()
            message = self.obstacle_distance_message(now_ns)
            if message is not None:
                self.link.send(message)
                self.last_sent = (now_ns, message)
            return message is not None and self.last_was_fresh

        await when_ready(self._scan_ready, self.config.obstacle_distance.rate_hz, send)

    def sends_distance_sensor(self) -> bool:
        """Whether DISTANCE_SENSOR goes to the autopilot on the link now.

        ArduPilot and PX4 both put a horizontal DISTANCE_SENSOR into the same proximity map as
        OBSTACLE_DISTANCE: ArduPilot keeps whichever message wrote a 45-degree sector last
        (so the two fight over it), PX4 spreads the one reading over the sensor's whole field
        of view. So they get it only with ``distance_sensor.alongside_obstacle_distance``, and
        so does an autopilot not heard from yet (it may be either: an earlier version sent
        ArduPilot DISTANCE_SENSOR until its first heartbeat arrived) or one whose link is
        down (the one heard last is taken to be coming back). Other autopilots get it
        whenever it is enabled.
        """
        autopilot = self.autopilot()
        if autopilot is not None:
            self._last_autopilot = autopilot
        if self._last_autopilot in (None, ARDUPILOT, PX4):
            return self.config.distance_sensor.alongside_obstacle_distance
        return True

    async def distance_sensor(self) -> None:
        """Send DISTANCE_SENSOR at its rate, one per fresh head (nothing for a stale one)."""
        codec = self.link.codec
        sensors = {
            head.name: DistanceSensorHead(head.pipeline.work_rig, head.pipeline.mount, index)
            for index, head in enumerate(self.heads)
        }

        def send() -> None:
            if not self.sends_distance_sensor():
                return
            now_ns = time.monotonic_ns()
            for head in self.heads:
                scan = head.fresh_scan(now_ns, self.max_age_ns)
                latest = head.latest
                if scan is None or latest is None:
                    continue  # stale: say nothing, the autopilot times the sensor out
                sensor = sensors[head.name]
                reading_cm = sensor.reading_cm(scan, self.min_cm, self.max_cm)
                if reading_cm is None:
                    continue
                self.link.send(
                    sensor.message(
                        codec,
                        self.vehicle.time_boot_ms(latest.t_capture_ns),
                        reading_cm,
                        self.min_cm,
                        self.max_cm,
                        latest.valid_fraction,
                    )
                )

        await every(self.config.distance_sensor.rate_hz, send)

    async def obstacle_distance_3d(self) -> None:
        """Send OBSTACLE_DISTANCE_3D at its rate: the nearest points of the merged scan."""
        od3 = self.config.obstacle_distance_3d
        codec = self.link.codec

        def send() -> None:
            scan = self.current_scan(time.monotonic_ns())
            if scan is None:
                return
            time_boot_ms = self.vehicle.time_boot_ms(scan.t_capture_ns)
            for point in nearest_points(scan, od3.max_points):
                self.link.send(
                    codec.obstacle_distance_3d(
                        time_boot_ms, point, self.min_cm / 100, self.max_cm / 100
                    )
                )

        await every(od3.rate_hz, send)
