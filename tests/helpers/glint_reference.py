"""Brute-force P-NDF references for the glint tests, written without the lobes.

A tile's NDF is the distribution of the bilinear normal field over the tile, each normal
blurred by the intrinsic roughness: sample ``u`` densely and uniformly over the tile, take
the bilinear projected normal there, and integrate the isotropic Gaussian
``N(s; s(u), sigma_r^2 I)`` over each cell exactly (a product of normal-CDF differences).
Nothing here uses the 4D lobes, their Jacobians or the seed Gaussians.
"""

from __future__ import annotations

import numpy as np
from scipy.special import ndtr


def bilinear_field(normals: np.ndarray, u: np.ndarray) -> np.ndarray:
    """``(N, 2)`` projected normals at ``u`` ``(N, 2)`` texels: centres at i + 0.5,
    bilinear, tiled (written again here, independently of ``materials.glints.lobes``)."""
    n = normals.shape[0]
    p = u - 0.5
    x0 = np.floor(p[:, 0]).astype(int)
    y0 = np.floor(p[:, 1]).astype(int)
    fx, fy = p[:, 0] - x0, p[:, 1] - y0
    out = np.zeros((len(u), 2))
    for dy, wy in ((0, 1 - fy), (1, fy)):
        for dx, wx in ((0, 1 - fx), (1, fx)):
            out += (wx * wy)[:, None] * normals[(y0 + dy) % n, (x0 + dx) % n, :2]
    return out


def tile_cell_masses(
    normals: np.ndarray,
    lo: tuple[float, float],
    side: float,
    resolution: int,
    extent: float,
    sigma_r: float,
    *,
    per_texel: int = 16,
) -> np.ndarray:
    """``(R, R)`` ``[iy, ix]`` masses of the tile ``[lo, lo + side)^2``'s NDF over the cells
    of ``[-e, e]^2``, from ``per_texel^2`` uniform samples per texel."""
    k = int(round(side * per_texel))
    g = (np.arange(k) + 0.5) / k * side
    yy, xx = np.meshgrid(lo[1] + g, lo[0] + g, indexing="ij")
    s = bilinear_field(normals, np.stack([xx.ravel(), yy.ravel()], axis=1))
    edges = np.linspace(-extent, extent, resolution + 1)
    mx = np.diff(ndtr((edges[None, :] - s[:, 0:1]) / sigma_r), axis=1)
    my = np.diff(ndtr((edges[None, :] - s[:, 1:2]) / sigma_r), axis=1)
    return (my.T @ mx) / len(s)
