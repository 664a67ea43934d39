"""The daemon's latest state as debug-view pictures, each drawn and encoded only when asked.

A :class:`Stream` draws its picture in a worker thread when a viewer wants one and the data
behind it changed since the last one (viewers of the same stream share the JPEG). With nobody
watching nothing is drawn or encoded: :class:`EncodeCounter` counts what was.
"""

from __future__ import annotations

import asyncio
import math
import threading
import time
from collections.abc import Callable, Hashable
from concurrent.futures import Executor
from dataclasses import dataclass
from typing import TYPE_CHECKING

from avoidd.debugview import render
from avoidd.types import Image

if TYPE_CHECKING:
    from avoidd.daemon.core import Daemon
    from avoidd.daemon.head import Head
    from avoidd.pipeline import HeadResult

_STALE_SEND_NS = 500_000_000  # both autopilots drop the data 0.5 s after the last message


@dataclass
class EncodeCounter:
    """JPEG pictures encoded, and the CPU time spent drawing and encoding them."""

    encodes: int = 0
    seconds: float = 0.0

    def __post_init__(self) -> None:
        self._lock = threading.Lock()

    def add(self, seconds: float) -> None:
        """Count one picture that took ``seconds``."""
        with self._lock:
            self.encodes += 1
            self.seconds += seconds


Snapshot = tuple[Hashable, Callable[[], Image | None]]
"""What a stream shows now: a cheap key that changes whenever the picture would, and the
drawing of exactly that state (drawn later, in a worker thread, from what was taken now)."""


class Stream:
    """One picture that viewers poll: redrawn only when its key changed.

    Args:
        snapshot: The state to show now (None: nothing to show yet). The picture is drawn
            from the state taken with its key: drawn from whatever is newest by the time a
            worker gets to it, a picture could be the previous key's once more.
        quality: JPEG quality.
        counter: Counts each encoding.
        pool: The worker threads that draw (None: asyncio's default ones).
    """

    def __init__(
        self,
        snapshot: Callable[[], Snapshot | None],
        quality: int,
        counter: EncodeCounter,
        pool: Executor | None = None,
    ) -> None:
        self._snapshot = snapshot
        self._quality = quality
        self._counter = counter
        self._pool = pool
        self._lock = asyncio.Lock()
        self._cached_key: Hashable | None = None
        self._cached: bytes | None = None

    def _encode(self, draw: Callable[[], Image | None]) -> bytes | None:
        start = time.thread_time()  # CPU of this worker thread: what drawing costs
        image = draw()
        if image is None:
            return None
        data = render.encode_jpeg(image, self._quality)
        self._counter.add(time.thread_time() - start)
        return data

    async def jpeg(self) -> bytes | None:
        """The current picture as JPEG (None while there is nothing to show)."""
        taken = self._snapshot()
        if taken is None:
            return None
        key, draw = taken
        async with self._lock:
            if key != self._cached_key or self._cached is None:
                loop = asyncio.get_running_loop()
                data = await loop.run_in_executor(self._pool, self._encode, draw)
                if data is None:
                    return None
                self._cached_key, self._cached = key, data
            return self._cached


def head_picture(head: Head, max_range_m: float, latest: HeadResult | None = None) -> Image | None:
    """One head's frame (its latest by default): the boxed left view beside the depth map."""
    latest = head.latest if latest is None else latest
    if latest is None or latest.left_view is None:
        return None
    depth = latest.filled_depth_m if latest.filled_depth_m is not None else latest.depth_m
    boxes = []
    if latest.obstacle_mask is not None:
        rig = head.pipeline.work_rig
        factor = render.range_per_depth(latest.depth_m.shape[1], rig.cx, rig.fx)
        boxes = render.obstacle_boxes(latest.obstacle_mask, latest.depth_m, factor)
    caption = f"{head.name}  frame {latest.seq}  valid {100 * latest.valid_fraction:.0f}%"
    return render.side_by_side(
        [
            render.left_panel(latest.left_view, boxes, max_range_m, caption),
            render.depth_panel(depth, max_range_m),
        ]
    )


def head_snapshot(head: Head, max_range_m: float) -> Snapshot | None:
    """The head's latest frame as a :data:`Snapshot` of :func:`head_picture` (None: none yet)."""
    latest = head.latest
    if latest is None:
        return None
    return (latest.seq, latest.t_capture_ns), lambda: head_picture(head, max_range_m, latest)


def head_stream(
    head: Head,
    max_range_m: float,
    quality: int,
    counter: EncodeCounter,
    pool: Executor | None = None,
) -> Stream:
    """The stream of :func:`head_picture` (a new picture with each processed frame)."""
    return Stream(lambda: head_snapshot(head, max_range_m), quality, counter, pool)


def planner_bearings(daemon: Daemon) -> tuple[float | None, float | None]:
    """Body-frame bearings of the planner's goal and chosen direction (None: not known).

    The planner works in the local NED frame: the vehicle's latest yaw turns its bearings into
    the body frame of the polar plot.
    """
    avoidance = daemon.avoidance
    if avoidance is None or not avoidance.config.enabled:
        return None, None
    attitude = daemon.vehicle.attitude_at(time.monotonic_ns())
    if attitude is None:
        return None, None
    yaw_deg = math.degrees(attitude.yaw_rad)
    goal_deg = direction_deg = None
    position, goal = daemon.vehicle.position, avoidance.goal
    if position is not None and goal is not None:
        north, east = goal.north_m - position.north_m, goal.east_m - position.east_m
        if math.hypot(north, east) > 0.01:
            goal_deg = math.degrees(math.atan2(east, north)) - yaw_deg
    decision = avoidance.last_decision
    if decision is not None and decision.state == "moving" and decision.direction_deg is not None:
        direction_deg = decision.direction_deg - yaw_deg
    return goal_deg, direction_deg


def sent_scan(daemon: Daemon) -> tuple[render.SentScan | None, int | None]:
    """The last OBSTACLE_DISTANCE sent, and when (monotonic ns), or (None, None)."""
    outputs = daemon.outputs
    if outputs is None or outputs.last_sent is None:
        return None, None
    sent_ns, message = outputs.last_sent
    scan = render.SentScan(
        tuple(int(v) for v in message.distances),
        float(message.increment_f or message.increment),
        float(message.angle_offset),
        int(message.min_distance),
        int(message.max_distance),
    )
    return scan, sent_ns


def polar_status(sent_ns: int | None, now_ns: int, withheld: int, planner: str | None) -> str:
    """The polar plot's status line: is the message going out, and the planner's phrase."""
    if sent_ns is None:
        state = "not sent yet"
    elif now_ns - sent_ns > _STALE_SEND_NS:
        state = f"NOT SENT for {(now_ns - sent_ns) / 1e9:.0f} s (no fresh data)"
    else:
        state = "sending"
    text = f"{state}; withheld {withheld}"
    return f"{text}; {planner}" if planner else text


def polar_snapshot(daemon: Daemon) -> Snapshot:
    """The sent scan with the planner's arrows and state, as a :data:`Snapshot`."""
    scan, sent_ns = sent_scan(daemon)
    withheld = daemon.outputs.withheld if daemon.outputs is not None else 0
    planner = daemon.avoidance.summary() if daemon.avoidance is not None else None
    status = polar_status(sent_ns, time.monotonic_ns(), withheld, planner)
    goal_deg, direction_deg = planner_bearings(daemon)
    # The content, not the time: a steady scene is drawn once, not at every message.
    key = (scan, status, (goal_deg, direction_deg))
    return key, lambda: render.polar_panel(scan, 480, status, goal_deg, direction_deg)


def polar_stream(
    daemon: Daemon, quality: int, counter: EncodeCounter, pool: Executor | None = None
) -> Stream:
    """The stream of the sent scan with the planner's arrows and state."""
    return Stream(lambda: polar_snapshot(daemon), quality, counter, pool)


def video_drawing(daemon: Daemon, width_px: int, height_px: int) -> Callable[[], Image | None]:
    """The state to show now as the video's frame (taken now, drawn when called)."""
    from avoidd.debugview.video import compose

    max_range_m = daemon.config.mavlink.obstacle_distance.max_distance_cm / 100.0
    polar = polar_snapshot(daemon)[1]
    taken = [head_snapshot(head, max_range_m) for head in daemon.heads]
    heads = [snapshot[1] for snapshot in taken if snapshot is not None]

    def draw() -> Image:
        pictures = [picture for picture in (h() for h in heads) if picture is not None]
        return compose(polar(), pictures, width_px, height_px)

    return draw
