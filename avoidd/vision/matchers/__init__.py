"""Stereo matchers behind one interface: rectified grey pair in, float32 disparity out."""

from __future__ import annotations

from avoidd.config import CensusConfig, MatcherConfig, SadConfig, SegmentConfig
from avoidd.vision.matchers.base import Matcher
from avoidd.vision.matchers.census import CensusMatcher
from avoidd.vision.matchers.sad import SadMatcher
from avoidd.vision.matchers.segment import SegmentMatcher
from avoidd.vision.matchers.sgbm import SgbmMatcher

__all__ = [
    "CensusMatcher",
    "Matcher",
    "SadMatcher",
    "SegmentMatcher",
    "SgbmMatcher",
    "create_matcher",
]


def create_matcher(config: MatcherConfig) -> Matcher:
    """Build the matcher a head's config asks for.

    Args:
        config: The ``matcher`` section of a head.

    Returns:
        A ready matcher.
    """
    if isinstance(config, SadConfig):
        return SadMatcher(config)
    if isinstance(config, CensusConfig):
        return CensusMatcher(config)
    if isinstance(config, SegmentConfig):
        return SegmentMatcher(config)
    return SgbmMatcher(config)
