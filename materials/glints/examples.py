"""Tiny examples (Xing et al. 2024, Sec. 5.1): small tileable normal maps of one microstructure.

Conventions, shared by every module of :mod:`materials.glints`:

- **normals** are tangent-space unit vectors, z up, ``(n, n, 3)`` float32 with ``z > 0``;
- arrays are indexed ``[row = y, column = x]``;
- **texel centres** sit at ``i + 0.5`` (texel units), values are **bilinear between
  centres**, and the example **tiles** (wraps) in both directions;
- ``s = (n_x, n_y)`` is the *projected normal*, the coordinate the NDFs are densities over.

The six procedural types of the paper's figures are made from periodic height fields, so
every example tiles without seams; each is seeded, deterministic, and scaled to a target RMS
slope. A user's own map comes in through :mod:`storage.formats.normal_map`, which refuses
anything that is not a square power-of-two map of unit normals with ``z > 0``.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from materials.noise import gaussian_noise, worley

#: The procedural example types (Sec. 5.1, Figs. 6-10), in display order.
TYPES: tuple[str, ...] = (
    "scratches",
    "isotropic_noise",
    "anisotropic_noise",
    "brushed_metal",
    "leather",
    "structured",
)
#: Allowed example sizes (texels per side): powers of two from 8 to 256.
SIZES: tuple[int, ...] = (8, 16, 32, 64, 128, 256)
#: Default RMS slope |grad h| of each type: scratches are sparse and steep, noise is mild.
DEFAULT_SLOPE: dict[str, float] = {
    "scratches": 0.35,
    "isotropic_noise": 0.25,
    "anisotropic_noise": 0.25,
    "brushed_metal": 0.2,
    "leather": 0.3,
    "structured": 0.3,
}


def _scratches(rng: np.random.Generator, n: int) -> np.ndarray:
    """A few straight scratches at random angles: V-grooves one to two texels wide."""
    y, x = np.mgrid[0:n, 0:n].astype(np.float64) + 0.5
    h = np.zeros((n, n))
    for _ in range(max(2, n // 8)):
        theta = rng.uniform(0.0, math.pi)
        c = rng.uniform(0.0, n, size=2)
        nx, ny = -math.sin(theta), math.cos(theta)  # the groove's normal in the plane
        # Signed distance to the line through c, wrapped so the groove tiles.
        d = ((x - c[0]) * nx + (y - c[1]) * ny + n / 2) % n - n / 2
        width = rng.uniform(0.8, 1.6)
        h -= np.clip(1.0 - np.abs(d) / width, 0.0, None) * rng.uniform(0.5, 1.0)
    return h


def _leather(rng: np.random.Generator, n: int) -> np.ndarray:
    """Worley cells: height is the distance to the cell border (rounded pebbles)."""
    margin, _ = worley(rng, n, max(3, n // 4))
    return np.sqrt(np.maximum(margin, 0.0))


def _structured(rng: np.random.Generator, n: int) -> np.ndarray:
    """A regular lattice of round dimples (four per side of the example)."""
    period = max(2, n // 4)
    y, x = np.mgrid[0:n, 0:n].astype(np.float64) + 0.5
    fx = (x % period) / period - 0.5
    fy = (y % period) / period - 0.5
    r2 = (fx * fx + fy * fy) / 0.16
    return -np.sqrt(np.clip(1.0 - r2, 0.0, None)) + 0.05 * gaussian_noise(rng, n, 2.0, 2.0)


def _height(kind: str, rng: np.random.Generator, n: int) -> np.ndarray:
    makers: dict[str, Callable[[], np.ndarray]] = {
        "scratches": lambda: _scratches(rng, n),
        "isotropic_noise": lambda: gaussian_noise(rng, n, 1.0, 1.0),
        "anisotropic_noise": lambda: gaussian_noise(rng, n, 3.0, 0.8),
        "brushed_metal": lambda: gaussian_noise(rng, n, max(8.0, n / 2), 0.6),
        "leather": lambda: _leather(rng, n),
        "structured": lambda: _structured(rng, n),
    }
    return makers[kind]()


def normals_from_height(h: np.ndarray, slope: float) -> np.ndarray:
    """Unit normals ``(n, n, 3)`` float32 of a periodic height field ``h`` ``[y, x]``, scaled
    so that the RMS of ``|grad h|`` is ``slope`` (central differences, wrapped)."""
    gx = 0.5 * (np.roll(h, -1, axis=1) - np.roll(h, 1, axis=1))
    gy = 0.5 * (np.roll(h, -1, axis=0) - np.roll(h, 1, axis=0))
    rms = math.sqrt(float(np.mean(gx * gx + gy * gy)))
    k = slope / rms if rms > 0 else 0.0
    v = np.stack([-k * gx, -k * gy, np.ones_like(h)], axis=-1)
    return (v / np.linalg.norm(v, axis=-1, keepdims=True)).astype(np.float32)


def procedural_example(
    kind: str, size: int, rng: np.random.Generator, *, slope: float | None = None
) -> np.ndarray:
    """A seeded procedural tiny example: ``(size, size, 3)`` float32 unit normals.

    ``kind`` is one of :data:`TYPES`, ``size`` one of :data:`SIZES`; ``slope`` is the RMS
    slope of the height field (default :data:`DEFAULT_SLOPE`). The same ``rng`` state gives
    the same bytes.
    """
    if kind not in TYPES:
        raise ValueError(f"unknown example type {kind!r}; known: {', '.join(TYPES)}")
    if size not in SIZES:
        raise ValueError(f"example size must be one of {SIZES}, got {size}")
    s = DEFAULT_SLOPE[kind] if slope is None else float(slope)
    if not (0.0 <= s <= 2.0):
        raise ValueError(f"slope must lie in [0, 2], got {s}")
    return normals_from_height(_height(kind, rng, size), s)
