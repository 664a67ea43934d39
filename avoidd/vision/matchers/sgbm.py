"""Semi-global matching through OpenCV's StereoSGBM."""

from __future__ import annotations

import cv2

from avoidd.config import SgbmConfig
from avoidd.types import BoolArray, FloatArray, Image
from avoidd.vision.matchers.border import confirm_band, run_opencv_matcher

_MODES = {
    "sgbm": cv2.StereoSGBM_MODE_SGBM,
    "hh": cv2.StereoSGBM_MODE_HH,
    "sgbm_3way": cv2.StereoSGBM_MODE_SGBM_3WAY,
    "hh4": cv2.StereoSGBM_MODE_HH4,
}


class SgbmMatcher:
    """OpenCV StereoSGBM on grey images; invalid pixels become NaN.

    With ``pad_left`` the left border band keeps only the readings the right view confirms
    (:func:`~avoidd.vision.matchers.border.confirm_band`): the rest read too far far more
    often than the pixels right of the band (docs/perception.md, "The left border band").

    Args:
        config: Matcher parameters; ``p1``/``p2`` default to 8 and 64 times block_size squared.
        confirm: Confirm the padded band (default). The near-field pass turns it off: it
            takes from its coarse map only readings nearer than the main range, and an
            unconfirmed nearer reading there is the safe side (dropping it would not be).
    """

    last_filled: BoolArray | None = None  # every value is measured
    last_unchecked: BoolArray | None = None  # set by compute() when the band is checked

    def __init__(self, config: SgbmConfig, *, confirm: bool = True) -> None:
        self._confirm = confirm and config.pad_left
        area = config.block_size * config.block_size
        self._min_disparity = config.min_disparity
        self._num_disparities = config.num_disparities
        self._pad = config.num_disparities if config.pad_left else 0
        self._sgbm = cv2.StereoSGBM.create(
            minDisparity=config.min_disparity,
            numDisparities=config.num_disparities,
            blockSize=config.block_size,
            P1=config.p1 if config.p1 is not None else 8 * area,
            P2=config.p2 if config.p2 is not None else 64 * area,
            disp12MaxDiff=config.disp12_max_diff,
            preFilterCap=config.pre_filter_cap,
            uniquenessRatio=config.uniqueness_ratio,
            speckleWindowSize=config.speckle_window_size,
            speckleRange=config.speckle_range,
            mode=_MODES[config.mode],
        )

    @property
    def num_disparities(self) -> int:
        """Width of the disparity search range in pixels."""
        return self._num_disparities

    def compute(self, left: Image, right: Image) -> FloatArray:
        """Match a rectified grey pair; see :class:`avoidd.vision.matchers.base.Matcher`."""
        disparity = run_opencv_matcher(self._sgbm, left, right, self._pad, self._min_disparity)
        if self._confirm:
            self.last_unchecked = confirm_band(
                left, right, disparity, self._num_disparities, self._min_disparity
            )
        return disparity
