"""Exception hierarchy of avoidd: every error names its subject and the remedy."""

from __future__ import annotations


class AvoiddError(Exception):
    """Base class of every error avoidd raises on purpose."""


class ConfigError(AvoiddError):
    """A configuration or calibration file is invalid.

    Attributes:
        lines: One human-readable line per problem, ``FILE:LINE: key.path: message``.
    """

    def __init__(self, lines: list[str]) -> None:
        super().__init__("\n".join(lines))
        self.lines = lines


class SourceError(AvoiddError):
    """A frame source cannot be opened or read (camera lost, file unreadable)."""


class BrokenFrame(AvoiddError):
    """One frame is unusable (unreadable file, wrong size); it is dropped and counted."""


class SourceExhausted(AvoiddError):
    """A finite frame source (files, video) has delivered its last frame.

    Args:
        message: What ended, and how (``side-by-side video X ended``).
        early: It ended before the frame count its file announces (truncated or damaged).
    """

    def __init__(self, message: str, early: bool = False) -> None:
        super().__init__(message)
        self.early = early


class LinkError(AvoiddError):
    """A MAVLink connection string is invalid or the link cannot be opened."""


class MeasureError(AvoiddError):
    """A measurement cannot be made (no frame, pixel unmeasured, ray above the horizon)."""
