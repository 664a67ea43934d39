"""SAD block matching through OpenCV's StereoBM (sum of absolute differences over a window)."""

from __future__ import annotations

import cv2

from avoidd.config import SadConfig
from avoidd.types import BoolArray, FloatArray, Image
from avoidd.vision.matchers.border import confirm_band, run_opencv_matcher

_PREFILTERS = {
    "xsobel": cv2.StereoBM_PREFILTER_XSOBEL,
    "normalized_response": cv2.StereoBM_PREFILTER_NORMALIZED_RESPONSE,
}


class SadMatcher:
    """OpenCV StereoBM on grey images; untextured, ambiguous and inconsistent pixels are NaN.

    Args:
        config: Matcher parameters.
    """

    last_filled: BoolArray | None = None  # every value is measured
    last_unchecked: BoolArray | None = None  # set by compute() when the band is checked

    def __init__(self, config: SadConfig) -> None:
        self._num_disparities = config.num_disparities
        self._pad = config.num_disparities if config.pad_left else 0
        bm = cv2.StereoBM.create(config.num_disparities, config.block_size)
        bm.setPreFilterType(_PREFILTERS[config.pre_filter])
        bm.setTextureThreshold(config.texture_threshold)
        bm.setUniquenessRatio(config.uniqueness_ratio)
        bm.setSpeckleWindowSize(config.speckle_window_size)
        bm.setSpeckleRange(config.speckle_range)
        bm.setDisp12MaxDiff(config.disp12_max_diff)
        self._bm = bm

    @property
    def num_disparities(self) -> int:
        """Width of the disparity search range in pixels."""
        return self._num_disparities

    def compute(self, left: Image, right: Image) -> FloatArray:
        """Match a rectified grey pair; see :class:`avoidd.vision.matchers.base.Matcher`."""
        disparity = run_opencv_matcher(self._bm, left, right, self._pad, 0)
        if self._pad:  # the padded band keeps what the right view confirms, as for SGBM
            self.last_unchecked = confirm_band(left, right, disparity, self._num_disparities)
        return disparity
