"""Stereo matchers behind one interface: rectified grey pair in, float32 disparity out."""

from __future__ import annotations

from avoidd.config import SgbmConfig
from avoidd.vision.matchers.base import Matcher
from avoidd.vision.matchers.sgbm import SgbmMatcher

__all__ = ["Matcher", "SgbmMatcher", "create_matcher"]


def create_matcher(config: SgbmConfig) -> Matcher:
    """Build the matcher a head's config asks for.

    Args:
        config: The ``matcher`` section of a head.

    Returns:
        A ready matcher.
    """
    return SgbmMatcher(config)
