"""Census transform and the sum of Hamming distances over a window (the paper's SHD matcher).

Each pixel is described by which of its neighbours are darker than it (the census code);
the cost of a disparity is the number of differing bits between the left code and the right
code at that disparity, summed over an ``aggregation`` x ``aggregation`` window (11x11 in the
paper); the disparity with the smallest sum wins.

The left border band is matched by padding both views with replicated columns, as for SGBM;
matches that land in the padding are dropped.

Vectorised with OpenCV: per disparity one XOR and one popcount look-up per code byte, one box
filter, and a winner-take-all in which cost and disparity are packed into one integer
(``cost << k | d``), so a single ``min`` keeps both, for the left view and (from the same
window costs, shifted) for the right view, whose disparities feed a left-right check.
"""

from __future__ import annotations

import cv2
import numpy as np

from avoidd.config import CensusConfig
from avoidd.types import BoolArray, FloatArray, Image
from avoidd.vision.matchers.border import crop_padded, pad_left
from avoidd.vision.postprocess import left_right_check, remove_speckles

PATTERNS: dict[str, tuple[tuple[int, int], ...]] = {
    # 8 samples on the border of a 5x5 window: cheap and robust.
    "sparse5x5": ((-2, -2), (-2, 0), (-2, 2), (0, -2), (0, 2), (2, -2), (2, 0), (2, 2)),
    # Every pixel of a 5x5 window but the centre: 24 bits.
    "full5x5": tuple((dy, dx) for dy in range(-2, 3) for dx in range(-2, 3) if (dy, dx) != (0, 0)),
}


def census_transform(image: Image, pattern: tuple[tuple[int, int], ...]) -> list[Image]:
    """Census codes of a grey image as one uint8 plane per 8 bits.

    Bit k of a pixel is 1 when its k-th neighbour (``pattern[k]``, as (dy, dx)) is darker.
    Borders are mirrored.
    """
    height, width = image.shape
    radius = max(max(abs(dy), abs(dx)) for dy, dx in pattern)
    padded = cv2.copyMakeBorder(image, radius, radius, radius, radius, cv2.BORDER_REFLECT_101)
    centre = padded[radius : radius + height, radius : radius + width]
    planes: list[Image] = []
    for start in range(0, len(pattern), 8):
        plane = np.zeros((height, width), dtype=np.uint8)
        for bit, (dy, dx) in enumerate(pattern[start : start + 8]):
            neighbour = padded[
                radius + dy : radius + dy + height, radius + dx : radius + dx + width
            ]
            plane |= (neighbour < centre).view(np.uint8) << np.uint8(bit)
        planes.append(plane)
    return planes


def texture_mask(image: Image, window_px: int, min_std: float) -> np.ndarray:
    """Pixels whose neighbourhood has a grey-level standard deviation of at least ``min_std``."""
    grey = image.astype(np.float32)
    size = (window_px, window_px)
    mean = cv2.boxFilter(grey, -1, size, borderType=cv2.BORDER_REFLECT_101)
    mean_sq = cv2.boxFilter(grey * grey, -1, size, borderType=cv2.BORDER_REFLECT_101)
    return np.asarray(mean_sq - mean * mean >= min_std * min_std)


class CensusMatcher:
    """Census + SHD block matching; untextured, poorly matched and speckle pixels are NaN.

    Args:
        config: Matcher parameters.
    """

    last_filled: BoolArray | None = None  # every value is measured
    last_unchecked: BoolArray | None = None  # set by compute() when the band is checked

    def __init__(self, config: CensusConfig) -> None:
        self._config = config
        self._pattern = PATTERNS[config.pattern]

    @property
    def num_disparities(self) -> int:
        """Width of the disparity search range in pixels."""
        return self._config.num_disparities

    def compute(self, left: Image, right: Image) -> FloatArray:
        """Match a rectified grey pair; see :class:`avoidd.vision.matchers.base.Matcher`."""
        config = self._config
        band = config.num_disparities
        left, right = pad_left(left, band), pad_left(right, band)
        codes_left = census_transform(left, self._pattern)
        codes_right = census_transform(right, self._pattern)
        best_left, best_right, shift = self._winner_take_all(codes_left, codes_right)
        mask = (1 << shift) - 1
        disparity_left = (best_left & mask).astype(np.int32)
        disparity_right = (best_right & mask).astype(np.int32)
        disparity = left_right_check(disparity_left, disparity_right, config.lr_max_diff_px)
        # Mean Hamming distance per pixel of the window at the best disparity.
        bits = len(self._pattern)
        area = config.aggregation_px * config.aggregation_px
        mean_bits = (best_left >> shift).astype(np.float32) / area
        disparity[mean_bits > config.max_mean_distance * bits] = np.nan
        disparity[~texture_mask(left, config.texture_window_px, config.min_texture_std)] = np.nan
        if config.speckle_window_size > 0:
            disparity = remove_speckles(disparity, config.speckle_window_size, 1.0)
        return crop_padded(disparity, band)

    def _winner_take_all(
        self, codes_left: list[Image], codes_right: list[Image]
    ) -> tuple[np.ndarray, np.ndarray, int]:
        """Best (window cost, disparity) of every left and every right pixel.

        Returns:
            The packed minima ``cost << shift | d`` for the left and the right view, and shift.
        """
        config = self._config
        height, width = codes_left[0].shape
        bits = len(self._pattern)
        area = config.aggregation_px * config.aggregation_px
        shift = max(1, (config.num_disparities - 1).bit_length())
        # 16-bit arithmetic is twice as fast; use it when the packed sums fit.
        fits16 = ((bits * area) << shift) + config.num_disparities < 1 << 16
        dtype, depth = (np.uint16, cv2.CV_16U) if fits16 else (np.int32, cv2.CV_32S)
        popcount = np.array([bin(i).count("1") << shift for i in range(256)], dtype=np.uint16)
        if not fits16:
            popcount = popcount.astype(np.int32)
        worst = bits << shift
        window = (config.aggregation_px, config.aggregation_px)
        cost = np.empty((height, width), dtype=popcount.dtype)
        packed = np.empty((height, width), dtype=dtype)
        best_left = np.full((height, width), np.iinfo(dtype).max, dtype=dtype)
        best_right = best_left.copy()
        for d in range(config.num_disparities):
            cost[:, :d] = worst  # the match would be left of the right image
            valid = cost[:, d:]
            for plane, (code_l, code_r) in enumerate(zip(codes_left, codes_right, strict=True)):
                diff = cv2.bitwise_xor(code_l[:, d:], code_r[:, : width - d])
                if plane == 0:
                    cv2.LUT(diff, popcount, dst=valid)
                else:
                    cv2.add(valid, cv2.LUT(diff, popcount), dst=valid)
            cv2.boxFilter(
                cost, depth, window, dst=packed, normalize=False, borderType=cv2.BORDER_REPLICATE
            )
            np.add(packed, dtype(d), out=packed)
            cv2.min(best_left, packed, dst=best_left)
            # The right pixel x - d sees the same window cost at disparity d.
            right_view = best_right[:, : width - d]
            cv2.min(right_view, packed[:, d:], dst=right_view)
        return best_left, best_right, shift
