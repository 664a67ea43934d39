"""Shading of rendered surfaces: the texture pattern, each surface's texture level, the light.

Texture is looked up rather than computed: one periodic, band-limited noise pattern (a ``1/f``
spectrum, like bark, concrete or grass from afar) is prepared once as a mip pyramid built in
the frequency domain, so every level is exactly periodic and free of aliasing. Each surface
shows it at its own offset, in its own coordinates in metres; each pixel reads the two levels
around its footprint on the surface (trilinear, through ``cv2.remap``), so both views see the
same pattern at every distance, as a real camera sees a real surface.

A surface's texture level (:data:`~avoidd.config.sim_world.TextureLevel`) says how much of
the pattern it shows: all of it, a tenth of its contrast (``low``), all of it in patches
``PATCH_M`` across with a flat shade between (``partial``), or one flat shade (``flat``). The
pipeline's texture gate must cope with the poor ones.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from avoidd.config.sim_world import TextureLevel
from avoidd.types import FloatArray, Image

AnyFloat = npt.NDArray[np.floating[Any]]
AnyArray = npt.NDArray[Any]

SKY_ID = 0
TEXEL_M = 0.004
"""Size of one texel of the finest level."""
LOW_CONTRAST = 0.1
"""The share of the pattern's contrast a ``low`` surface shows."""
PATCH_M = 1.5
"""Size of the textured and the flat patches of a ``partial`` surface."""
_TEXTURE_SIZE = 2048
_REMAP_ROW = 1024


@functools.lru_cache(maxsize=1)
def texture_pyramid() -> tuple[npt.NDArray[np.float32], ...]:
    """The noise pattern's mip levels, finest first, values around 0.5 (periodic in both axes).

    Level ``k`` holds the spectrum's lowest ``size / 2**k`` frequencies, so sampling it where a
    pixel covers ``2**k`` texels shows nothing finer than the pixel.
    """
    size = _TEXTURE_SIZE
    rng = np.random.default_rng(20260101)
    fy = np.fft.fftfreq(size)[:, None]
    fx = np.fft.fftfreq(size)[None, :]
    radius = np.hypot(fx, fy)
    amplitude = np.where(radius > 0, 1.0 / np.maximum(radius, 1.0 / size), 0.0)
    spectrum = amplitude * np.exp(2j * np.pi * rng.random((size, size)))
    levels: list[npt.NDArray[np.float32]] = []
    scale = 0.0
    n = size
    while n >= 8:
        half = n // 2
        # The lowest n x n frequencies (fft order: positive first, then negative).
        keep = np.concatenate([np.arange(half), np.arange(size - half, size)])
        block = spectrum[np.ix_(keep, keep)]
        pattern = np.real(np.fft.ifft2(block)) * (n * n) / (size * size)
        if not levels:
            scale = 0.22 / float(np.std(pattern))
        levels.append(np.asarray(0.5 + scale * pattern, dtype=np.float32))
        n //= 2
    return tuple(levels)


class Hits:
    """Per-pixel nearest hit so far: depth, surface, surface coordinates, shading terms."""

    def __init__(self, shape: tuple[int, int]) -> None:
        self.t = np.full(shape, np.inf, dtype=np.float32)
        self.ids = np.zeros(shape, dtype=np.int16)
        self.s = np.zeros(shape, dtype=np.float32)
        self.u = np.zeros(shape, dtype=np.float32)
        self.cos = np.ones(shape, dtype=np.float32)
        self.light = np.ones(shape, dtype=np.float32)

    def offer(
        self,
        window: tuple[slice, slice],
        t: AnyFloat,
        surface_id: int,
        s: AnyFloat,
        u: AnyFloat,
        cos: AnyFloat,
        light: AnyFloat | float,
    ) -> None:
        """Keep the offered hits (``inf`` where none) that are nearer than what is there."""
        nearer = t < self.t[window]
        if not nearer.any():
            return
        # copyto with a mask writes in one pass (indexing by the mask would gather first).
        np.copyto(self.t[window], t, where=nearer)
        np.copyto(self.ids[window], np.int16(surface_id), where=nearer)
        np.copyto(self.s[window], s, where=nearer)
        np.copyto(self.u[window], u, where=nearer)
        np.copyto(self.cos[window], cos, where=nearer)
        np.copyto(self.light[window], light, where=nearer)


@dataclass(frozen=True)
class SurfaceTable:
    """Per surface id: offset of its texture (texels), albedo, and its texture level.

    Attributes:
        offset_x: Where its texture starts, texels.
        offset_y: Where its texture starts, texels.
        albedo: How bright it is.
        flat: 1 where it is one flat shade.
        contrast: The share of the pattern's contrast it shows.
        partial: 1 where it is textured in patches only.
    """

    offset_x: npt.NDArray[np.float32]
    offset_y: npt.NDArray[np.float32]
    albedo: npt.NDArray[np.float32]
    flat: npt.NDArray[np.uint8]
    contrast: npt.NDArray[np.float32]
    partial: npt.NDArray[np.uint8]

    @classmethod
    def of(
        cls, rng: np.random.Generator, albedo: FloatArray, levels: Sequence[TextureLevel]
    ) -> SurfaceTable:
        """The table of surfaces with these albedos and levels; their offsets drawn from ``rng``."""
        count = len(levels)
        return cls(
            offset_x=rng.uniform(0, _TEXTURE_SIZE, count).astype(np.float32),
            offset_y=rng.uniform(0, _TEXTURE_SIZE, count).astype(np.float32),
            albedo=albedo.astype(np.float32),
            flat=np.array([level == "flat" for level in levels], np.uint8),
            contrast=np.array(
                [LOW_CONTRAST if level == "low" else 1.0 for level in levels], np.float32
            ),
            partial=np.array([level == "partial" for level in levels], np.uint8),
        )


class Shader:
    """Turns a view's nearest hits into grey levels.

    Args:
        table: The surfaces.
        fx_px: The camera's focal length (a pixel's footprint on a surface).
    """

    def __init__(self, table: SurfaceTable, fx_px: float) -> None:
        self.table = table
        self.fx = fx_px
        self._levels = texture_pyramid()
        self._low = bool((table.contrast != 1.0).any())
        self._partial = bool(table.partial.any())

    def shade(
        self, hits: Hits, rays: FloatArray, ray_length: FloatArray, noise: FloatArray | None
    ) -> Image:
        """The view's grey levels: texture by level, light, sky, sensor noise."""
        ids = hits.ids
        gather = self._gatherer(ids)
        surfaces = self.table
        # Every pixel is computed as if textured (sky and flat ones are overwritten after):
        # whole-image arithmetic is cheaper than selecting the pixels first.
        distance = hits.t * ray_length
        with np.errstate(invalid="ignore", over="ignore"):
            footprint_texels = distance / np.float32(self.fx * TEXEL_M)
            footprint_texels /= np.sqrt(np.maximum(hits.cos, np.float32(0.02)))
        top = np.float32(len(self._levels) - 1.001)
        lod = np.log2(np.clip(footprint_texels, 1.0, 2.0**top))
        x = _wrap(hits.s * np.float32(1.0 / TEXEL_M) + gather(surfaces.offset_x))
        y = _wrap(hits.u * np.float32(1.0 / TEXEL_M) + gather(surfaces.offset_y))
        pattern = self._sample(x, y, lod)
        if self._low:
            half = np.float32(0.5)
            pattern = half + gather(surfaces.contrast) * (pattern - half)
        lit = gather(surfaces.albedo) * hits.light
        value = lit * (0.35 + 1.3 * pattern)
        flat = gather(surfaces.flat) != 0
        if self._partial:
            cells = np.floor(hits.s * np.float32(1.0 / PATCH_M))
            cells += np.floor(hits.u * np.float32(1.0 / PATCH_M))
            flat |= (gather(surfaces.partial) != 0) & (np.remainder(cells, 2.0) == 1.0)
        value = np.where(flat, 0.8 * lit, value)
        sky = ids == SKY_ID
        value = np.where(sky, 0.78 - 0.15 * rays[..., 2] / ray_length, value)
        scaled = value * np.float32(255.0)
        if noise is not None:
            scaled += noise
        return np.asarray(np.clip(np.rint(scaled), 0, 255), dtype=np.uint8)

    def _gatherer(self, ids: npt.NDArray[np.int16]) -> Callable[[AnyArray], AnyArray]:
        """Per-pixel lookup of a per-surface table by the pixels' surface ids.

        With at most 256 surfaces the ids fit a byte and OpenCV's table lookup does it (a
        fraction of NumPy's indexing by an int16 array); otherwise NumPy indexes.
        """
        if len(self.table.albedo) > 256:
            return lambda table: np.asarray(table[ids])
        small = ids.astype(np.uint8)

        def lookup(table: AnyArray) -> AnyArray:
            padded = np.zeros(256, dtype=table.dtype)
            padded[: len(table)] = table
            return np.asarray(cv2.LUT(small, padded))

        return lookup

    def _sample(self, x: FloatArray, y: FloatArray, lod: FloatArray) -> FloatArray:
        """Trilinear lookup of the pattern at texel coordinates (finest level) and a level."""
        shape = x.shape
        base = np.floor(lod).astype(np.int8).ravel()
        # One stable (radix) sort puts each level's pixels together.
        order = np.argsort(base, kind="stable")
        counts = np.bincount(base, minlength=len(self._levels))
        xs, ys = x.ravel()[order], y.ravel()[order]
        frac = (lod.ravel() - base)[order].astype(np.float32)
        sorted_out = np.empty(xs.shape, dtype=np.float32)
        start = 0
        for level, count in enumerate(counts.tolist()):
            if not count:
                continue
            part = slice(start, start + count)
            fine = self._lookup(level, xs[part], ys[part])
            coarse = self._lookup(level + 1, xs[part], ys[part])
            w = frac[part]
            sorted_out[part] = fine + (coarse - fine) * w
            start += count
        out = np.empty(xs.shape, dtype=np.float32)
        out[order] = sorted_out
        return out.reshape(shape)

    def _lookup(self, level: int, x: FloatArray, y: FloatArray) -> FloatArray:
        image = self._levels[level]
        scale = np.float32(0.5**level)
        count = x.size
        # remap wants a 2-D map under 32767 on a side: lay the points out in rows.
        rows = -(-count // _REMAP_ROW)
        map_x = np.zeros(rows * _REMAP_ROW, dtype=np.float32)
        map_y = np.zeros(rows * _REMAP_ROW, dtype=np.float32)
        np.multiply(x, scale, out=map_x[:count])
        np.multiply(y, scale, out=map_y[:count])
        sampled = cv2.remap(
            image,
            map_x.reshape(rows, _REMAP_ROW),
            map_y.reshape(rows, _REMAP_ROW),
            cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_WRAP,
        )
        return np.asarray(sampled, dtype=np.float32).ravel()[:count]


def _wrap(texels: FloatArray) -> FloatArray:
    """Texel coordinates brought into one period of the pattern.

    remap's fixed point needs coordinates below 32767; its border wrap then handles the last
    texel.
    """
    period = np.float32(_TEXTURE_SIZE)
    return np.asarray(texels - period * np.floor(texels * (1.0 / period)), dtype=np.float32)
