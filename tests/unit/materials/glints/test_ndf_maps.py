"""Multi-scale NDF maps (Eq. 2): every identity the paper implies, and the images against a
brute-force P-NDF written without the lobes (:mod:`tests.helpers.glint_reference`).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from materials.glints.examples import TYPES, procedural_example
from materials.glints.lobes import make_lobes
from materials.glints.ndf_maps import (
    auto_extent,
    gaussian_cell_masses,
    levels_of,
    ndf_maps,
    tiles_per_side,
)
from tests.helpers.glint_reference import tile_cell_masses


def _maps(kind: str, n: int, r: int, rate: int, extent: float | None = None) -> tuple:
    normals = procedural_example(kind, n, np.random.default_rng(11))
    lobes = make_lobes(normals, rate=rate, sigma_r=0.02)
    e = extent or auto_extent(lobes)
    return normals, lobes, e, ndf_maps(lobes, r, e)


def test01_layout() -> None:
    _, _, e, maps = _maps("isotropic_noise", 16, 24, 2)
    assert levels_of(16) == 4 and [tiles_per_side(16, lv) for lv in range(4)] == [8, 4, 2, 1]
    assert [m.shape for m in maps] == [(r, r, 24, 24) for r in (8, 4, 2, 1)]
    assert all(m.dtype == np.float32 for m in maps)


def test02_level_is_the_mean_of_its_children() -> None:
    """Exactly, up to the float32 rounding of both sides (each is rounded from float64: half
    an ulp each, 1.2e-7 together, under ``rtol``; the float64 sums differ by ~1e-15)."""
    _, _, _, maps = _maps("scratches", 32, 16, 2)
    for child, parent in zip(maps[:-1], maps[1:], strict=True):
        r = parent.shape[0]
        mean = child.astype(np.float64).reshape(r, 2, r, 2, 16, 16).mean(axis=(1, 3))
        assert np.allclose(parent, mean, rtol=2e-7, atol=1e-7 * float(parent.max()))


@pytest.mark.parametrize("kind", TYPES)
def test03_masses_at_most_one(kind: str) -> None:
    """A tile's image integrates to at most 1, and to 1 (within the 3-sigma margin of the
    automatic extent, and the window's 5-sigma truncation) when e covers the normals; a
    small extent loses mass but never exceeds 1."""
    _, lobes, e, maps = _maps(kind, 16, 32, 2)
    area = (2 * e / 32) ** 2
    for m in maps:
        mass = m.astype(np.float64).sum(axis=(-1, -2)) * area
        assert mass.max() <= 1.0 + 1e-5 and mass.min() > 0.99, (kind, mass.min(), mass.max())
    small = ndf_maps(lobes, 32, 0.1)[0].astype(np.float64).sum(axis=(-1, -2)) * (0.2 / 32) ** 2
    assert small.max() <= 1.0 + 1e-6 and small.min() < 0.99


def test04_cell_masses_against_riemann_sums() -> None:
    """The t-substitution quadrature against a fine Riemann sum of correlated Gaussians."""
    rng = np.random.default_rng(4)
    mean = rng.uniform(-0.2, 0.2, (6, 2))
    a = rng.uniform(0.01, 0.05, 6)
    b = rng.uniform(0.01, 0.05, 6)
    rho = rng.uniform(-0.9, 0.9, 6)
    cov = np.stack([[a * a, rho * a * b], [rho * a * b, b * b]]).transpose(2, 0, 1)
    edges = np.linspace(-0.5, 0.5, 21)
    ix0, iy0, mass = gaussian_cell_masses(mean, cov, edges)
    f = 150  # Riemann points per cell per axis
    g = (np.arange(20 * f) + 0.5) / (20 * f) - 0.5
    xx, yy = np.meshgrid(g, g)
    for k in range(6):
        inv = np.linalg.inv(cov[k])
        d = np.stack([xx - mean[k, 0], yy - mean[k, 1]], axis=-1)
        dens = np.exp(-0.5 * np.einsum("...a,ab,...b->...", d, inv, d))
        dens /= 2 * math.pi * math.sqrt(np.linalg.det(cov[k]))
        cells = dens.reshape(20, f, 20, f).sum(axis=(1, 3)) * (1.0 / (20 * f)) ** 2
        w = mass.shape[1]
        ours = np.zeros((20, 20))
        for wy in range(w):
            for wx in range(w):
                y, x = iy0[k] + wy, ix0[k] + wx
                if 0 <= x < 20 and 0 <= y < 20:
                    ours[y, x] = mass[k, wy, wx]
        # The midpoint rule, 150 points per cell: error (h / sigma)^2 / 24 of a cell, < 1e-5;
        # the quadrature to ~3e-5 at the strongest correlation here (0.83).
        assert np.abs(ours - cells).max() < 1e-4 * cells.max(), (k, rho[k])


@pytest.mark.parametrize("kind", TYPES)
def test05_tiles_against_brute_force(kind: str) -> None:
    """Each level's images against the brute-force P-NDF of their tiles, in total-variation
    distance. The lobe model blurs the bilinear field with the seeds' Gaussians (sigma_h =
    h / sqrt(8 ln 2), wider than a box of side h) and linearises it per seed: an error of
    order h^2 that shrinks about 3x from 2 to 4 seeds per texel. Bounds: 0.15 at 2 seeds
    per texel, 0.06 at 4 (the largest measured: structured, 0.11 and 0.042), and the error
    must fall."""
    normals = procedural_example(kind, 16, np.random.default_rng(11))
    tv = {}
    for rate in (2, 4):
        lobes = make_lobes(normals, rate=rate, sigma_r=0.02)
        e = auto_extent(make_lobes(normals, rate=2, sigma_r=0.02))
        maps = ndf_maps(lobes, 32, e)
        area = (2 * e / 32) ** 2
        worst = 0.0
        for level in (0, 1, 3):
            side = 2 << level
            r = maps[level].shape[0]
            for tx, ty in {(0, 0), (r - 1, r // 2)}:
                ref = tile_cell_masses(normals, (tx * side, ty * side), side, 32, e, 0.02)
                ours = maps[level][ty, tx].astype(np.float64) * area
                worst = max(worst, 0.5 * float(np.abs(ref - ours).sum()))
        tv[rate] = worst
    assert tv[2] < 0.15 and tv[4] < 0.06 and tv[4] < 0.6 * tv[2], tv


def test06_rotation_rotates_the_image() -> None:
    """The example turned by 90 degrees (texels and normals) has the NDF images turned by
    90 degrees. The seed grid maps onto itself, so the lobes do exactly; the cell masses
    agree to the quadrature's error (it integrates x then y, so a turned correlated lobe is
    integrated differently): 1e-4 of the largest value."""
    normals = procedural_example("anisotropic_noise", 16, np.random.default_rng(3))
    # np.rot90: new[y', x'] = old[x', n-1-y'], i.e. old (x, y) -> (x' = y, y' = n - x), so the
    # slopes turn the same way: s'_x = s_y, s'_y = -s_x; and so do the tiles and the images.
    rot = np.rot90(normals, k=1, axes=(0, 1)).copy()
    sx, sy = rot[..., 0].copy(), rot[..., 1].copy()
    rot[..., 0], rot[..., 1] = sy, -sx
    a = ndf_maps(make_lobes(normals, rate=2, sigma_r=0.02), 24, 0.6)
    b = ndf_maps(make_lobes(rot, rate=2, sigma_r=0.02), 24, 0.6)
    for la, lb in zip(a, b, strict=True):
        turned = np.rot90(np.rot90(la, k=1, axes=(0, 1)), k=1, axes=(2, 3))
        assert np.abs(lb - turned).max() < 1e-4 * float(la.max())


def test07_gauss_legendre_rule_for_wide_gaussians() -> None:
    """The 3 x 3 Gauss-Legendre rule used for Gaussians at least a cell wide agrees with the
    t-substitution rule (at 32 nodes, ~1e-8) to 1e-5 of the largest cell, any correlation."""
    import materials.glints.ndf_maps as nm

    rng = np.random.default_rng(8)
    k = 120
    mean = rng.uniform(-0.2, 0.2, (k, 2))
    a = rng.uniform(0.02, 0.06, k)
    b = rng.uniform(0.02, 0.06, k)
    rho = rng.uniform(-0.95, 0.95, k)
    cov = np.stack([[a * a, rho * a * b], [rho * a * b, b * b]]).transpose(2, 0, 1)
    narrow = np.sqrt(np.linalg.eigvalsh(cov)[:, 0]) / 0.02
    keep = narrow >= nm.GL_MIN_SIGMA_CELLS
    edges = np.linspace(-0.6, 0.6, 61)  # cells of 0.02
    saved = nm.QUAD_NODES
    try:
        nm.QUAD_NODES = 32
        _, _, ref = nm.gaussian_cell_masses(mean[keep], cov[keep], edges, window=40)
    finally:
        nm.QUAD_NODES = saved
    _, _, gl = nm.gaussian_cell_masses_gl(mean[keep], cov[keep], edges, window=40)
    err = np.abs(gl - ref).max(axis=(1, 2)) / ref.max(axis=(1, 2))
    assert keep.sum() > 50 and err.max() < 1e-5, err.max()
