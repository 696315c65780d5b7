"""P-NDF over a pixel footprint: the tiny-example evaluation (Xing et al. 2024, Sec. 6.3) and
the explicit reference (Yan et al. 2016), numpy references of what the renderer traces.

**Footprint** (Heckbert 1989): a pixel's footprint in texture space is the parallelogram
spanned by the uv derivatives ``du/dx``, ``du/dy`` (texels per pixel); its Gaussian
approximation has covariance ``Sigma_P = sigma_pixel^2 [du/dx du/dy][du/dx du/dy]^T`` with
``sigma_pixel`` :data:`PIXEL_SIGMA` (the pixel filter's standard deviation, in pixels).
The P-NDF is ``D_P(s) = int N(u; c, Sigma_P) N(u, s) du`` (Eq. 1, a density over projected
normals ``s``; the footprint is normalised).

**Tiny examples** (Sec. 6.3): the footprint is split over the tiles of the example
instances it meets, each tile contributing ``w_T B_l(tile, s)``: its exact footprint mass
times its NDF image (bilinear between cell centres); a footprint smaller than the finest
tiles is evaluated from the lobes directly by Eq. 1. The paper descends from the top level
and splits tiles the pixel's parallelogram covers only partly, since over a covered tile a
box footprint's weight is uniform and the tile's averaged NDF exact. Under Heckbert's
Gaussian the weight varies across every tile, so what makes a tile usable is that it is
small against the footprint: its side at most :data:`FLATNESS` of the footprint's smallest
standard deviation (without this, the tile-averaged NDF misweights the lobes by 15-40 % in
L1 at footprints of 1-4 texels). Splitting a partly covered tile then changes nothing (its
weight is its exact mass), so the descent settles on one level per footprint
(:func:`lod_level`): the coarsest whose tiles are flat under it -- whole examples from the
top level when the footprint is wide, the lobes when it is below the finest tile. Transforms
map the query into the instance's frame (:mod:`materials.glints.surface`).

**The paper's lookup rule** (``lookup="paper"``, :func:`paper_tiles`): the descent of
Sec. 6.3 as written. Starting from the top level (one tile per example), a tile the pixel
covers entirely is read at that level; a partly covered one is split into its four
children, down to the finest level, where partly covered tiles are read as they are;
tiles outside the footprint's support are dropped. With Heckbert's Gaussian, "covered"
means that the tile's four corners lie within :data:`COVER_SIGMAS` standard deviations
(Mahalanobis) of the centre: at 1, the ellipse inscribed in the pixel's parallelogram
(the filter's sigma is half a pixel). Each tile read weighs its exact footprint mass.
When the footprint is smaller than the finest tile (its 1-sigma ellipse's minor diameter
``2 COVER_SIGMAS sigma_min`` below the tile side, 2 texels), the lobes are summed by Eq. 1.
The default rule (``lookup="flat"``, :func:`lod_level`) is the one above.

**Reference** (Yan et al. 2016): Eq. 1 summed over every lobe of an explicit normal map
near the footprint.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.special import ndtr, ndtri

from materials.glints.lobes import Lobes, pndf
from materials.glints.surface import Instance, Surface, Transform

#: Standard deviation of the pixel filter, in pixels (Heckbert's Gaussian footprint).
PIXEL_SIGMA = 0.5
#: The footprint's support: the ellipse at this many standard deviations (mass outside:
#: ``exp(-SUPPORT_SIGMAS^2 / 2)``, 0.2 % at 3.5).
SUPPORT_SIGMAS = 3.5
#: A tile counts as whole only when its side is at most this many of the footprint's
#: smallest standard deviations (module docstring).
FLATNESS = 0.5
#: The lookup rules of the tiny-example evaluation: ``flat`` (:func:`lod_level`, the
#: default) and ``paper`` (:func:`paper_tiles`).
LOOKUPS = ("flat", "paper")
#: ``paper``: a tile is covered when its corners lie within this many standard deviations of
#: the footprint's centre (1: the ellipse inscribed in the pixel's parallelogram).
COVER_SIGMAS = 1.0


def heckbert_covariance(
    duv_dx: np.ndarray, duv_dy: np.ndarray, sigma: float = PIXEL_SIGMA
) -> np.ndarray:
    """``Sigma_P`` ``(2, 2)`` of a pixel whose texture derivatives are ``duv_dx``,
    ``duv_dy`` (texels per pixel); a floor of 1e-8 texel^2 keeps it invertible."""
    j = np.stack([np.asarray(duv_dx, float), np.asarray(duv_dy, float)], axis=1)
    return sigma * sigma * (j @ j.T) + 1e-8 * np.eye(2)


def box_mass(mean: np.ndarray, cov: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> float:
    """``int_[lo, hi] N(u; mean, cov) du`` over an axis-aligned box (the quadrature of
    :func:`materials.glints.ndf_maps.gaussian_cell_masses`: exact in y, Gauss-Legendre in
    ``t = Phi(x)``)."""
    sx = math.sqrt(cov[0, 0])
    t0, t1 = ndtr((lo[0] - mean[0]) / sx), ndtr((hi[0] - mean[0]) / sx)
    if t1 <= t0:
        return 0.0
    nodes, weights = np.polynomial.legendre.leggauss(8)
    t = np.clip(0.5 * (t0 + t1) + 0.5 * (t1 - t0) * nodes, 1e-300, 1 - 1e-16)
    x = mean[0] + sx * ndtri(t)
    beta = cov[0, 1] / cov[0, 0]
    sd = math.sqrt(max(cov[1, 1] - beta * cov[0, 1], 1e-300))
    my = mean[1] + beta * (x - mean[0])
    band = ndtr((hi[1] - my) / sd) - ndtr((lo[1] - my) / sd)
    return float(0.5 * (t1 - t0) * (weights @ band))


@dataclass(frozen=True)
class TinyExample:
    """What the tiny-example model stores: the example's lobes, its NDF maps
    (``[level_0, ...]``, each ``(r, r, R, R)``) and the maps' extent ``e``."""

    lobes: Lobes
    maps: list[np.ndarray]
    extent: float

    @property
    def n(self) -> int:
        return self.lobes.size

    def lookup(self, level: int, tx: int, ty: int, s: np.ndarray) -> np.ndarray:
        """``B_l(tile, s)``: the tile's NDF image at local projected normals ``s``
        ``(M, 2)``, bilinear between cell centres, 0 outside ``[-e, e]^2``."""
        img = self.maps[level][ty, tx].astype(np.float64)
        r = img.shape[0]
        width = 2.0 * self.extent / r
        p = (np.asarray(s) + self.extent) / width - 0.5
        i0 = np.floor(p).astype(np.int64)
        f = p - i0
        out = np.zeros(len(p))
        for dy in (0, 1):
            for dx in (0, 1):
                ix, iy = i0[:, 0] + dx, i0[:, 1] + dy
                w = (f[:, 0] if dx else 1 - f[:, 0]) * (f[:, 1] if dy else 1 - f[:, 1])
                ok = (ix >= 0) & (ix < r) & (iy >= 0) & (iy < r)
                out[ok] += w[ok] * img[iy[ok], ix[ok]]
        return out

    def tile_lobes(self, tx: int, ty: int) -> np.ndarray:
        """Indices of the lobes seeded in finest-level tile ``(tx, ty)``."""
        t = np.floor(self.lobes.u / 2.0).astype(np.int64)
        return np.flatnonzero((t[:, 0] == tx) & (t[:, 1] == ty))


def _bbox(c: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    half = SUPPORT_SIGMAS * np.sqrt(np.diag(cov))
    return c - half, c + half


def lod_level(ex: TinyExample, cov: np.ndarray) -> int:
    """The level whose tiles are flat under the footprint ``cov`` (example texels): the
    coarsest with tile side ``2**(l+1) <= FLATNESS * sigma_min``; -1 (the lobes) when even
    the finest tiles are too large."""
    sigma_min = math.sqrt(max(float(np.linalg.eigvalsh(cov)[0]), 1e-300))
    target = FLATNESS * sigma_min
    if target < 2.0:
        return -1
    return min(int(math.floor(math.log2(target))) - 1, len(ex.maps) - 1)


def paper_uses_lobes(cov: np.ndarray) -> bool:
    """``paper``: the footprint is smaller than the finest tile (side 2 texels): its
    covered ellipse's minor diameter ``2 COVER_SIGMAS sigma_min`` is below 2."""
    sigma_min = math.sqrt(max(float(np.linalg.eigvalsh(cov)[0]), 1e-300))
    return 2.0 * COVER_SIGMAS * sigma_min < 2.0


def _covered(c: np.ndarray, inv: np.ndarray, lo: np.ndarray, side: float) -> bool:
    d = lo + side * np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]]) - c
    return bool(np.all(np.einsum("ka,ab,kb->k", d, inv, d) <= COVER_SIGMAS**2))


def paper_tiles(
    ex: TinyExample, c: np.ndarray, cov: np.ndarray, lo_b: np.ndarray, hi_b: np.ndarray
) -> list[tuple[int, int, int]]:
    """The paper's descent (module docstring) over one instance (the square ``[0, n)^2``):
    ``(level, tx, ty)`` of every tile read, for a footprint ``N(c, cov)`` whose support box
    is ``[lo_b, hi_b]``."""
    inv = np.linalg.inv(cov)
    top = len(ex.maps) - 1
    side = 2 << top
    r = len(ex.maps[top])
    t0 = np.maximum(np.floor(lo_b / side).astype(int), 0)
    t1 = np.minimum(np.floor(hi_b / side).astype(int), r - 1)
    stack = [(top, tx, ty) for ty in range(t0[1], t1[1] + 1) for tx in range(t0[0], t1[0] + 1)]
    out: list[tuple[int, int, int]] = []
    while stack:
        level, tx, ty = stack.pop()
        side = 2 << level
        lo = np.array([tx, ty], dtype=np.float64) * side
        if np.any(lo > hi_b) or np.any(lo + side < lo_b):
            continue
        if level == 0 or _covered(c, inv, lo, side):
            out.append((level, tx, ty))
            continue
        for dy in (0, 1):
            for dx in (0, 1):
                stack.append((level - 1, 2 * tx + dx, 2 * ty + dy))
    return out


def _paper_pndf(
    ex: TinyExample,
    c: np.ndarray,
    cov: np.ndarray,
    s_local: np.ndarray,
    lo_b: np.ndarray,
    hi_b: np.ndarray,
    owned: Callable[[np.ndarray], np.ndarray] | None,
) -> np.ndarray:
    out = np.zeros(len(s_local))
    for level, tx, ty in paper_tiles(ex, c, cov, lo_b, hi_b):
        side = 2 << level
        lo = np.array([tx, ty], dtype=np.float64) * side
        if owned is not None and not owned((lo + 0.5 * side)[None])[0]:
            continue
        out += box_mass(c, cov, lo, lo + side) * ex.lookup(level, tx, ty, s_local)
    return out


def instance_pndf(
    ex: TinyExample,
    c: np.ndarray,
    cov: np.ndarray,
    s_local: np.ndarray,
    *,
    owned: Callable[[np.ndarray], np.ndarray] | None = None,
    lookup: str = "flat",
) -> np.ndarray:
    """One instance's share of the P-NDF, in its local frame: footprint ``N(c, cov)`` in
    example texels (the instance's square is ``[0, n)^2``), queries ``s_local`` ``(M, 2)``.

    The level is :func:`lod_level`'s; every tile of it that meets the footprint's support box
    contributes its exact footprint mass times its NDF image; at level -1 the lobes of the
    finest tiles there are summed by Eq. 1. ``owned(points)`` (optional) says which local
    points the instance owns (Fig. 3's occlusion): a tile counts when its centre is owned, a
    lobe when its seed is. ``lookup`` ``"paper"``: the tiles of :func:`paper_tiles` instead
    of one level (the lobes when :func:`paper_uses_lobes`). Returns ``(M,)`` densities.
    """
    if lookup not in LOOKUPS:
        raise ValueError(f"lookup must be one of {LOOKUPS}, got {lookup!r}")
    lo_b, hi_b = _bbox(c, cov)
    # Lobes reach 5 sigma_h beyond their seeds: tiles that near the support still count.
    lo_b, hi_b = lo_b - 5 * ex.lobes.sigma_h, hi_b + 5 * ex.lobes.sigma_h
    if lookup == "paper":
        if not paper_uses_lobes(cov):
            return _paper_pndf(ex, c, cov, s_local, lo_b, hi_b, owned)
        level = -1
    else:
        level = lod_level(ex, cov)
    side = 2 << max(level, 0)
    r = ex.n // side
    t0 = np.maximum(np.floor(lo_b / side).astype(int), 0)
    t1 = np.minimum(np.floor(hi_b / side).astype(int), r - 1)
    out = np.zeros(len(s_local))
    if np.any(t1 < t0):
        return out
    tiles = [(tx, ty) for ty in range(t0[1], t1[1] + 1) for tx in range(t0[0], t1[0] + 1)]
    if level < 0:
        idx = np.concatenate([ex.tile_lobes(tx, ty) for tx, ty in tiles])
        if owned is not None:
            idx = idx[owned(ex.lobes.u[idx])]
        return pndf(ex.lobes, c, cov, s_local, index=idx) if len(idx) else out
    centres = (np.array(tiles, dtype=np.float64) + 0.5) * side
    keep = owned(centres) if owned is not None else np.ones(len(tiles), dtype=bool)
    for (tx, ty), k in zip(tiles, keep, strict=True):
        if k:
            lo = np.array([tx, ty], dtype=np.float64) * side
            out += box_mass(c, cov, lo, lo + side) * ex.lookup(level, tx, ty, s_local)
    return out


def _tiled_copies(lo: np.ndarray, hi: np.ndarray, n: int) -> list[tuple[int, int]]:
    k0 = np.floor(lo / n).astype(int)
    k1 = np.floor(hi / n).astype(int)
    return [(kx, ky) for ky in range(k0[1], k1[1] + 1) for kx in range(k0[0], k1[0] + 1)]


def tiny_pndf(
    ex: TinyExample,
    surface: Surface,
    centre: np.ndarray,
    cov: np.ndarray,
    s: np.ndarray,
    *,
    lookup: str = "flat",
) -> np.ndarray:
    """The tiny-example P-NDF of ``surface`` (whose example ``ex`` describes) at global
    projected normals ``s`` ``(M, 2)``, footprint ``N(centre, cov)`` in global texels;
    ``lookup`` the rule (:data:`LOOKUPS`, module docstring)."""
    centre = np.asarray(centre, dtype=np.float64)
    cov = np.asarray(cov, dtype=np.float64)
    s = np.asarray(s, dtype=np.float64)
    n = ex.n
    if surface.dist.kind == "tiled":
        t = surface.dist.transform
        ainv = t.inverse
        c_l, cov_l = ainv @ centre, ainv @ cov @ ainv.T
        s_l = t.slopes_to_local(s)
        lo, hi = _bbox(c_l, cov_l)
        out = np.zeros(len(s))
        for kx, ky in _tiled_copies(lo, hi, n):
            out += instance_pndf(ex, c_l - np.array([kx, ky]) * n, cov_l, s_l, lookup=lookup)
        return t.density_scale * out
    lo, hi = _bbox(centre, cov)
    out = np.zeros(len(s))
    for inst in surface.instances_near(lo, hi):
        out += _stochastic_instance(ex, surface, inst, centre, cov, s, lookup)
    return out


def _stochastic_instance(
    ex: TinyExample,
    surface: Surface,
    inst: Instance,
    centre: np.ndarray,
    cov: np.ndarray,
    s: np.ndarray,
    lookup: str = "flat",
) -> np.ndarray:
    t: Transform = inst.transform
    ainv = t.inverse
    c_l = (centre - inst.centre) @ ainv.T + 0.5 * ex.n
    cov_l = ainv @ cov @ ainv.T
    lo, hi = _bbox(c_l, cov_l)
    if np.any(hi <= 0) or np.any(lo >= ex.n):
        return np.zeros(len(s))

    def owned(p_local: np.ndarray) -> np.ndarray:
        glob = (p_local - 0.5 * ex.n) @ t.a.T + inst.centre
        mask = np.zeros(len(glob), dtype=bool)
        for other, m in surface.owner(glob):
            if np.allclose(other.centre, inst.centre):
                mask |= m
        return mask

    s_l = t.slopes_to_local(s)
    return t.density_scale * instance_pndf(ex, c_l, cov_l, s_l, owned=owned, lookup=lookup)


def yan_pndf(lobes: Lobes, centre: np.ndarray, cov: np.ndarray, s: np.ndarray) -> np.ndarray:
    """The reference: Eq. 1 over every lobe of an explicit, tiled normal map whose seed lies
    in the footprint's support box (plus ``5 sigma_h``), all periodic copies included."""
    centre = np.asarray(centre, dtype=np.float64)
    cov = np.asarray(cov, dtype=np.float64)
    lo, hi = _bbox(centre, cov)
    lo, hi = lo - 5 * lobes.sigma_h, hi + 5 * lobes.sigma_h
    n = lobes.size
    idx_all, shift_all = [], []
    for kx, ky in _tiled_copies(lo, hi, n):
        shift = np.array([kx, ky], dtype=np.float64) * n
        u = lobes.u + shift
        sel = np.flatnonzero(np.all((u >= lo) & (u <= hi), axis=1))
        idx_all.append(sel)
        shift_all.append(np.broadcast_to(shift, (len(sel), 2)))
    idx = np.concatenate(idx_all)
    if not len(idx):
        return np.zeros(len(s))
    return pndf(lobes, centre, cov, s, index=idx, shift=np.concatenate(shift_all))
