"""Stereo sections of a head: the matchers, pre- and post-processing, sectors and histogram."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import (
    AfterValidator,
    Discriminator,
    Field,
    Tag,
    field_validator,
    model_validator,
)

from avoidd.config.base import Strict, WholeNumber, _multiple_of_16, _odd

DisparityRange = Annotated[int, Field(ge=16, le=512), AfterValidator(_multiple_of_16)]
"""Width of a disparity search range: a multiple of 16 pixels."""


class SgbmConfig(Strict):
    """OpenCV semi-global matching; ``p1``/``p2`` default to 8 and 64 times block_size squared.

    ``pad_left`` matches the left border band (the first ``num_disparities`` columns, which
    OpenCV leaves unmatched) by padding both views with replicated columns; estimates whose match
    would fall in the padding are dropped. The band's disparities are less reliable (a near
    object there has no match in the right image), so obstacle detection never uses them; it
    still pays to pad, because SGBM's paths then reach the pixels right of the band with context
    (without it the rendered truth suite's p95 range error rose from 5.0 to 6.4%).
    The defaults (pad, uniqueness 5, P2 64 bs^2) were measured over Middlebury 2014 Q, 2003
    and 2001 together (README, "Stereo quality").

    Attributes:
        min_disparity: Smallest disparity searched (0 for a rectified rig with parallel axes).
        num_disparities: Width of the search range (multiple of 16); with the rig it sets the
            nearest measurable range f*B/(n-1).
        block_size: Odd matching window side.
        p1: Penalty for a disparity change of 1 between neighbours (null: 8 * block_size^2).
        p2: Penalty for larger changes (null: 64 * block_size^2; must exceed p1).
        uniqueness_ratio: Percent by which the best cost must beat the second best.
        speckle_window_size: Islands of similar disparity smaller than this are dropped (0: off).
        speckle_range: Largest disparity step inside one island.
        disp12_max_diff: Left-right check tolerance in pixels (-1: off).
        pre_filter_cap: Clip of the x-derivative prefilter.
        mode: OpenCV's SGBM mode: sgbm (5 paths), hh (8 paths, slow), sgbm_3way (fast), hh4.
        pad_left: Pad both views so the left border band is matched too (its
            disparities never reach obstacle detection).
    """

    kind: Literal["sgbm"] = "sgbm"
    min_disparity: int = Field(0, ge=-128, le=256)
    num_disparities: DisparityRange = 64
    block_size: Annotated[int, Field(ge=1, le=15), AfterValidator(_odd)] = 5
    p1: int | None = Field(None, gt=0, le=1_000_000)
    p2: int | None = Field(None, gt=0, le=1_000_000)
    uniqueness_ratio: int = Field(5, ge=0, le=100)
    speckle_window_size: int = Field(100, ge=0, le=1_000_000)
    speckle_range: int = Field(2, ge=0, le=1000)
    disp12_max_diff: int = Field(1, ge=-1, le=1000)
    pre_filter_cap: int = Field(63, ge=1, le=255)
    mode: Literal["sgbm", "hh", "sgbm_3way", "hh4"] = "sgbm_3way"
    pad_left: bool = True

    @model_validator(mode="after")
    def _p2_above_p1(self) -> SgbmConfig:
        if self.p1 is not None and self.p2 is not None and self.p2 <= self.p1:
            raise ValueError("p2 must be greater than p1 (p2 penalises large disparity jumps)")
        return self


class SadConfig(Strict):
    """SAD block matching (OpenCV StereoBM): the paper's first matcher.

    Attributes:
        block_size: Odd window side (5 to 51).
        texture_threshold: Minimum texture (sum of |x-derivative| over the window) to match.
        uniqueness_ratio: Percent by which the best cost must beat the second best.
        pre_filter: ``xsobel`` (OpenCV's default) or ``normalized_response``.
        pad_left: As for SGBM.
        num_disparities: Width of the search range (multiple of 16).
        speckle_window_size: As for SGBM.
        speckle_range: As for SGBM.
        disp12_max_diff: As for SGBM.
    """

    kind: Literal["sad"]
    num_disparities: DisparityRange = 64
    block_size: Annotated[int, Field(ge=5, le=51), AfterValidator(_odd)] = 11
    texture_threshold: int = Field(10, ge=0, le=1_000_000)
    uniqueness_ratio: int = Field(15, ge=0, le=100)
    speckle_window_size: int = Field(100, ge=0, le=1_000_000)
    speckle_range: int = Field(2, ge=0, le=1000)
    disp12_max_diff: int = Field(1, ge=-1, le=1000)
    pre_filter: Literal["xsobel", "normalized_response"] = "xsobel"
    pad_left: bool = False


class CensusConfig(Strict):
    """Census transform + sum of Hamming distances (the paper's SHD matcher).

    Attributes:
        pattern: ``sparse5x5`` (8 samples on a 5x5 ring) or ``full5x5`` (24 bits).
        aggregation_px: Side of the window the Hamming distances are summed over (11 in the
            paper).
        max_mean_distance: Drop a match whose mean Hamming distance per pixel exceeds this share
            of the code's bits.
        texture_window_px: Window of the texture test.
        min_texture_std: Minimum grey-level standard deviation in that window; flatter pixels
            are not matched (their census codes carry no information).
        lr_max_diff_px: Left-right check: the right view's match must point back within this.
        speckle_window_size: Islands of similar disparity smaller than this are dropped (0: off).
        num_disparities: Width of the search range (multiple of 16, up to 256).
    """

    kind: Literal["census"]
    num_disparities: Annotated[int, Field(ge=16, le=256), AfterValidator(_multiple_of_16)] = 64
    pattern: Literal["sparse5x5", "full5x5"] = "sparse5x5"
    aggregation_px: Annotated[int, Field(ge=3, le=31), AfterValidator(_odd)] = 11
    max_mean_distance: float = Field(0.35, gt=0.0, le=1.0)
    texture_window_px: Annotated[int, Field(ge=3, le=31), AfterValidator(_odd)] = 7
    min_texture_std: float = Field(1.0, ge=0.0)
    lr_max_diff_px: int = Field(1, ge=0, le=256)
    speckle_window_size: int = Field(100, ge=0, le=1_000_000)


class SegmentConfig(Strict):
    """The paper's segmentation-based hybrid matcher.

    Lightness (Lab L) is clustered by K-means on its histogram; each cluster is cleaned by a
    morphological opening and split into connected regions; SAD block matching is kept only on
    region boundaries; each region's interior is filled from its boundary disparities (a plane
    fitted to them). Interior pixels are filled, not measured: obstacles never use them.

    Attributes:
        clusters: K of the K-means on lightness.
        open_px: Side of the opening that removes thin fragments of a cluster (odd; 1 = off).
        min_region_px: Regions smaller than this are not filled; their pixels keep the SAD value.
        boundary_px: Width of the boundary band on each side of a region edge.
        block_size: SAD window side (odd).
        texture_threshold: As for ``sad``.
        uniqueness_ratio: As for ``sad``.
        min_boundary_px: Boundary measurements a region needs before its interior is filled.
        max_residual_px: A region is filled only if its boundary disparities fit a plane this
            well (median absolute residual); otherwise it spans a depth edge and stays empty.
        pad_left: As for SGBM.
        num_disparities: Width of the search range (multiple of 16).
    """

    kind: Literal["segment"]
    num_disparities: DisparityRange = 64
    clusters: int = Field(8, ge=2, le=16)
    open_px: Annotated[int, Field(ge=1, le=15), AfterValidator(_odd)] = 3
    min_region_px: int = Field(64, ge=1, le=10_000_000)
    boundary_px: int = Field(2, ge=1, le=8)
    block_size: Annotated[int, Field(ge=5, le=51), AfterValidator(_odd)] = 9
    texture_threshold: int = Field(10, ge=0, le=1_000_000)
    uniqueness_ratio: int = Field(15, ge=0, le=100)
    min_boundary_px: int = Field(12, ge=3, le=10_000_000)
    max_residual_px: float = Field(1.0, gt=0.0)
    pad_left: bool = True


def _matcher_kind(value: object) -> str:
    if isinstance(value, dict):
        return str(value.get("kind", "sgbm"))
    return str(getattr(value, "kind", "sgbm"))


MatcherConfig = Annotated[
    Annotated[SgbmConfig, Tag("sgbm")]
    | Annotated[SadConfig, Tag("sad")]
    | Annotated[CensusConfig, Tag("census")]
    | Annotated[SegmentConfig, Tag("segment")],
    Discriminator(_matcher_kind),
]
"""The ``matcher`` section of a head: one of the matchers, chosen by ``kind``."""


class SectorsConfig(Strict):
    """How a head's obstacle points become the 72 distance bins.

    Attributes:
        min_pixels: Points a bin's nearest cluster needs before it counts as an obstacle, so that
            a few speckles cannot create one.
        cluster_window_px: Width of that cluster in disparity pixels (about the matcher's noise
            band; see ``avoidd.perception.sectors.nearest_cluster``).
        min_valid_fraction: Below this share of measured pixels a bin without an obstacle is
            unknown rather than clear.
        min_free_fraction: A bin without an obstacle is clear only when at least this share of
            its pixels show free space out to the maximum range (measured beyond it, with the
            ray inside the height band all the way); else it is unknown.
        max_unresolved_fraction: A bin without an obstacle is clear only when at most this
            share of its pixels are textured but unmeasured (occluded, nearer than any search
            range, too oblique to match): something may stand there.
        min_size_m: A cluster must also cover a square of this side at its own distance (so
            near clusters need many pixels, and pixels smeared off an edge cannot pass for an
            object). The default is the smallest obstacle avoidd must see: a 5 cm pole.
        unseen_patch_m: A bin without an obstacle is never clear while its view holds an
            unmeasured patch at least this wide and tall at the maximum range (and at least
            3 x 3 pixels), among the rays at or above the level that are still inside the
            height band at the maximum range (any surface in the band that reaches the
            camera's height meets them). Such a patch may be a surface too plain to match;
            smaller ones are noise.
    """

    min_pixels: int = Field(20, ge=1)
    cluster_window_px: float = Field(0.8, gt=0.0, le=16.0)
    min_valid_fraction: float = Field(0.3, ge=0.0, le=1.0)
    min_free_fraction: float = Field(0.05, ge=0.0, le=1.0)
    max_unresolved_fraction: float = Field(0.1, ge=0.0, le=1.0)
    min_size_m: float = Field(0.05, ge=0.0, le=1.0)
    unseen_patch_m: float = Field(0.3, gt=0.0, le=10.0)

    @model_validator(mode="before")
    @classmethod
    def _no_row_band(cls, data: object) -> object:
        if isinstance(data, dict) and "row_band" in data:
            raise ValueError(
                "row_band is gone: obstacles are now points between the ground and the "
                "height band of 'perception' (ground.margin_m, band.above_m, band.below_m); "
                "delete row_band"
            )
        return data


class NearFieldConfig(Strict):
    """The near-field pass (see ``avoidd.vision.nearfield``).

    A second, coarse SGBM pass on both views shrunk by ``scale`` searches ``scale`` times
    farther than its ``num_disparities``: objects nearer than the main matcher's range are
    measured there instead of reading farther than they are, and the head's minimum range
    becomes ``f B / ((num_disparities - 1) * scale)``.

    Attributes:
        enabled: Run the pass (off only for benchmarks and comparisons: without it an object
            nearer than the main range can read far).
        scale: Shrink factor of the coarse pass (2 or 4).
        num_disparities: Search range of the coarse pass in its own (shrunk) pixels.
        block_size: SGBM block size of the coarse pass (odd).
    """

    enabled: bool = True
    scale: Annotated[Literal[2, 4], WholeNumber] = 4
    num_disparities: DisparityRange = 64
    block_size: Annotated[int, Field(ge=3, le=11), AfterValidator(_odd)] = 5


class TextureConfig(Strict):
    """The paper's adaptive-threshold texture mask.

    A pixel is textured when it differs from the mean (or median) of its ``window_px`` window by
    at least ``offset`` grey levels, or has such a pixel within ``spread_px``; disparities of
    untextured pixels are dropped rather than guessed.

    Attributes:
        method: Local reference: ``mean`` or ``median`` of the window.
        window_px: Odd side of that window.
        offset: Grey levels a pixel must differ from the reference to count as texture.
        spread_px: Odd side of the neighbourhood over which texture is spread.
    """

    method: Literal["mean", "median"] = "mean"
    window_px: Annotated[int, Field(ge=3, le=31), AfterValidator(_odd)] = 7
    offset: float = Field(2.0, ge=0.0, le=255.0)
    spread_px: Annotated[int, Field(ge=1, le=31), AfterValidator(_odd)] = 5


class PreprocessConfig(Strict):
    """Image preparation before matching, as the paper has it; every step off unless asked.

    Attributes:
        resize_scale: Scale both views (and the rig) by this factor before matching (1: off).
        median_px: Median denoise window (0: off; 3, 5 or 7).
        mean_px: Mean (box) denoise window (0: off; odd).
        texture: Adaptive-threshold texture mask (None: off).
    """

    resize_scale: float = Field(1.0, ge=0.25, le=1.0)
    median_px: Annotated[Literal[0, 3, 5, 7], WholeNumber] = 0
    mean_px: Annotated[int, Field(ge=0, le=15)] = 0
    texture: TextureConfig | None = None

    @field_validator("mean_px")
    @classmethod
    def _mean_window(cls, value: int) -> int:
        if value and value % 2 == 0:
            raise ValueError(f"must be 0 or odd; use {value + 1}")
        return value


class PostprocessConfig(Strict):
    """Disparity post-processing after any matcher.

    Attributes:
        subpixel_refine: One Gauss-Newton step along the epipolar line after the matcher
            (off by default: SGBM and SAD interpolate to 1/16 px themselves, and on the
            Middlebury scenes the extra step raises their sub-pixel error; see the README).
        refine_window_px: Window of that step (odd).
        median_size: Median filter on the disparity over each window's measured pixels (0 off,
            3 or 5).
        speckle_window_px: An extra speckle pass after the median: islands smaller than this
            are dropped (0 off; every matcher already removes speckles in its own step).
        speckle_range_px: Disparity step that separates islands in that pass.
        fill_holes: Also produce a hole-filled depth map (``filled_depth_m``, for display and
            recordings). Obstacles never use it: they see measured pixels only.
        min_texture_snr: Drop disparities where the left view's local contrast (standard
            deviation over ``texture_window_px``) is below this multiple of the frame's
            sensor noise: a match in sky or on a blank wall is a guess (0: off).
        texture_window_px: Window of that test (odd).
        edge_radius_px: Check for foreground fattening this far from each depth edge (see
            ``avoidd.vision.edges``): a pixel there keeps the near disparity only if its own
            grey level matches the right view better at it than at the far one (0: off).
        edge_jump_px: Smallest disparity step that counts as a depth edge.
    """

    subpixel_refine: bool = False
    refine_window_px: int = Field(7, ge=3, le=21)
    median_size: Annotated[Literal[0, 3, 5], WholeNumber] = 5
    speckle_window_px: int = Field(0, ge=0, le=1_000_000)
    speckle_range_px: float = Field(1.0, gt=0.0)
    fill_holes: bool = False
    min_texture_snr: float = Field(1.5, ge=0.0, le=20.0)
    texture_window_px: Annotated[int, Field(ge=3, le=31), AfterValidator(_odd)] = 7
    edge_radius_px: int = Field(8, ge=0, le=16)
    edge_jump_px: float = Field(2.0, gt=0.0, le=64.0)

    @field_validator("refine_window_px")
    @classmethod
    def _odd_window(cls, value: int) -> int:
        if value % 2 == 0:
            raise ValueError(f"must be odd; use {value + 1}")
        return value


class HistogramConfig(Strict):
    """The per-frame depth histogram (linearly spaced edges from ``min_m`` to ``max_m``).

    Attributes:
        min_m: Lower edge of the first bin.
        max_m: Upper edge of the last bin.
        bins: Number of bins.
    """

    min_m: float = Field(0.0, ge=0.0)
    max_m: float = Field(20.0, gt=0.0, le=1000.0)
    bins: int = Field(40, ge=1, le=1000)

    @model_validator(mode="after")
    def _range(self) -> HistogramConfig:
        if self.max_m <= self.min_m:
            raise ValueError("max_m must be greater than min_m")
        return self
