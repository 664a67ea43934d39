"""Procedural surface texture: multi-octave value noise in metres, band-limited to the pixel.

Defined on a surface's own coordinates (metres), the same point gets the same value in every
view, and octaves finer than two pixel footprints fade out, so nothing aliases between views.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from avoidd.types import FloatArray

_OCTAVE_BASE_M = 0.015
_OCTAVES = 10


def _hash01(i: npt.NDArray[np.int64], j: npt.NDArray[np.int64], salt: int) -> FloatArray:
    """Integer lattice hash to [0, 1) (no period within any practical scene)."""
    mask = np.uint64(0xFFFFFFFF)
    h = (i.astype(np.uint64) * np.uint64(0x9E3779B1)) ^ (
        j.astype(np.uint64) * np.uint64(0x85EBCA77)
    )
    h = (h ^ np.uint64((salt * 0xC2B2AE3D) & 0xFFFFFFFF)) & mask
    h ^= h >> np.uint64(15)
    h = (h * np.uint64(0x2C1B3C6D)) & mask
    h ^= h >> np.uint64(12)
    h = (h * np.uint64(0x297A2D39)) & mask
    h ^= h >> np.uint64(15)
    return (h.astype(np.float32) * np.float32(1.0 / 4294967296.0)).astype(np.float32)


def _value_noise(s: FloatArray, u: FloatArray, salt: int) -> FloatArray:
    fs = np.floor(s)
    fu = np.floor(u)
    i = fs.astype(np.int64)
    j = fu.astype(np.int64)
    a = s - fs
    b = u - fu
    a = a * a * (3.0 - 2.0 * a)
    b = b * b * (3.0 - 2.0 * b)
    top = _hash01(i, j, salt) * (1 - a) + _hash01(i + 1, j, salt) * a
    bottom = _hash01(i, j + 1, salt) * (1 - a) + _hash01(i + 1, j + 1, salt) * a
    return (top * (1 - b) + bottom * b).astype(np.float32)


def surface_texture(s: FloatArray, u: FloatArray, footprint_m: FloatArray, salt: int) -> FloatArray:
    """Multi-octave value noise in [0, 1]; octaves finer than two pixel footprints fade out.

    Args:
        s: First surface coordinate in metres.
        u: Second surface coordinate in metres.
        footprint_m: Size of the pixel on the surface in metres.
        salt: Texture seed (differs per surface).

    Returns:
        Texture value per point.
    """
    total = np.zeros_like(s)
    weight = np.zeros_like(s)
    for octave in range(_OCTAVES):
        wavelength = _OCTAVE_BASE_M * (2.0**octave)
        fade = np.clip(wavelength / np.maximum(footprint_m, 1e-6) - 1.0, 0.0, 1.0)
        active = fade > 0
        if not active.any():
            continue
        noise = _value_noise(
            s[active] / np.float32(wavelength) + np.float32(octave * 17.3),
            u[active] / np.float32(wavelength) - np.float32(octave * 5.1),
            salt * 31 + octave,
        )
        total[active] += fade[active] * (noise - 0.5)
        weight[active] += fade[active] * fade[active]
    # Independent octaves add in variance: normalising by the root of the summed squared
    # weights keeps the contrast the same however many octaves the footprint lets through.
    contrast = np.where(weight > 0, total / np.sqrt(np.maximum(weight, 1e-6)), 0.0)
    return np.clip(0.5 + 1.2 * contrast, 0.0, 1.0).astype(np.float32)
