"""The near field: obstacles nearer than the main matcher's search range can reach.

An object nearer than ``f*B/(D-1)`` has a disparity above the main matcher's range ``D``. The
matcher then returns a wrong, smaller disparity, and the object reads farther than it is (a
wall at 0.3 m read at 2.4 m, and at 16 m in one bin). A second, coarse pass on both views
shrunk by ``scale`` searches ``scale`` times farther for a sixteenth of the cost (at scale 4).
Where it sees something beyond the main range, its disparity replaces the main one, and
where it is at the end of its own range the object may be nearer still, so it is put at the
coarse pass's limit: read at the rig's minimum range, never farther.

The coarse pass guesses in featureless places as the main matcher does (a few rows of open
sky read nearer than the main range in about one rendered scene in twenty), and a near guess
there would blank the whole left band of the image (below). Its candidates therefore pass the
same texture test the main map does (:func:`avoidd.vision.postprocess.texture_gate`), only in
frames where it found any: a featureless pixel is dropped from the merged map anyway. And a
candidate must belong to a patch at least two coarse pixels across.

Two more things follow from the geometry (:func:`unseen_behind`). A near surface hides from
the right camera what lies just left of it in the left view, and the main matcher, whose own
consistency check cannot work beyond its range, fills that shadow with guesses (the
background beside a box at 0.3 m read at 2.4 m). And in a row where a surface at disparity
``d`` was found, the same surface continued left of column ``d`` would be outside the right
camera's view. Neither place can be vouched for, so both are dropped (as the main matcher's
own left band is).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import cv2
import numpy as np

from avoidd.config import NearFieldConfig, PostprocessConfig, SgbmConfig
from avoidd.types import BoolArray, FloatArray, Image, RectifiedRig
from avoidd.vision.edges import row_suffix_min
from avoidd.vision.matchers.sgbm import SgbmMatcher
from avoidd.vision.postprocess import texture_gate


@dataclass(frozen=True)
class NearFieldResult:
    """The near-field pass's verdict on one frame.

    Attributes:
        disparity: The merged disparity (full resolution, NaN invalid).
        near: Pixels whose disparity came from the coarse pass.
        saturated_pixels: Pixels at the end of the coarse range (read at the minimum range).
        blanked_pixels: Pixels dropped because a near surface could hide there unseen.
        texture_gate: The left view's texture gate (:func:`~avoidd.vision.postprocess.texture_gate`
            with the post-processing's window and threshold), when the pass computed it (only
            when the coarse pass saw something near): post-processing can take it as it is.
    """

    disparity: FloatArray
    near: BoolArray
    saturated_pixels: int
    blanked_pixels: int
    texture_gate: BoolArray | None = None

    @property
    def near_pixels(self) -> int:
        """How many pixels the coarse pass measured."""
        return int(np.count_nonzero(self.near))


def min_range_m(rig: RectifiedRig, main_disparities: int, config: NearFieldConfig) -> float:
    """Nearest range a head measures: its main range, or the near-field pass's when on.

    Args:
        rig: The rig of the images the matcher sees.
        main_disparities: Search range of the main matcher.
        config: The near-field pass.
    """
    top_px = (config.num_disparities - 1) * config.scale if config.enabled else 0
    return rig.fx * rig.baseline_m / max(main_disparities - 1, top_px, 1)


class NearField:
    """Runs the coarse pass and merges it into the main disparity map.

    Args:
        main_disparities: Search range ``D`` of the head's main matcher.
        config: Scale, range and block size of the coarse pass.
        texture: The head's ``postprocess`` section, whose texture test the coarse pass's
            candidates must pass (none: every candidate is kept).
    """

    def __init__(
        self,
        main_disparities: int,
        config: NearFieldConfig,
        texture: PostprocessConfig | None = None,
    ) -> None:
        self.main_disparities = main_disparities
        self._texture = texture
        self.scale = config.scale
        self.num_disparities = config.num_disparities
        self._coarse = SgbmMatcher(
            SgbmConfig(
                num_disparities=config.num_disparities,
                block_size=config.block_size,
                pad_left=True,
            ),
            # Only readings nearer than the main range are taken from this map: there an
            # unconfirmed band reading errs on the near side, and dropping it would not.
            confirm=False,
        )

    @property
    def max_disparity_px(self) -> float:
        """Largest full-resolution disparity the coarse pass can measure."""
        return float((self.num_disparities - 1) * self.scale)

    def min_range_m(self, focal_baseline: float) -> float:
        """Nearest range the head can measure with this pass, for ``f*B`` in pixel metres."""
        return focal_baseline / self.max_disparity_px

    def coarse(self, left: Image, right: Image) -> FloatArray:
        """The coarse pass's disparity, in full-resolution pixels and at full resolution."""
        height, width = left.shape[:2]
        size = (max(width // self.scale, 1), max(height // self.scale, 1))
        small_left = np.asarray(cv2.resize(left, size, interpolation=cv2.INTER_AREA), np.uint8)
        small_right = np.asarray(cv2.resize(right, size, interpolation=cv2.INTER_AREA), np.uint8)
        disparity = self._coarse.compute(small_left, small_right) * np.float32(self.scale)
        # Nearest neighbour: a depth edge must not blend a near and a far surface.
        full = cv2.resize(disparity, (width, height), interpolation=cv2.INTER_NEAREST)
        return np.asarray(full, dtype=np.float32)

    def merge(self, main: FloatArray, coarse: FloatArray) -> NearFieldResult:
        """Merge a coarse map (:meth:`coarse`) into the main matcher's map.

        Args:
            main: The main disparity map (NaN invalid); it is not modified.
            coarse: The coarse map in full-resolution pixels.

        Returns:
            The merged map and what the pass found.
        """
        merged = main.copy()
        # The coarse pass is trusted only beyond the main range (less a coarse pixel's worth
        # for its rounding): there the main matcher cannot be right.
        threshold = np.float32(self.main_disparities - 1 - self.scale)
        with np.errstate(invalid="ignore"):
            near = coarse >= threshold
            saturated = coarse >= np.float32(self.max_disparity_px - self.scale)
        np.copyto(merged, coarse, where=near)
        np.copyto(merged, np.float32(self.max_disparity_px), where=saturated)
        hidden = unseen_behind(merged, near)
        blanked = int(np.count_nonzero(hidden & ~np.isnan(merged)))
        merged[hidden] = np.nan
        return NearFieldResult(merged, near, int(np.count_nonzero(saturated)), blanked)

    def apply(self, left: Image, right: Image, main: FloatArray) -> NearFieldResult:
        """Run the coarse pass on a rectified grey pair and merge it into ``main``."""
        coarse = self.coarse(left, right)
        threshold = np.float32(self.main_disparities - 1 - self.scale)
        with np.errstate(invalid="ignore"):
            candidates = coarse >= threshold
        if not candidates.any():
            return self.merge(main, coarse)
        texture = self._texture
        found = candidates
        gate = None
        if texture is not None and texture.min_texture_snr > 0:
            gate = texture_gate(left, texture.texture_window_px, texture.min_texture_snr)
            candidates = candidates & gate
        # At least two coarse pixels each way: a lone coarse pixel is a guess, not a surface
        # (at the near range an object of the smallest size covers dozens).
        side = 2 * self.scale - 1  # odd: the opening keeps a patch in place
        kept = cv2.morphologyEx(
            candidates.view(np.uint8), cv2.MORPH_OPEN, np.ones((side, side), np.uint8)
        )
        coarse[found & (kept == 0)] = np.nan
        return dataclasses.replace(self.merge(main, coarse), texture_gate=gate)


def unseen_behind(disparity: FloatArray, near: BoolArray) -> BoolArray:
    """Pixels the right camera cannot see because of the near surfaces in view.

    A near pixel at column ``u`` with disparity ``d`` covers, in the right view, what the left
    view shows in columns ``[u - d, u)`` of its row behind it. And a near surface could go on,
    unseen by the right camera, anywhere left of column ``d``: in any row, since objects
    extend up and down beyond where the coarse pass happened to match them (a box at 0.3 m
    matched in a few rows only read 5.9 m in the rows between). Near pixels themselves are not
    in the result.

    Args:
        disparity: Disparity map (full resolution).
        near: Near-field pixels of that map.

    Returns:
        The pixels to drop.
    """
    hidden = np.zeros(near.shape, dtype=np.bool_)
    rows = np.flatnonzero(near.any(axis=1))
    if rows.size == 0:
        return hidden
    width = near.shape[1]
    columns = np.arange(width, dtype=np.float32)[None, :]
    near_rows = near[rows]
    reach = np.where(near_rows, disparity[rows], np.float32(0.0))
    # Shadow: column c is covered when some near pixel u >= c has u - d(u) <= c.
    start = np.where(near_rows, columns - reach, np.float32(np.inf))
    covered_from = row_suffix_min(start, np.empty_like(start))
    hidden[rows] = covered_from <= columns
    hidden[:, : int(np.ceil(float(reach.max())))] = True
    hidden &= ~near
    return hidden
