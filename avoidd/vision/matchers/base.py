"""The matcher interface shared by every disparity algorithm."""

from __future__ import annotations

from typing import Protocol

from avoidd.types import BoolArray, FloatArray, Image


class Matcher(Protocol):
    """Computes the disparity of the left view of a rectified grey pair.

    ``last_filled`` marks pixels of the last result that the matcher filled rather than
    measured (the segment matcher's region interiors); None when every value was measured.
    ``last_unchecked`` marks, in the left border band (its first columns), readings dropped
    because the right view could not check them (see
    :func:`~avoidd.vision.matchers.border.confirm_band`); None when no band was checked.
    """

    last_filled: BoolArray | None
    last_unchecked: BoolArray | None

    @property
    def num_disparities(self) -> int:
        """Width of the disparity search range in pixels."""
        ...

    def compute(self, left: Image, right: Image) -> FloatArray:
        """Match a rectified grey pair.

        Args:
            left: Left (reference) view, (H, W) uint8.
            right: Right view, same shape.

        Returns:
            Disparity in pixels, float32 (H, W); NaN where no trustworthy match exists.
        """
        ...
