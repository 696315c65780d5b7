"""Yan et al. 2016's hierarchical P-NDF evaluation: Eq. 1 over the lobes of an explicit
normal map, skipping every block of texels that cannot reach the query.

The brute force (:func:`materials.glints.pndf_drjit.lobes_pndf`) sums Eq. 1 over every
lobe whose texel lies in the footprint's support box (:data:`SUPPORT_SIGMAS` plus
``5 sigma_h``). This evaluation sums the same box, but walks a min-max hierarchy over
blocks of texels and descends only into blocks that meet the box and whose **normal
bounds** hold the query ``q`` (Yan et al. 2016: a 4D bounding-box hierarchy over
the lobes' positions and Jacobian-linearised normals).

**What is bounded.** Given a footprint ``N(c, P)``, lobe ``i``'s term of Eq. 1 is
``w g_i N(q; mu_i, C_i)`` with ``mu_i = s_i + J_i delta_i``, ``delta_i = m_i - u_i =
sigma_h^2 (P + sigma_h^2 I)^-1 (c - u_i)`` and ``C_i = sigma_r^2 I + J_i S J_i^T``,
``S = (I / sigma_h^2 + P^-1)^-1`` (:mod:`materials.glints.lobes`). Two bounds make a
block test exact for every lobe of the box:

- ``|delta_i| <= Delta = sigma_h^2 / (sigma_h^2 + lambda_min(P)) |c - u_i|_max`` (the
  matrix's norm is that ratio), with ``|c - u_i|_max`` the farthest corner of the box
  from ``c``: per query, so ``|(J_i delta_i)_a| <= (|J_a0| + |J_a1|) Delta``;
- ``lambda_max(C_i) <= sigma_n,i^2 = sigma_r^2 + sigma_h^2 |J_i|_F^2`` (``S <=
  sigma_h^2 I``): per lobe, footprint-free.

Each node stores, over its lobes, ``min (s_i - k sigma_n,i)``, ``max (s_i + k sigma_n,i)``
per axis and ``max (|J_a0| + |J_a1|)`` per row ``a`` (``k`` :data:`TRUNCATION_SIGMAS`),
so a node whose box ``[lo - j Delta, hi + j Delta]`` misses ``q`` holds only lobes with
``|q - mu_i| > k sigma_n,i``, i.e. ``(q - mu_i)^T C_i^-1 (q - mu_i) > k^2``.

**What is dropped.** Each skipped term is below ``exp(-k^2 / 2)`` of its own peak
``w g_i / (2 pi sqrt(det C_i))``, so ``|D_hier - D_brute| <= exp(-k^2 / 2) B`` with
``B = sum_i w g_i / (2 pi sqrt(det C_i))`` over the box (:func:`truncation_bound`, the test's
tolerance). At ``k = 5`` the factor is ``3.7e-6``, the size of float32 rounding in a sum of
a few thousand terms.

**Layout.** Level 0 holds blocks of 2 x 2 texels; level ``l`` blocks of ``2^(l+1)``; the
grid is padded to a power of two with empty blocks (bounds that hold nothing), so a map of
any side ``n`` works. The map tiles (period ``n``): the walk's roots are, for each periodic
copy of the map that meets the box, the (at most 2 x 2) blocks of the coarsest level whose
side is at least the box's; a stackless depth-first walk below each root (a Morton code
and a level per lane) finds the next leaf that passes, whose texels in the box are then
summed. Building the bounds (:func:`build_bounds`, numpy) is precompute.
"""

from __future__ import annotations

import math
import types
from dataclasses import dataclass
from typing import Any

import numpy as np

from materials.glints.footprint import SUPPORT_SIGMAS
from materials.glints.lobes import Lobes
from materials.glints.pndf_drjit import JitLobes, Sym2, lobe_terms

#: ``k``: a block is skipped when the query lies beyond ``k`` of its lobes' normal
#: standard deviations (module docstring: the dropped mass is below ``exp(-k^2 / 2)``).
TRUNCATION_SIGMAS = 5.0
#: Texels per side of a level-0 block.
LEAF = 2
#: Bounds per node: ``lo_x, lo_y, hi_x, hi_y, j_x, j_y`` (float32).
NODE_FLOATS = 6

__all__ = [
    "LEAF",
    "TRUNCATION_SIGMAS",
    "JitBounds",
    "NormalBounds",
    "bounds_bytes",
    "build_bounds",
    "hier_pndf",
    "hier_pndf_stats",
    "jit_bounds",
    "truncation_bound",
]

_SUPPORT = SUPPORT_SIGMAS  # the box is the brute force's (lobe_terms)


@dataclass(frozen=True)
class NormalBounds:
    """The min-max hierarchy of a map's lobes (numpy, float32, rounded outwards).

    ``levels[l]`` is ``(6, g_l, g_l)`` indexed ``[field, by, bx]`` (fields as
    :data:`NODE_FLOATS`), ``g_l = g_0 / 2^l`` blocks per side, ``g_0`` a power of two
    with ``LEAF g_0 >= n``; blocks beyond the map hold ``lo = +inf``, ``hi = -inf``."""

    n: int
    sigmas: float
    leaf: int
    levels: list[np.ndarray]

    @property
    def nbytes(self) -> int:
        return int(sum(a.size * 4 for a in self.levels))


def bounds_bytes(n: int, leaf: int = LEAF) -> int:
    """Bytes of :func:`build_bounds`'s hierarchy for an ``n``-texel map (float32)."""
    g = 1 << max(0, math.ceil(math.log2(math.ceil(n / leaf))))
    nodes = 0
    while g:
        nodes, g = nodes + g * g, g // 2
    return 4 * NODE_FLOATS * nodes


def _round_out(x: np.ndarray, up: bool) -> np.ndarray:
    """float64 to float32, rounded towards ``+inf`` (``up``) or ``-inf``."""
    y = x.astype(np.float32)
    if up:
        return np.where(y.astype(np.float64) < x, np.nextafter(y, np.float32(np.inf)), y)
    return np.where(y.astype(np.float64) > x, np.nextafter(y, np.float32(-np.inf)), y)


def build_bounds(
    lobes: Lobes, *, sigmas: float = TRUNCATION_SIGMAS, leaf: int = LEAF, rows: int = 256
) -> NormalBounds:
    """The hierarchy of ``lobes`` (texel-major, :func:`~materials.glints.lobes.make_lobes`),
    ``sigmas`` the truncation ``k``; ``rows`` texel rows are reduced at a time (peak
    memory)."""
    if not sigmas > 0:
        raise ValueError(f"the truncation must be > 0 standard deviations, got {sigmas}")
    n, k2 = lobes.size, lobes.rate * lobes.rate
    if len(lobes) != n * n * k2:
        raise ValueError(f"expected {n * n * k2} texel-major lobes, got {len(lobes)}")
    if leaf not in (1, 2, 4):
        raise ValueError(f"the leaf block side must be 1, 2 or 4 texels, got {leaf}")
    g0 = 1 << max(0, math.ceil(math.log2(math.ceil(n / leaf))))
    side = leaf * g0
    texel = np.empty((NODE_FLOATS, side, side))
    texel[0:2] = np.inf
    texel[2:4] = -np.inf
    texel[4:6] = 0.0
    rows = max(1, int(rows))
    for y0 in range(0, n, rows):
        y1 = min(n, y0 + rows)
        sl = slice(y0 * n * k2, y1 * n * k2)
        s = lobes.s[sl].reshape(y1 - y0, n, k2, 2)
        jac = lobes.jac[sl].reshape(y1 - y0, n, k2, 2, 2)
        reach = sigmas * np.sqrt(lobes.sigma_r**2 + lobes.sigma_h**2 * np.sum(jac * jac, axis=-1))
        texel[0:2, y0:y1, :n] = np.moveaxis((s - reach).min(axis=2), -1, 0)
        texel[2:4, y0:y1, :n] = np.moveaxis((s + reach).max(axis=2), -1, 0)
        texel[4:6, y0:y1, :n] = np.moveaxis(np.abs(jac).sum(axis=-1).max(axis=2), -1, 0)
    out = []
    level, f = texel, leaf
    for _ in range(int(math.log2(g0)) + 1):
        g = level.shape[1] // f
        blocks = level.reshape(NODE_FLOATS, g, f, g, f)
        f = 2
        level = np.concatenate([blocks[0:2].min(axis=(2, 4)), blocks[2:6].max(axis=(2, 4))], axis=0)
        out.append(
            np.concatenate([_round_out(level[0:2], up=False), _round_out(level[2:6], up=True)])
        )
    return NormalBounds(n=n, sigmas=float(sigmas), leaf=int(leaf), levels=out)


@dataclass(frozen=True)
class JitBounds:
    """:class:`NormalBounds` as Dr.Jit arrays: one array per field over all levels,
    level ``l`` from ``offsets[l]``, ``sides[l]`` blocks per side."""

    n: int
    sigmas: float
    leaf: int
    sides: tuple[int, ...]
    offsets: Any  # mi.UInt32 per level
    arrays: tuple[Any, ...]  # lo_x, lo_y, hi_x, hi_y, j_x, j_y
    nbytes: int

    @property
    def levels(self) -> int:
        return len(self.sides)


def jit_bounds(mi: types.ModuleType, bounds: NormalBounds) -> JitBounds:
    """Upload ``bounds``."""
    sizes = [a.shape[1] * a.shape[2] for a in bounds.levels]
    offsets = np.cumsum([0] + sizes[:-1]).astype(np.uint32)
    arrays = tuple(
        mi.Float(np.concatenate([a[f].ravel() for a in bounds.levels]).astype(np.float32))
        for f in range(NODE_FLOATS)
    )
    return JitBounds(
        n=bounds.n,
        sigmas=bounds.sigmas,
        leaf=bounds.leaf,
        sides=tuple(int(a.shape[1]) for a in bounds.levels),
        offsets=mi.UInt32(offsets),
        arrays=arrays,
        nbytes=bounds.nbytes,
    )


def _compact(dr: Any, m: Any) -> Any:
    """The even bits of ``m`` (UInt32), packed: one coordinate of a Morton code."""
    x = m & 0x55555555
    x = (x | (x >> 1)) & 0x33333333
    x = (x | (x >> 2)) & 0x0F0F0F0F
    x = (x | (x >> 4)) & 0x00FF00FF
    return (x | (x >> 8)) & 0x0000FFFF


def _walk(
    mi: types.ModuleType,
    lobes: JitLobes,
    bounds: JitBounds,
    c: tuple[Any, Any],
    cov: Sym2,
    q: tuple[Any, Any],
    active: Any,
    max_items: int,
) -> tuple[Any, Any, Any]:
    """``(sum, nodes, leaves)``: Eq. 1's sum (before the lobe weight) over the lobes the
    walk reaches, and per lane the nodes tested and the leaves summed."""
    import drjit as dr

    if bounds.n != lobes.n:
        raise ValueError(f"bounds of a {bounds.n}-texel map for lobes of {lobes.n}")
    n, k2 = lobes.n, lobes.rate * lobes.rate
    terms = lobe_terms(mi, lobes, c, cov, active, max_items)
    x0, y0 = terms.x0, terms.y0
    x1, y1 = x0 + terms.nx - 1, y0 + terms.ny - 1
    cx, cy = c
    qx, qy = q
    # Delta: the largest lobe shift |m_i - u_i| over the box (module docstring).
    h2 = lobes.sigma_h**2
    lam = 0.5 * (cov.a + cov.d) - dr.sqrt(
        dr.maximum(dr.square(0.5 * (cov.a - cov.d)) + cov.b * cov.b, 0.0)
    )
    far_x = dr.maximum(cx - mi.Float(x0), mi.Float(x1 + 1) - cx)
    far_y = dr.maximum(cy - mi.Float(y0), mi.Float(y1 + 1) - cy)
    delta = h2 / (h2 + dr.maximum(lam, 0.0)) * dr.sqrt(far_x * far_x + far_y * far_y)
    delta = delta * (1.0 + 1e-5) + 1e-6  # float32 slack on the shift bound

    def fdiv(i: Any, d: int) -> Any:
        return mi.Int32(dr.floor(mi.Float(i) / float(d)))

    kx0, ky0 = fdiv(x0, n), fdiv(y0, n)
    ncx = fdiv(x1, n) - kx0 + 1
    ncy = fdiv(y1, n) - ky0 + 1
    top = bounds.levels - 1
    # Root level: the coarsest needed, blocks of 2^(l0+1) >= the box's width.
    leaf = bounds.leaf
    lsh = leaf.bit_length() - 1  # texels per level-l block: 2^(l + lsh)
    width = mi.Float(dr.maximum(terms.nx, terms.ny))
    l0 = mi.Int32(dr.ceil(dr.log2(dr.maximum(width / leaf, 1.0))))
    l0 = dr.select(mi.Int32(leaf) << l0 < mi.Int32(width), l0 + 1, l0)
    l0 = dr.clip(l0, 0, top)
    nroots = dr.select(terms.count > 0, ncx * ncy * 4, 0)
    lo_x, lo_y, hi_x, hi_y, j_x, j_y = bounds.arrays
    g0 = bounds.sides[0]

    def root(j: Any) -> tuple[Any, ...]:
        """Root ``j``'s copy origin ``(ox, oy)``, block ``(rx, ry)`` at ``l0``, validity."""
        ci = j >> 2
        kx = kx0 + ci % ncx
        ky = ky0 + ci // ncx
        ox, oy = kx * n, ky * n
        lx0 = dr.maximum(x0 - ox, 0)
        ly0 = dr.maximum(y0 - oy, 0)
        lx1 = dr.minimum(x1 - ox, n - 1)
        ly1 = dr.minimum(y1 - oy, n - 1)
        sh = l0 + lsh
        rx = (lx0 >> sh) + (j & 1)
        ry = (ly0 >> sh) + ((j >> 1) & 1)
        ok = ((rx << sh) <= lx1) & ((ry << sh) <= ly1) & (lx0 <= lx1) & (ly0 <= ly1)
        return ox, oy, rx, ry, ok

    def step(j: Any, lvl: Any, m: Any) -> tuple[Any, ...]:
        """Test node ``(j, lvl, m)``; returns the next state and a found leaf."""
        ox, oy, rx, ry, ok = root(j)
        d = mi.UInt32(l0 - lvl)
        bx = mi.Int32((mi.UInt32(rx) << d) | _compact(dr, m))
        by = mi.Int32((mi.UInt32(ry) << d) | _compact(dr, m >> 1))
        sh = lvl + lsh
        tx0, ty0 = ox + (bx << sh), oy + (by << sh)
        tx1, ty1 = tx0 + (mi.Int32(1) << sh) - 1, ty0 + (mi.Int32(1) << sh) - 1
        ok &= (tx0 <= x1) & (tx1 >= x0) & (ty0 <= y1) & (ty1 >= y0)
        side = mi.Int32(g0) >> lvl
        idx = dr.gather(mi.UInt32, bounds.offsets, mi.UInt32(lvl), ok)
        idx = idx + mi.UInt32(by * side + bx)
        jx = dr.gather(mi.Float, j_x, idx, ok) * delta
        jy = dr.gather(mi.Float, j_y, idx, ok) * delta
        ok &= qx >= dr.gather(mi.Float, lo_x, idx, ok) - jx
        ok &= qx <= dr.gather(mi.Float, hi_x, idx, ok) + jx
        ok &= qy >= dr.gather(mi.Float, lo_y, idx, ok) - jy
        ok &= qy <= dr.gather(mi.Float, hi_y, idx, ok) + jy
        leaf = ok & (lvl == 0)
        down = ok & (lvl > 0)
        # Next in depth-first order: the next sibling, popping finished parents.
        at_root = lvl == l0
        m1 = m + 1
        t = dr.minimum(mi.Int32(dr.tzcnt(m1) >> 1), l0 - lvl)
        m2 = m1 >> mi.UInt32(2 * t)
        lvl2 = lvl + t
        done = at_root | (lvl2 == l0)
        nj = dr.select(~down & done, j + 1, j)
        nlvl = dr.select(down, lvl - 1, dr.select(done, l0, lvl2))
        nm = dr.select(down, m << 2, dr.select(done, 0, m2))
        return nj, nlvl, nm, leaf, tx0, ty0, ox, oy

    zero_i = dr.zeros(mi.Int32)

    def outer(j: Any, lvl: Any, m: Any, acc: Any, nodes: Any, leaves: Any) -> tuple[Any, ...]:
        def inner(j: Any, lvl: Any, m: Any, found: Any, lx: Any, ly: Any, ox: Any,
                  oy: Any, nodes: Any) -> tuple[Any, ...]:  # fmt: skip
            nj, nlvl, nm, leaf, tx0, ty0, sox, soy = step(j, lvl, m)
            return (
                nj, nlvl, nm, leaf, dr.select(leaf, tx0, lx), dr.select(leaf, ty0, ly),
                dr.select(leaf, sox, ox), dr.select(leaf, soy, oy), nodes + 1,
            )  # fmt: skip

        state = (j, lvl, m, mi.Bool(False), zero_i, zero_i, zero_i, zero_i, nodes)
        j, lvl, m, found, lx, ly, ox, oy, nodes = dr.while_loop(
            state, lambda j, lvl, m, found, *rest: (j < nroots) & ~found, inner,
            label="glint: yan walk",
        )  # fmt: skip
        for dy in range(leaf):
            for dx in range(leaf):
                tx, ty = lx + dx, ly + dy
                on = found & (tx <= x1) & (ty <= y1) & (tx >= x0) & (ty >= y0)
                on &= (tx - ox < n) & (ty - oy < n)
                for k in range(k2):
                    g, mean_x, mean_y, ncov = terms.at(tx, ty, k)
                    ninv = ncov.inverse(dr)
                    nnorm = dr.rcp(2.0 * math.pi * dr.sqrt(ncov.det()))
                    ex = qx - mean_x
                    ey = qy - mean_y
                    term = g * nnorm * dr.exp(-0.5 * ninv.quad(ex, ey))
                    acc += dr.select(on, term, 0.0)
        return j, lvl, m, acc, nodes, leaves + dr.select(found, 1, 0)

    state = (zero_i, l0, dr.zeros(mi.UInt32), dr.zeros(mi.Float), zero_i, zero_i)
    _, _, _, acc, nodes, leaves = dr.while_loop(
        state, lambda j, lvl, m, acc, nodes, leaves: (j < nroots) & (leaves < max_items),
        outer, label="glint: yan leaves",
    )  # fmt: skip
    return acc, nodes, leaves


def hier_pndf(
    mi: types.ModuleType,
    lobes: JitLobes,
    bounds: JitBounds,
    c: tuple[Any, Any],
    cov: Sym2,
    q: tuple[Any, Any],
    active: Any = True,
    *,
    max_items: int = 1 << 16,
) -> Any:
    """Eq. 1 at ``q`` for the footprint ``N(c, cov)`` (map texels), the twin of
    :func:`~materials.glints.pndf_drjit.lobes_pndf` walking ``bounds`` (of the same
    lobes); at most ``max_items`` leaf blocks per lane."""
    return lobes.weight * _walk(mi, lobes, bounds, c, cov, q, active, max_items)[0]


def hier_pndf_stats(
    mi: types.ModuleType,
    lobes: JitLobes,
    bounds: JitBounds,
    c: tuple[Any, Any],
    cov: Sym2,
    q: tuple[Any, Any],
    active: Any = True,
    *,
    max_items: int = 1 << 16,
) -> tuple[Any, Any, Any]:
    """:func:`hier_pndf` and, per lane, the nodes it tested and the leaf blocks it summed."""
    acc, nodes, leaves = _walk(mi, lobes, bounds, c, cov, q, active, max_items)
    return lobes.weight * acc, nodes, leaves


def truncation_bound(lobes: Lobes, centre: np.ndarray, cov: np.ndarray, sigmas: float) -> float:
    """``exp(-k^2 / 2) B`` (module docstring): the most the hierarchy may drop at any query
    for the footprint ``N(centre, cov)`` (map texels), ``B`` summed in float64 over the
    brute force's box (every periodic copy)."""
    c = np.asarray(centre, dtype=np.float64)
    p = np.asarray(cov, dtype=np.float64)
    n, h2 = lobes.size, lobes.sigma_h**2
    reach = 5.0 * lobes.sigma_h
    half = _SUPPORT * np.sqrt(np.diag(p)) + reach
    lo = np.floor(c - half).astype(int)
    hi = np.floor(c + half).astype(int)
    gx, gy = np.meshgrid(np.arange(lo[0], hi[0] + 1), np.arange(lo[1], hi[1] + 1))
    tx, ty = gx.ravel(), gy.ravel()
    k2 = lobes.rate * lobes.rate
    base = ((ty % n) * n + (tx % n)) * k2
    idx = (base[:, None] + np.arange(k2)[None]).ravel()
    shift = np.repeat(np.stack([tx - tx % n, ty - ty % n], axis=1), k2, axis=0)
    u = lobes.u[idx] + shift
    m_cov = p + h2 * np.eye(2)
    d = c - u
    inv = np.linalg.inv(m_cov)
    g = np.exp(-0.5 * np.einsum("ka,ab,kb->k", d, inv, d)) / (
        2 * math.pi * math.sqrt(np.linalg.det(m_cov))
    )
    s_mat = np.linalg.inv(np.eye(2) / h2 + np.linalg.inv(p))
    jac = lobes.jac[idx]
    ncov = lobes.sigma_r**2 * np.eye(2) + np.einsum("kab,bc,kdc->kad", jac, s_mat, jac)
    peak = 1.0 / (2 * math.pi * np.sqrt(np.linalg.det(ncov)))
    return float(math.exp(-0.5 * sigmas * sigmas) * lobes.weight * np.sum(g * peak))
