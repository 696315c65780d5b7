"""Seeded procedural BTF surfaces: height, albedo and roughness maps of one tileable patch.

Four kinds in the spirit of UBO2014's material classes (Xu et al. use its leather, fabric,
wood and stone captures):

============  =================================================================================
kind          what it is
============  =================================================================================
``leather``   pebbled cells (Worley) with grooves between them; brown, cells vary in tone;
              grooves darker and rougher
``fabric``    a plain weave: over-under threads of two colours, rounded across each thread
``wood``      growth rings (light early wood, dark late wood) with shallow grooves at the
              late wood; fairly glossy (varnish)
``stone``     fractal relief (fBm) with mottled grey albedo; rough
============  =================================================================================

Maps are ``(n, n)`` (``albedo`` ``(n, n, 3)``) over the patch ``[0, 1)^2``, ``[row = y,
column = x]``, texel centres at ``(i + 0.5) / n``, periodic. ``height`` is in patch units
(the patch's side is 1; the mean plane is z = 0), scaled so its standard deviation is
``relief``; ``albedo`` is linear RGB in ``[0, 1]``; ``roughness`` is the principled BSDF's
perceptual roughness in ``[0, 1]``. The renderer turns the height into a displaced mesh, so
shadowing, masking and interreflection are real geometry.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from materials.noise import fbm, gaussian_noise, worley

KINDS: tuple[str, ...] = ("leather", "fabric", "wood", "stone")


@dataclass(frozen=True)
class SurfaceMaps:
    """One procedural patch (see the module docstring)."""

    height: np.ndarray
    albedo: np.ndarray
    roughness: np.ndarray

    @property
    def size(self) -> int:
        return int(self.height.shape[0])


def _scale_height(h: np.ndarray, relief: float) -> np.ndarray:
    h = h - h.mean()
    return h * (relief / max(float(h.std()), 1e-12))


def _leather(rng: np.random.Generator, n: int) -> tuple[np.ndarray, ...]:
    margin, cell = worley(rng, n, max(6, n // 5))
    height = np.sqrt(np.clip(margin, 0.0, None)) + 0.15 * gaussian_noise(rng, n, 1.0, 1.0)
    tone = rng.uniform(0.8, 1.2, int(cell.max()) + 1)[cell.astype(int)]
    groove = np.clip(1.0 - margin / 1.5, 0.0, 1.0)
    base = np.array([0.32, 0.17, 0.08])
    albedo = base[None, None, :] * (tone * (1.0 - 0.5 * groove))[..., None]
    roughness = 0.55 + 0.25 * groove + 0.05 * gaussian_noise(rng, n, 2.0, 2.0)
    return height, albedo, roughness


def _fabric(rng: np.random.Generator, n: int) -> tuple[np.ndarray, ...]:
    threads = max(4, n // 8)
    y, x = (np.mgrid[0:n, 0:n] + 0.5) / n
    u, v = x * threads, y * threads
    warp_up = (np.floor(u) + np.floor(v)) % 2 == 0
    across_warp = np.abs(np.sin(math.pi * u))  # rounded threads running along y
    across_weft = np.abs(np.sin(math.pi * v))
    height = np.where(warp_up, across_warp, across_weft) * (
        0.6 + 0.4 * np.where(warp_up, np.abs(np.sin(math.pi * v)), np.abs(np.sin(math.pi * u)))
    )
    height += 0.1 * gaussian_noise(rng, n, 0.7, 0.7)
    warp_c, weft_c = np.array([0.55, 0.12, 0.10]), np.array([0.85, 0.78, 0.62])
    shade = 0.85 + 0.15 * np.where(warp_up, across_warp, across_weft)
    albedo = np.where(warp_up[..., None], warp_c, weft_c) * shade[..., None]
    roughness = 0.75 + 0.05 * gaussian_noise(rng, n, 1.0, 1.0)
    return height, albedo, roughness


def _wood(rng: np.random.Generator, n: int) -> tuple[np.ndarray, ...]:
    y, x = (np.mgrid[0:n, 0:n] + 0.5) / n
    rings = rng.integers(5, 9)
    warp = 0.04 * gaussian_noise(rng, n, n / 6.0, n / 3.0)
    phase = (rings * (y + 0.15 * np.sin(2 * math.pi * x)) + warp * rings) % 1.0
    late = np.clip((phase - 0.7) / 0.3, 0.0, 1.0) ** 2
    height = -late + 0.05 * gaussian_noise(rng, n, 0.8, 4.0)
    early_c, late_c = np.array([0.62, 0.42, 0.22]), np.array([0.30, 0.16, 0.06])
    albedo = early_c * (1 - late[..., None]) + late_c * late[..., None]
    albedo *= (1.0 + 0.08 * gaussian_noise(rng, n, 0.6, 6.0))[..., None]
    roughness = 0.3 + 0.15 * late + 0.03 * gaussian_noise(rng, n, 2.0, 2.0)
    return height, albedo, roughness


def _stone(rng: np.random.Generator, n: int) -> tuple[np.ndarray, ...]:
    height = fbm(rng, n, octaves=5, gain=0.55)
    mottle = fbm(rng, n, octaves=4, gain=0.6)
    grey = 0.35 + 0.08 * mottle + 0.05 * np.clip(height, -2, 2)
    tint = np.array([1.0, 0.97, 0.92])
    albedo = grey[..., None] * tint
    roughness = 0.85 + 0.05 * gaussian_noise(rng, n, 2.0, 2.0)
    return height, albedo, roughness


def procedural_surface(
    kind: str, size: int, rng: np.random.Generator, *, relief: float = 0.02
) -> SurfaceMaps:
    """A seeded patch of ``kind`` (:data:`KINDS`) at ``size x size`` texels, height standard
    deviation ``relief`` (patch units)."""
    makers = {"leather": _leather, "fabric": _fabric, "wood": _wood, "stone": _stone}
    if kind not in makers:
        raise ValueError(f"unknown surface {kind!r}; known: {', '.join(KINDS)}")
    if size < 4 or size > 4096:
        raise ValueError(f"surface size must be in [4, 4096], got {size}")
    if not 0.0 <= relief <= 0.5:
        raise ValueError(f"relief must be in [0, 0.5], got {relief}")
    height, albedo, roughness = makers[kind](rng, size)
    return SurfaceMaps(
        height=_scale_height(np.asarray(height, np.float64), relief).astype(np.float32),
        albedo=np.clip(albedo, 0.0, 1.0).astype(np.float32),
        roughness=np.clip(roughness, 0.05, 1.0).astype(np.float32),
    )
