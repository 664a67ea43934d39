"""``avoidd cameras``: the V4L2 cameras attached, their formats, and a config snippet for each."""

from __future__ import annotations

import argparse

from avoidd.commands import EXIT_OK
from avoidd.sources.v4l2_probe import Camera, FrameSize, PixelFormat, probe

_SIDE_BY_SIDE = 2.5
"""A frame at least this many times wider than high holds two eyes side by side."""
_MIN_FPS = 15.0


def configure(name: str, parser: argparse.ArgumentParser) -> None:
    """Add the options of ``cameras``."""
    parser.add_argument("--dev", default="/dev", help="where the device nodes are (default: /dev)")
    parser.set_defaults(handler=run_cameras)


def run_cameras(args: argparse.Namespace) -> int:
    """List the cameras and print a ``source:`` snippet for each; 'nothing found' if none."""
    cameras = probe(args.dev)
    if not cameras:
        print(
            f"nothing found: no V4L2 camera under {args.dev} (no video* node). Plug one in, "
            "see `dmesg` for what the kernel made of it, and check that this user may open "
            "it (the video group)."
        )
    for camera in cameras:
        print(format_camera(camera))
    print(
        "RealSense and OAK-D depth cameras: not looked for (avoidd does not read them yet; "
        "a RealSense's infrared pair also shows up above as V4L2 nodes)."
    )
    return EXIT_OK


def format_camera(camera: Camera) -> str:
    """The camera's lines: what it is, its formats, and the snippet."""
    lines = [f"{camera.path}: {camera.card} ({camera.driver}, {camera.bus})"]
    if camera.by_id:
        lines.append(f"  stable name: {camera.by_id}")
    if camera.error is not None:
        lines.append(f"  cannot be read: {camera.error}")
        return "\n".join(lines)
    for pixel in camera.formats:
        sizes = ", ".join(
            f"{s.width}x{s.height}@{'/'.join(f'{r:g}' for r in s.fps) or '?'}" for s in pixel.sizes
        )
        lines.append(f"  {pixel.fourcc} ({pixel.description}): {sizes}")
    lines.append(snippet(camera))
    return "\n".join(lines)


def choose(camera: Camera) -> tuple[PixelFormat, FrameSize, bool] | None:
    """The format and size the snippet asks for, and whether the frame is side by side.

    MJPG when offered (USB bandwidth for two eyes); a side-by-side size when there is one
    (a frame at least 2.5 times wider than high); else the size nearest 640x480, what the
    matcher works at; at least 15 fps where the camera offers it.
    """
    if not camera.formats:
        return None
    pixel = next((p for p in camera.formats if p.fourcc == "MJPG"), camera.formats[0])
    sizes = [s for s in pixel.sizes if not s.fps or s.fps[0] >= _MIN_FPS] or list(pixel.sizes)
    if not sizes:
        return None
    wide = [s for s in sizes if s.width >= _SIDE_BY_SIDE * s.height]
    if wide:
        return pixel, min(wide, key=lambda s: abs(s.width // 2 - 640)), True
    return pixel, min(sizes, key=lambda s: abs(s.width * s.height - 640 * 480)), False


def snippet(camera: Camera) -> str:
    """A ``source:`` block for the head's configuration."""
    chosen = choose(camera)
    if chosen is None:
        return "  (no format offered: not usable as a source)"
    pixel, size, side_by_side = chosen
    fps = next((r for r in size.fps if r <= 30.0), size.fps[-1] if size.fps else 30.0)
    device = camera.by_id or camera.path
    width = size.width // 2 if side_by_side else size.width
    what = (
        f"one eye of a {size.width}x{size.height} side-by-side frame"
        if side_by_side
        else "pair it with the other eye's device: devices: [LEFT, RIGHT]"
    )
    return "\n".join(
        [
            f"  # a head's source ({what}):",
            "  source:",
            "    kind: v4l2",
            f"    devices: [{device}]",
            f"    width: {width}",
            f"    height: {size.height}",
            f"    fps: {fps:g}",
            f"    fourcc: {pixel.fourcc}",
        ]
    )
