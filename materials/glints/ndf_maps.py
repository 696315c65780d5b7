"""Multi-scale NDF maps of a tiny example (Xing et al. 2024, Sec. 5.2, Eq. 2).

For an ``n x n`` example, level ``l = 0 .. log2(n) - 1`` splits it into ``r x r`` tiles with
``r = n / 2**(l+1)`` (8, 4, 2, 1 for ``n = 16``); tile ``(tx, ty)`` covers texels
``[tx n/r, (tx+1) n/r) x [ty n/r, (ty+1) n/r)``. Each tile holds an NDF image of ``R x R``
cells over projected normals ``s = (n_x, n_y)`` in ``[-e, e]^2``, cell edges
``linspace(-e, e, R + 1)``, ``[iy, ix]`` with ``iy`` along ``n_y``. A cell's value is the
**mean density over the cell** (the mass that falls in it divided by its area) of the tile's
NDF, Eq. 2: the equally weighted average of the normal marginals of the lobes seeded in the
tile (:mod:`materials.glints.lobes`). So a tile's image integrates (sum times cell area) to
at most 1, and to 1 when no mass falls outside ``[-e, e]^2``; and since every tile holds
the same number of seeds, a level is exactly the mean of its four children -- which is how
levels above 0 are built.

Cell masses are computed per lobe over a window of cells around its mean: the x-integral is
rewritten in ``t = Phi((x - mu_x) / sigma_x)``, which absorbs the Gaussian weight, and done
by Gauss-Legendre quadrature; the y-integral given x is an exact difference of normal
CDFs. For an uncorrelated lobe the result is exact; for a correlated one the integrand is
smooth in ``t`` except near the tails, and :data:`QUAD_NODES` nodes give a relative error
(of the largest cell) of about 3e-5 at correlation 0.83 and below 1e-8 under 0.5 (measured
against 32 nodes; tested against a fine Riemann sum). Mass beyond :data:`WINDOW_SIGMAS`
standard deviations is dropped (below 1e-6).

Arrays: maps are ``(r, r, R, R)`` float32 indexed ``[ty, tx, iy, ix]`` (``ndf.npz``'s
``level_<l>``).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.special import ndtr, ndtri

from materials.glints.lobes import Lobes

#: Gauss-Legendre nodes per cell column in the ``t`` variable (module docstring).
QUAD_NODES = 12
#: Half-width of a lobe's window of cells, in standard deviations.
WINDOW_SIGMAS = 5.0
#: Gaussians at least this many cells wide (smallest standard deviation) are integrated by
#: :func:`gaussian_cell_masses_gl`, narrower ones by the t-substitution rule.
GL_MIN_SIGMA_CELLS = 1.0


def levels_of(n: int) -> int:
    """Number of levels for an ``n x n`` example: ``log2(n)``, levels ``0 .. log2(n) - 1``."""
    if n < 2 or n & (n - 1):
        raise ValueError(f"the example side must be a power of two >= 2, got {n}")
    return int(round(math.log2(n)))


def tiles_per_side(n: int, level: int) -> int:
    """``r = n / 2**(level + 1)``."""
    return n >> (level + 1)


def auto_extent(lobes: Lobes, *, margin_sigmas: float = 3.0, step: float = 0.05) -> float:
    """An extent ``e`` that holds the lobes' normals with ``margin_sigmas`` of their widest
    marginal, rounded up to ``step``, at most 1."""
    spread = np.sqrt(np.linalg.eigvalsh(lobes.normal_covariances())[:, 1])
    reach = float((np.abs(lobes.s).max(axis=1) + margin_sigmas * spread).max())
    return round(min(1.0, math.ceil(reach / step - 1e-9) * step), 6)


def gaussian_cell_masses(
    mean: np.ndarray, cov: np.ndarray, edges: np.ndarray, *, window: int | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Masses of 2D Gaussians over the cells of a regular grid.

    ``mean`` ``(K, 2)`` and ``cov`` ``(K, 2, 2)`` (x then y), ``edges`` ``(R + 1,)`` the
    cell edges on both axes. Returns ``(ix0, iy0, mass)``: each Gaussian's window of
    ``W x W`` cells starts at cell ``(ix0, iy0)`` (may reach outside ``0 .. R - 1``; those
    cells hold mass outside the grid) and ``mass`` is ``(K, W, W)`` indexed ``[k, wy, wx]``.
    """
    mean = np.asarray(mean, dtype=np.float64)
    cov = np.asarray(cov, dtype=np.float64)
    r = len(edges) - 1
    lo, width = float(edges[0]), float(edges[1] - edges[0])
    sx = np.sqrt(cov[:, 0, 0])
    sy = np.sqrt(cov[:, 1, 1])
    if window is None:
        window = int(math.ceil(2 * WINDOW_SIGMAS * max(sx.max(), sy.max()) / width)) + 2
    window = max(1, min(window, r + 2))
    ix0 = np.floor((mean[:, 0] - lo) / width).astype(np.int64) - window // 2
    iy0 = np.floor((mean[:, 1] - lo) / width).astype(np.int64) - window // 2
    offs = np.arange(window + 1)
    xe = lo + (ix0[:, None] + offs[None]) * width  # (K, W+1) column edges
    ye = lo + (iy0[:, None] + offs[None]) * width  # (K, W+1) row edges
    # x-integral in t = Phi((x - mu_x) / s_x); Gauss-Legendre on each column's t-range.
    tx = ndtr((xe - mean[:, 0:1]) / sx[:, None])  # (K, W+1)
    nodes, weights = np.polynomial.legendre.leggauss(QUAD_NODES)
    t_lo, t_hi = tx[:, :-1], tx[:, 1:]
    half = 0.5 * (t_hi - t_lo)  # (K, W)
    t = (0.5 * (t_hi + t_lo))[..., None] + half[..., None] * nodes  # (K, W, Q)
    t = np.clip(t, 1e-300, 1.0 - 1e-16)
    x = mean[:, 0, None, None] + sx[:, None, None] * ndtri(t)  # (K, W, Q)
    # y | x ~ N(mu_y + rho s_y / s_x (x - mu_x), s_y^2 (1 - rho^2))
    beta = cov[:, 0, 1] / cov[:, 0, 0]
    cond_sd = np.sqrt(np.maximum(cov[:, 1, 1] - beta * cov[:, 0, 1], 1e-300))
    mu_y = mean[:, 1, None, None] + beta[:, None, None] * (x - mean[:, 0, None, None])
    z = (ye[:, :, None, None] - mu_y[:, None]) / cond_sd[:, None, None, None]  # (K, W+1, W, Q)
    cdf = ndtr(z)
    band = cdf[:, 1:] - cdf[:, :-1]  # (K, W rows, W cols, Q)
    mass = np.einsum("kyxq,q,kx->kyx", band, weights, half)
    return ix0, iy0, mass


def gaussian_cell_masses_gl(
    mean: np.ndarray, cov: np.ndarray, edges: np.ndarray, *, window: int | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`gaussian_cell_masses` by a 3 x 3 Gauss-Legendre product rule on each cell, for
    Gaussians at least :data:`GL_MIN_SIGMA_CELLS` cells wide: the rule integrates
    polynomials of degree 5 exactly, and its error on a Gaussian that wide is below 1e-7 of
    the largest cell (measured against the t-substitution rule). Same return layout."""
    mean = np.asarray(mean, dtype=np.float64)
    cov = np.asarray(cov, dtype=np.float64)
    r = len(edges) - 1
    lo, width = float(edges[0]), float(edges[1] - edges[0])
    sx, sy = np.sqrt(cov[:, 0, 0]), np.sqrt(cov[:, 1, 1])
    if window is None:
        window = int(math.ceil(2 * WINDOW_SIGMAS * max(sx.max(), sy.max()) / width)) + 2
    window = max(1, min(window, r + 2))
    ix0 = np.floor((mean[:, 0] - lo) / width).astype(np.int64) - window // 2
    iy0 = np.floor((mean[:, 1] - lo) / width).astype(np.int64) - window // 2
    nodes, weights = np.polynomial.legendre.leggauss(3)
    offs = np.arange(window)
    # Node coordinates per axis: (K, W, 3), relative to the mean.
    gx = lo + (ix0[:, None, None] + offs[None, :, None] + 0.5 + 0.5 * nodes) * width
    gy = lo + (iy0[:, None, None] + offs[None, :, None] + 0.5 + 0.5 * nodes) * width
    dx = gx - mean[:, 0, None, None]
    dy = gy - mean[:, 1, None, None]
    det = cov[:, 0, 0] * cov[:, 1, 1] - cov[:, 0, 1] ** 2
    ia = (cov[:, 1, 1] / det)[:, None, None, None, None]
    ib = (-cov[:, 0, 1] / det)[:, None, None, None, None]
    ic = (cov[:, 0, 0] / det)[:, None, None, None, None]
    x = dx[:, None, :, None, :]  # (K, 1, Wx, 1, 3)
    y = dy[:, :, None, :, None]  # (K, Wy, 1, 3, 1)
    dens = np.exp(-0.5 * (ia * x * x + 2 * ib * x * y + ic * y * y))  # (K, Wy, Wx, 3, 3)
    w2 = np.outer(weights, weights) * (0.25 * width * width)
    norm = 1.0 / (2.0 * math.pi * np.sqrt(det))
    mass = np.einsum("kyxab,ab->kyx", dens, w2) * norm[:, None, None]
    return ix0, iy0, mass


def _scatter(
    images: np.ndarray, tile: np.ndarray, ix0: np.ndarray, iy0: np.ndarray, mass: np.ndarray
) -> None:
    """Add each lobe's window of masses into ``images[tile]`` (cells outside are dropped)."""
    r = images.shape[-1]
    k, w, _ = mass.shape
    offs = np.arange(w)
    cx = ix0[:, None] + offs[None]  # (K, W)
    cy = iy0[:, None] + offs[None]
    ok = (cy[:, :, None] >= 0) & (cy[:, :, None] < r) & (cx[:, None, :] >= 0) & (cx[:, None, :] < r)
    kk = np.broadcast_to(tile[:, None, None], (k, w, w))
    yy = np.broadcast_to(cy[:, :, None], (k, w, w))
    xx = np.broadcast_to(cx[:, None, :], (k, w, w))
    np.add.at(images, (kk[ok], yy[ok], xx[ok]), mass[ok])


def tile_masses(
    lobes: Lobes, tiles: int, resolution: int, extent: float, *, chunk: int = 128
) -> np.ndarray:
    """Cell masses of the finest level: ``(tiles, tiles, R, R)`` float64, each tile's image
    the *sum* of its lobes' masses (:func:`ndf_maps` divides by the lobe count).

    Lobes are processed in chunks sorted by their spread, so that each chunk's window is as
    small as its widest lobe needs.
    """
    n = lobes.size
    edges = np.linspace(-extent, extent, resolution + 1)
    side = n // tiles
    t = np.floor(lobes.u / side).astype(np.int64) % tiles
    tile = t[:, 1] * tiles + t[:, 0]
    covs = lobes.normal_covariances()
    spread = np.sqrt(np.maximum(covs[:, 0, 0], covs[:, 1, 1]))
    order = np.argsort(spread, kind="stable")
    images = np.zeros((tiles * tiles, resolution, resolution))
    width = float(edges[1] - edges[0])
    narrowest = np.sqrt(np.linalg.eigvalsh(covs)[:, 0]) / width  # in cells
    wide = narrowest >= GL_MIN_SIGMA_CELLS
    for rule, group in (
        (gaussian_cell_masses_gl, order[wide[order]]),
        (gaussian_cell_masses, order[~wide[order]]),
    ):
        for lo in range(0, len(group), chunk):
            idx = group[lo : lo + chunk]
            ix0, iy0, mass = rule(lobes.s[idx], covs[idx], edges)
            _scatter(images, tile[idx], ix0, iy0, mass)
    return images.reshape(tiles, tiles, resolution, resolution)


def ndf_maps(lobes: Lobes, resolution: int, extent: float) -> list[np.ndarray]:
    """The multi-scale NDF maps: ``[level_0, level_1, ...]``, each ``(r, r, R, R)`` float32
    of mean densities over cells (module docstring). Level 0 from the lobes, each coarser
    level the mean of its four children (computed in float64, then rounded)."""
    n = lobes.size
    count = levels_of(n)
    r0 = tiles_per_side(n, 0)
    cell_area = (2.0 * extent / resolution) ** 2
    per_tile = len(lobes) / (r0 * r0)
    level = tile_masses(lobes, r0, resolution, extent) / (per_tile * cell_area)
    out = [level.astype(np.float32)]
    for _ in range(1, count):
        r = level.shape[0] // 2
        level = level.reshape(r, 2, r, 2, resolution, resolution).mean(axis=(1, 3))
        out.append(level.astype(np.float32))
    return out


def map_bytes(maps: list[np.ndarray]) -> int:
    """Bytes of the maps as stored (float32)."""
    return int(sum(m.size * 4 for m in maps))
