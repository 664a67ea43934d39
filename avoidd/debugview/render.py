"""Pictures of the debug view, pure functions on arrays: the boxed left view, depth, polar scan.

Nothing here does I/O or knows about the web: each function takes arrays and numbers and
returns a BGR image; :func:`encode_jpeg` turns one into JPEG bytes.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from avoidd.types import BoolArray, FloatArray, Image

UNKNOWN_CM = 65535

# BGR colours of the polar plot (kept apart so that a screenshot can tell them apart).
UNKNOWN_BGR = (110, 110, 110)
"""A bin sent as 65535: not covered, not measured or stale."""
CLEAR_BGR = (70, 190, 70)
"""A bin sent as ``max_distance + 1``: measured clear."""
NEAR_BGR = (40, 40, 235)
"""A bin holding a reading: drawn out to that distance."""
INVALID_BGR = (220, 60, 220)
"""A value neither unknown, clear nor in [min, max] (the autopilot ignores it)."""
GOAL_BGR = (235, 200, 40)
DIRECTION_BGR = (40, 220, 255)
BEYOND_BGR = (60, 60, 60)
"""The plot's disc: beyond a reading (hidden behind it)."""
BACKGROUND_BGR = (32, 24, 24)
_TEXT_BGR = (235, 235, 235)
_FONT = cv2.FONT_HERSHEY_SIMPLEX


@dataclass(frozen=True)
class Box:
    """An obstacle's outline in the image and its distance.

    Attributes:
        x: Left column.
        y: Top row.
        width: Width in pixels.
        height: Height in pixels.
        distance_m: Its range from the camera (25th percentile of its measured pixels).
    """

    x: int
    y: int
    width: int
    height: int
    distance_m: float


@dataclass(frozen=True)
class SentScan:
    """An OBSTACLE_DISTANCE as it went on the wire.

    Attributes:
        distances_cm: The 72 values.
        increment_deg: Width of a bin (``increment_f``).
        angle_offset_deg: Bearing of bin 0 (``angle_offset``), positive right.
        min_cm: ``min_distance``.
        max_cm: ``max_distance``.
    """

    distances_cm: tuple[int, ...]
    increment_deg: float
    angle_offset_deg: float
    min_cm: int
    max_cm: int


def to_bgr(image: Image) -> Image:
    """A grey or BGR 8-bit image as BGR."""
    if image.ndim == 2:
        return np.asarray(cv2.cvtColor(image, cv2.COLOR_GRAY2BGR), dtype=np.uint8)
    return image.copy()


def range_per_depth(width: int, cx: float, fx: float) -> FloatArray:
    """(W,) range from the camera per metre of depth in each column: ``sqrt(1 + xn^2)``."""
    xn = (np.arange(width, dtype=np.float32) - np.float32(cx)) / np.float32(fx)
    return np.asarray(np.sqrt(1.0 + xn * xn), dtype=np.float32)


def obstacle_boxes(
    mask: BoolArray,
    depth_m: FloatArray,
    range_factor: FloatArray | None = None,
    min_area_fraction: float = 0.001,
    limit: int = 8,
    step: int = 2,
) -> list[Box]:
    """Outline the obstacle pixels: their connected regions, nearest first.

    A region's distance is the 25th percentile of its pixels' ranges: lower percentiles
    picked up the errors stereo matching makes at a thin object's edges (the demo's pole,
    9.7 m away, read more than a metre short at the 5th).

    Args:
        mask: (H, W) True at obstacle points (see ``HeadResult.obstacle_mask``).
        depth_m: The depth map of the same size.
        range_factor: (W,) range per metre of depth by column (see :func:`range_per_depth`);
            None: distances are depths.
        min_area_fraction: Regions smaller than this share of the image are left out.
        limit: At most this many boxes.
        step: Regions are found on every ``step``-th row and column (a quarter of the work
            for 2; boxes are that coarse).

    Returns:
        The boxes, nearest first.
    """
    if mask.shape != depth_m.shape or not mask.any():
        return []
    small_mask, small_depth = mask[::step, ::step], depth_m[::step, ::step]
    if range_factor is not None:
        small_depth = small_depth * range_factor[::step][None, :]
    joined = cv2.morphologyEx(
        small_mask.astype(np.uint8), cv2.MORPH_CLOSE, np.ones((3, 3), dtype=np.uint8)
    )
    count, labels, stats, _ = cv2.connectedComponentsWithStats(joined, connectivity=8)
    min_area = max(5, int(min_area_fraction * small_mask.size))
    boxes = []
    for label in range(1, count):
        x, y, w, h, area = (int(v) for v in stats[label])
        if area < min_area:
            continue
        window = labels[y : y + h, x : x + w] == label
        window &= small_mask[y : y + h, x : x + w]
        values = small_depth[y : y + h, x : x + w][window]
        values = values[np.isfinite(values)]
        if values.size == 0:
            continue
        distance = float(np.percentile(values, 25.0))
        boxes.append(Box(x * step, y * step, w * step, h * step, distance))
    boxes.sort(key=lambda b: b.distance_m)
    return boxes[:limit]


def _label(image: Image, text: str, x: int, y: int, colour: tuple[int, int, int]) -> None:
    """Text with a dark backing, its top-left corner at (x, y), kept inside the image."""
    scale, thickness = 0.5, 1
    (w, h), base = cv2.getTextSize(text, _FONT, scale, thickness)
    x = min(max(x, 0), max(image.shape[1] - w - 4, 0))
    y = min(max(y, 0), max(image.shape[0] - h - base - 4, 0))
    cv2.rectangle(image, (x, y), (x + w + 4, y + h + base + 4), (0, 0, 0), -1)
    cv2.putText(image, text, (x + 2, y + h + 2), _FONT, scale, colour, thickness, cv2.LINE_AA)


def _near_colour(distance_m: float, max_range_m: float) -> tuple[int, int, int]:
    """Red when near, through orange to yellow toward the maximum range."""
    t = min(max(distance_m / max(max_range_m, 1e-6), 0.0), 1.0)
    return (40, int(60 + 180 * t), 240)


def left_panel(left: Image, boxes: Sequence[Box], max_range_m: float, caption: str = "") -> Image:
    """The left view with each obstacle boxed and labelled with its distance.

    Args:
        left: The rectified left view (grey or BGR).
        boxes: Obstacle boxes in its pixel coordinates.
        max_range_m: Range of the colour scale of the boxes.
        caption: A line drawn at the top left (head name, frame number).

    Returns:
        A BGR image of the view's size.
    """
    image = to_bgr(left)
    for box in boxes:
        colour = _near_colour(box.distance_m, max_range_m)
        cv2.rectangle(
            image, (box.x, box.y), (box.x + box.width - 1, box.y + box.height - 1), colour, 2
        )
        _label(image, f"{box.distance_m:.1f} m", box.x, box.y - 22, colour)
    if caption:
        _label(image, caption, 4, 4, _TEXT_BGR)
    return image


def depth_panel(depth_m: FloatArray, max_range_m: float, ticks_m: float = 5.0) -> Image:
    """The depth map in colour (near red, far blue; black unmeasured) with a legend bar.

    Args:
        depth_m: (H, W) depth in metres; NaN unmeasured, ``inf`` or beyond the range: far.
        max_range_m: Depth shown at the far end of the scale.
        ticks_m: Spacing of the legend's labels.

    Returns:
        A BGR image of the map's size, the legend on its right edge.
    """
    height, width = depth_m.shape
    # 255 at 0 m down to 0 at the range and beyond (inf too); NaN is blacked out after.
    # (OpenCV calls throughout: boolean indexing of a 640x480 map cost milliseconds.)
    scaled = depth_m * np.float32(-255.0 / max_range_m) + np.float32(255.0)
    np.clip(scaled, 0.0, 255.0, out=scaled)
    measured = cv2.compare(depth_m, depth_m, cv2.CMP_EQ)  # 0 where NaN
    cv2.patchNaNs(scaled, 0.0)
    colours = cv2.applyColorMap(scaled.astype(np.uint8), cv2.COLORMAP_TURBO)
    image = np.asarray(cv2.bitwise_and(colours, colours, mask=measured), dtype=np.uint8)
    # Legend: a bar from 0 m (top) to the range (bottom) with labels.
    bar_w, margin = 14, 8
    top, bottom = margin + 14, height - margin
    x1 = width - margin - bar_w
    cv2.rectangle(image, (x1 - 40, top - 18), (width - 2, bottom + 4), (0, 0, 0), -1)
    rows = np.linspace(255, 0, max(bottom - top, 2)).astype(np.uint8)
    bar = cv2.applyColorMap(rows[:, None], cv2.COLORMAP_TURBO)
    image[top:bottom, x1 : x1 + bar_w] = np.repeat(bar, bar_w, axis=1)[: bottom - top]
    cv2.putText(image, "m", (x1 - 2, top - 6), _FONT, 0.4, _TEXT_BGR, 1, cv2.LINE_AA)
    steps = int(max_range_m // ticks_m)
    for k in range(steps + 1):
        value = k * ticks_m
        y = top + round((bottom - top - 1) * value / max_range_m)
        cv2.line(image, (x1 - 4, y), (x1, y), _TEXT_BGR, 1)
        cv2.putText(image, f"{value:g}", (x1 - 36, y + 4), _FONT, 0.4, _TEXT_BGR, 1, cv2.LINE_AA)
    _label(image, "depth (black: unmeasured)", 4, 4, _TEXT_BGR)
    return image


def side_by_side(images: Sequence[Image]) -> Image:
    """Images of one height next to each other (shorter ones padded at the bottom)."""
    height = max(image.shape[0] for image in images)
    padded = [
        cv2.copyMakeBorder(
            image, 0, height - image.shape[0], 0, 0, cv2.BORDER_CONSTANT, value=(0, 0, 0)
        )
        for image in images
    ]
    return np.asarray(np.hstack(padded), dtype=np.uint8)


def bin_kind(value_cm: int, min_cm: int, max_cm: int) -> str:
    """What a sent value means: ``unknown``, ``clear``, ``near`` or ``invalid``."""
    if value_cm == UNKNOWN_CM:
        return "unknown"
    if value_cm == max_cm + 1:
        return "clear"
    if min_cm <= value_cm <= max_cm:
        return "near"
    return "invalid"


def _screen(cx: int, cy: int, radius: float, bearing_deg: float) -> tuple[int, int]:
    """Screen point of a bearing (0 up, positive clockwise) at a radius."""
    b = math.radians(bearing_deg)
    return (round(cx + radius * math.sin(b)), round(cy - radius * math.cos(b)))


def _wedge(
    cx: int, cy: int, radius: float, start_deg: float, end_deg: float
) -> np.ndarray[tuple[int, int], np.dtype[np.int32]]:
    """Polygon of a pie slice between two bearings."""
    steps = max(2, math.ceil(abs(end_deg - start_deg)))
    points = [(cx, cy)] + [
        _screen(cx, cy, radius, start_deg + (end_deg - start_deg) * k / steps)
        for k in range(steps + 1)
    ]
    return np.asarray(points, dtype=np.int32)


def _arrow(
    image: Image, cx: int, cy: int, radius: float, bearing_deg: float, colour: tuple[int, ...]
) -> None:
    cv2.arrowedLine(
        image, (cx, cy), _screen(cx, cy, radius, bearing_deg), colour, 3, cv2.LINE_AA, 0, 0.06
    )


def polar_panel(
    sent: SentScan | None,
    size_px: int = 480,
    status: str = "",
    goal_bearing_deg: float | None = None,
    direction_bearing_deg: float | None = None,
    ring_m: float = 5.0,
) -> Image:
    """The bins of an OBSTACLE_DISTANCE around the vehicle, as the autopilot receives them.

    Bin ``j`` is drawn centred on bearing ``angle_offset + j * increment`` (body frame, ahead
    up, right to the right), one ``increment`` wide; only the ``360 / increment`` bins in use
    are drawn. A reading fills its wedge out to its distance; clear and unknown bins fill
    theirs to the edge, each in its colour.

    Args:
        sent: The message's values, or None when nothing has been sent.
        size_px: Height of the image (it is 1.5 times as wide, for the legend).
        status: A line drawn under the title (age of the message, layout).
        goal_bearing_deg: Bearing of the planner's goal from the vehicle (an arrow), if any.
        direction_bearing_deg: Bearing of the planner's chosen direction, if any.
        ring_m: Spacing of the distance rings.

    Returns:
        A BGR image.
    """
    width = size_px * 3 // 2
    image = np.full((size_px, width, 3), BACKGROUND_BGR, dtype=np.uint8)
    cx, cy = size_px // 2, size_px // 2 + 10
    radius = size_px // 2 - 30
    max_cm = sent.max_cm if sent is not None else 2000
    max_m = max_cm / 100.0
    cv2.circle(image, (cx, cy), radius, BEYOND_BGR, -1, cv2.LINE_AA)
    if sent is not None:
        bins = round(360.0 / sent.increment_deg)
        half = sent.increment_deg / 2.0
        for j, value in enumerate(sent.distances_cm[:bins]):
            centre = sent.angle_offset_deg + j * sent.increment_deg
            kind = bin_kind(value, sent.min_cm, sent.max_cm)
            if kind == "near":
                colour, r = NEAR_BGR, radius * min(value / max_cm, 1.0)
            else:
                colour = {"unknown": UNKNOWN_BGR, "clear": CLEAR_BGR}.get(kind, INVALID_BGR)
                r = float(radius)
            cv2.fillPoly(image, [_wedge(cx, cy, r, centre - half, centre + half)], colour)
    rings = int(max_m // ring_m)
    for k in range(1, rings + 1):
        r = round(radius * k * ring_m / max_m)
        cv2.circle(image, (cx, cy), r, (20, 20, 20), 1, cv2.LINE_AA)
        cv2.putText(image, f"{k * ring_m:g} m", (cx + 3, cy - r + 12), _FONT, 0.4, _TEXT_BGR, 1)
    for sector in range(8):  # ArduPilot's 45-degree sectors
        cv2.line(image, (cx, cy), _screen(cx, cy, radius, sector * 45.0 + 22.5), (20, 20, 20), 1)
    cv2.circle(image, (cx, cy), radius, (200, 200, 200), 1, cv2.LINE_AA)
    for bearing, name in ((0.0, "ahead"), (90.0, "right"), (180.0, "behind"), (270.0, "left")):
        x, y = _screen(cx, cy, radius + 14, bearing)
        (w, h), _ = cv2.getTextSize(name, _FONT, 0.45, 1)
        cv2.putText(image, name, (x - w // 2, y + h // 2), _FONT, 0.45, _TEXT_BGR, 1, cv2.LINE_AA)
    cv2.drawMarker(image, (cx, cy), (255, 255, 255), cv2.MARKER_TRIANGLE_UP, 14, 2)
    if goal_bearing_deg is not None:
        _arrow(image, cx, cy, radius * 0.95, goal_bearing_deg, GOAL_BGR)
    if direction_bearing_deg is not None:
        _arrow(image, cx, cy, radius * 0.8, direction_bearing_deg, DIRECTION_BGR)
    # Legend and the message's parameters.
    x0 = size_px + 24
    cv2.putText(image, "OBSTACLE_DISTANCE", (x0, 24), _FONT, 0.5, _TEXT_BGR, 1, cv2.LINE_AA)
    y = 50
    legend = [
        (NEAR_BGR, "reading (to its distance)"),
        (BEYOND_BGR, "beyond a reading"),
        (CLEAR_BGR, "clear (max + 1)"),
        (UNKNOWN_BGR, "unknown (65535)"),
        (INVALID_BGR, "invalid (ignored)"),
        (GOAL_BGR, "goal"),
        (DIRECTION_BGR, "chosen direction"),
    ]
    for colour, text in legend:
        cv2.rectangle(image, (x0, y - 10), (x0 + 14, y + 2), colour, -1)
        cv2.putText(image, text, (x0 + 20, y), _FONT, 0.4, _TEXT_BGR, 1, cv2.LINE_AA)
        y += 20
    y += 10
    if sent is not None:
        lines = [
            f"increment {sent.increment_deg:g} deg",
            f"angle_offset {sent.angle_offset_deg:g} deg",
            f"min {sent.min_cm} cm, max {sent.max_cm} cm",
        ]
    else:
        lines = ["nothing sent yet"]
    lines += _wrap(status, 26)
    for line in lines:
        cv2.putText(image, line, (x0, y), _FONT, 0.4, _TEXT_BGR, 1, cv2.LINE_AA)
        y += 18
    return image


def _wrap(text: str, width: int) -> list[str]:
    """Words of ``text`` in lines of at most about ``width`` characters."""
    lines: list[str] = []
    for word in text.split():
        if lines and len(lines[-1]) + 1 + len(word) <= width:
            lines[-1] += " " + word
        else:
            lines.append(word)
    return lines


def encode_jpeg(image: Image, quality: int) -> bytes:
    """JPEG bytes of a BGR or grey image."""
    ok, data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise ValueError(f"JPEG encoding of a {image.shape} image failed")
    return bytes(data.tobytes())
