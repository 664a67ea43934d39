"""Frame sources: synthetic scene, recorded files and live V4L2 cameras."""

from __future__ import annotations

from pathlib import Path

from avoidd.config import (
    FilesSourceConfig,
    SimSourceConfig,
    SourceConfig,
    SyntheticSourceConfig,
)
from avoidd.errors import SourceError
from avoidd.sources.base import FrameSource
from avoidd.sources.files import open_files
from avoidd.sources.synthetic import SyntheticSource
from avoidd.sources.v4l2 import V4l2Source
from avoidd.types import RectifiedRig

__all__ = ["FrameSource", "open_source"]


def open_source(
    config: SourceConfig,
    rig: RectifiedRig,
    head: str,
    paced: bool,
    input_path: Path | None = None,
) -> FrameSource:
    """Open the source a head's config describes.

    Args:
        config: The head's ``source`` section.
        rig: The head's rectified rig (the synthetic camera renders through it).
        head: The head's name, for messages.
        paced: Real-time delivery (daemon) or as fast as possible (replay).
        input_path: Read this folder or video instead of the configured source (replay).

    Returns:
        The opened source.

    Raises:
        SourceError: The source cannot be opened.
    """
    if input_path is not None:
        return open_files(input_path, None, paced, loop=False)
    if isinstance(config, SyntheticSourceConfig):
        return SyntheticSource(config, rig, paced)
    if isinstance(config, FilesSourceConfig):
        return open_files(config.path, config.fps, paced, config.loop)
    if isinstance(config, SimSourceConfig):
        raise SourceError(
            f"head '{head}': a sim source renders the world from the autopilot's pose; only "
            "`avoidd run` (with an autopilot on the link) opens it; give --input to read files"
        )
    return V4l2Source(config, head)
