"""Frames a camera delivers that carry no news: the same image again (frozen) or blind ones.

A frozen camera (a driver that hands back its last buffer, a USB camera whose sensor stopped)
delivers the same image again with a new timestamp; a blind one (lens cap, exposure failure,
the sun) delivers images whose every pixel is clipped black or white. Neither says anything
about the world now: processing them would send old or invented data as fresh. Such frames are
dropped, so the head goes stale and the daemon says so (HEARTBEAT CRITICAL, STATUSTEXT) with
the reason this module names.

A real sensor's noise makes two consecutive images differ, so even one repeat is dropped; the
camera is called frozen, in one log line, once the repeats run to :data:`FROZEN_AFTER`.
"""

from __future__ import annotations

import logging

import numpy as np

from avoidd.types import Image, StereoFrame

logger = logging.getLogger(__name__)

FROZEN_AFTER = 3
"""This many repeats of one image in a row and the camera is reported frozen."""
BLIND_AFTER = 3
"""This many blind frames in a row and the camera is reported blind."""
BLIND_FRACTION = 0.98
"""A view is blind when at least this share of its (sampled) pixels is clipped."""
DARK_LEVEL = 8
"""Grey levels at or below this are clipped black."""
BRIGHT_LEVEL = 247
"""Grey levels at or above this are clipped white."""
_STEP_PX = 8
"""Every this many pixels along each axis are sampled (cheap: about 1/64 of the image)."""


def _sample(image: Image) -> Image:
    """A sparse, contiguous sample of an image (all channels), for cheap comparisons."""
    return np.ascontiguousarray(image[::_STEP_PX, ::_STEP_PX])


def blind_view(image: Image) -> str | None:
    """Whether one view is blind: "black", "saturated", or None when it shows something.

    Args:
        image: The view (or a sample of it), 8-bit grey or colour.

    Returns:
        What the clipped pixels are when nearly all of them are, else None.
    """
    size = image.size
    if size == 0:
        return None
    dark = np.count_nonzero(image <= DARK_LEVEL) / size
    bright = np.count_nonzero(image >= BRIGHT_LEVEL) / size
    if dark + bright < BLIND_FRACTION:
        return None
    return "black" if dark >= bright else "saturated"


class FrameCheck:
    """Drops frames that carry no news and logs each fault once per run of it.

    Args:
        head: The head's name, for messages.
        repeats: Whether a repeated image is a fault (not for the synthetic camera, whose
            still scene without noise repeats on purpose).

    Attributes:
        repeated: Frames dropped as a repeat of the one before.
        blind: Frames dropped as blind.
    """

    def __init__(self, head: str, repeats: bool = True) -> None:
        self._head = head
        self._check_repeats = repeats
        self._previous: tuple[Image, Image] | None = None
        self._repeats = 0
        self._blind_in_row = 0
        self.repeated = 0
        self.blind = 0
        self.fault: str | None = None
        """What is wrong while it lasts ("camera frozen", "camera blind"), else None."""

    def usable(self, frame: StereoFrame) -> bool:
        """Whether a frame is news; a frame that is not is counted and must be dropped.

        Blindness is checked first: a clipped image repeats exactly, and "blind" says more.
        """
        sample = (_sample(frame.left), _sample(frame.right))
        previous, self._previous = self._previous, sample
        clipped = [
            (view, what)
            for view, image in zip(("left", "right"), sample, strict=True)
            if (what := blind_view(image))
        ]
        if clipped:
            self.blind += 1
            self._blind_in_row += 1
            if self._blind_in_row == BLIND_AFTER:
                self.fault = "camera blind"
                view, what = clipped[0]
                logger.error(
                    "head '%s': camera blind: the %s view is %s (%d frames in a row); its frames "
                    "are dropped until it shows something (lens cap? exposure?)",
                    self._head,
                    view,
                    what,
                    self._blind_in_row,
                )
            return False
        if self._blind_in_row:
            if self._blind_in_row >= BLIND_AFTER:
                logger.warning(
                    "head '%s': camera sees again after %d blind frames",
                    self._head,
                    self._blind_in_row,
                )
                self.fault = None
            self._blind_in_row = 0
        if (
            self._check_repeats
            and previous is not None
            and all(
                a.shape == b.shape and np.array_equal(a, b)
                for a, b in zip(sample, previous, strict=True)
            )
        ):
            self.repeated += 1
            self._repeats += 1
            if self._repeats == FROZEN_AFTER:
                self.fault = "camera frozen"
                logger.error(
                    "head '%s': camera frozen: the same image %d times in a row; its frames "
                    "are dropped until the image changes (check the camera and its cable)",
                    self._head,
                    self._repeats + 1,
                )
            return False
        if self._repeats:
            if self._repeats >= FROZEN_AFTER:
                logger.warning(
                    "head '%s': camera no longer frozen after %d repeated frames",
                    self._head,
                    self._repeats,
                )
                self.fault = None
            self._repeats = 0
        return True
