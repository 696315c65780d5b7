"""Dr.Jit twins of the P-NDF evaluators of :mod:`materials.glints.footprint`.

The same formulas, traced into one kernel per call (the glint BSDF traces them into the
render kernel): ``lobes_pndf`` is Eq. 1 summed over the lobes of the texels in the
footprint's support box (the Yan et al. reference on an explicit map, and the tiny-example
model below its finest tiles); ``tiny_pndf`` is the tiny-example model over a tiled example
under a transform, at :func:`~materials.glints.footprint.lod_level`'s level. Loops are
symbolic ``dr.while_loop`` over a per-lane count of texels or tiles, so each SIMD packet
runs as long as its widest footprint needs. A lane's work is capped (``max_items``): beyond
it the footprint is truncated, and the cap is reported by the benchmarks, not hidden.

Differences from the numpy reference, both small: a tile's footprint mass is a 2 x 2
Gauss-Legendre product rule (the tile is at most half a standard deviation wide, so the
rule's error is below 1e-5) instead of the 8-node quadrature, and arithmetic is float32.

``lookup="paper"`` (:func:`materials.glints.footprint.paper_tiles`, the paper's descent) is
traced as one loop over the finest tiles of the support box: each finds its coarsest
covered ancestor (levels unrolled), the ancestor's lower-left finest tile reads it and its
other finest tiles add nothing, and an uncovered tile reads itself. So it reads the same
tiles as the numpy descent but does not visit fewer; its masses are exact in y (normal CDF)
and 4-node Gauss-Legendre in x, since its tiles reach 2 standard deviations.

Every argument named ``mi`` is the module of :func:`materials.backend.load_mitsuba` with a
vectorised variant; positions are texels of the map (or example), ``q`` the query's
projected normal.
"""

from __future__ import annotations

import math
import types
from dataclasses import dataclass
from typing import Any

import numpy as np

from materials.glints.footprint import COVER_SIGMAS, FLATNESS, LOOKUPS, SUPPORT_SIGMAS
from materials.glints.lobes import Lobes

#: Gauss-Legendre nodes of the 2 x 2 rule on [-1, 1].
_GL2 = 1.0 / math.sqrt(3.0)


@dataclass(frozen=True)
class JitLobes:
    """Lobes as Dr.Jit arrays, texel-major (texel y, texel x, sub y, sub x), so the
    ``rate^2`` lobes of texel ``(x, y)`` start at ``(y n + x) rate^2``."""

    n: int
    rate: int
    sigma_h: float
    sigma_r: float
    weight: float
    arrays: tuple[Any, ...]  # ux, uy, sx, sy, j00, j01, j10, j11

    @property
    def nbytes(self) -> int:
        return int(8 * 4 * self.n * self.n * self.rate * self.rate)


def jit_lobes(mi: types.ModuleType, lobes: Lobes) -> JitLobes:
    """Upload ``lobes`` (from :func:`~materials.glints.lobes.make_lobes`, texel-major)."""
    cols = [
        lobes.u[:, 0],
        lobes.u[:, 1],
        lobes.s[:, 0],
        lobes.s[:, 1],
        lobes.jac[:, 0, 0],
        lobes.jac[:, 0, 1],
        lobes.jac[:, 1, 0],
        lobes.jac[:, 1, 1],
    ]
    return JitLobes(
        n=lobes.size,
        rate=lobes.rate,
        sigma_h=lobes.sigma_h,
        sigma_r=lobes.sigma_r,
        weight=lobes.weight,
        arrays=tuple(mi.Float(np.ascontiguousarray(c, dtype=np.float32)) for c in cols),
    )


@dataclass(frozen=True)
class JitMaps:
    """All levels of the NDF maps in one Dr.Jit array; ``offsets[l]`` is where level ``l``
    starts, ``tiles[l]`` its ``r``."""

    data: Any
    offsets: Any  # mi.UInt32 per level
    tiles: tuple[int, ...]
    resolution: int
    extent: float
    n: int

    @property
    def levels(self) -> int:
        return len(self.tiles)


def jit_maps(mi: types.ModuleType, maps: list[np.ndarray], extent: float) -> JitMaps:
    """Upload the maps of :func:`~materials.glints.ndf_maps.ndf_maps`."""
    flat = np.concatenate([m.astype(np.float32).ravel() for m in maps])
    offsets = np.cumsum([0] + [m.size for m in maps[:-1]]).astype(np.uint32)
    return JitMaps(
        data=mi.Float(flat),
        offsets=mi.UInt32(offsets),
        tiles=tuple(int(m.shape[0]) for m in maps),
        resolution=int(maps[0].shape[-1]),
        extent=float(extent),
        n=int(maps[0].shape[0]) * 2,
    )


@dataclass
class Sym2:
    """A symmetric 2 x 2 matrix of per-lane floats ``[[a, b], [b, d]]``."""

    a: Any
    b: Any
    d: Any

    def det(self) -> Any:
        return self.a * self.d - self.b * self.b

    def inverse(self, dr: Any) -> Sym2:
        r = dr.rcp(self.det())
        return Sym2(self.d * r, -self.b * r, self.a * r)

    def quad(self, x: Any, y: Any) -> Any:
        """``(x, y) M (x, y)^T``."""
        return self.a * x * x + 2.0 * self.b * x * y + self.d * y * y


def _gauss(dr: Any, inv: Sym2, norm: Any, x: Any, y: Any) -> Any:
    return norm * dr.exp(-0.5 * inv.quad(x, y))


def _pmod(mi: types.ModuleType, dr: Any, i: Any, n: int) -> Any:
    """``i mod n`` in ``[0, n)`` for Int32 ``i`` (negative too)."""
    q = mi.Int32(dr.floor(mi.Float(i) / float(n)))
    return i - q * n


def lobes_pndf(
    mi: types.ModuleType,
    lobes: JitLobes,
    c: tuple[Any, Any],
    cov: Sym2,
    q: tuple[Any, Any],
    active: Any = True,
    *,
    max_items: int = 1 << 16,
) -> Any:
    """Eq. 1 over the lobes of every texel (tiled with period ``n``) whose seeds may reach
    the footprint ``N(c, cov)``: the support box at :data:`SUPPORT_SIGMAS` plus
    ``5 sigma_h``. At most ``max_items`` texels per lane."""
    import drjit as dr

    terms = lobe_terms(mi, lobes, c, cov, active, max_items)
    count, lobe = terms.count, terms.lobe
    k2 = lobes.rate * lobes.rate
    qx, qy = q

    def body(i: Any, acc: Any) -> tuple[Any, Any]:
        for j in range(k2):
            g, mean_x, mean_y, ncov = lobe(i, j)
            ninv = ncov.inverse(dr)
            nnorm = dr.rcp(2.0 * math.pi * dr.sqrt(ncov.det()))
            acc += g * _gauss(dr, ninv, nnorm, qx - mean_x, qy - mean_y)
        return i + 1, acc

    _, acc = dr.while_loop(
        (mi.Int32(0), dr.zeros(mi.Float)),
        lambda i, acc: i < count,
        body,
        label="glint: lobes",
    )
    return lobes.weight * acc


#: Gauss-Legendre nodes and weights on [-1, 1] of the paper lookup's tile masses.
_GL4 = tuple(tuple(float(v) for v in a) for a in np.polynomial.legendre.leggauss(4))


def _box_mass(dr: Any, cov: Sym2, ox: Any, oy: Any, side: Any) -> Any:
    """``int N(u; 0, cov)`` over ``[ox, ox + side] x [oy, oy + side]``: exact in y (normal
    CDF of y given x), 4-node Gauss-Legendre in x."""
    sx = dr.sqrt(cov.a)
    beta = cov.b / cov.a
    sd = dr.sqrt(dr.maximum(cov.d - beta * cov.b, 1e-30))
    inv_sd = dr.rcp(sd) * (1.0 / math.sqrt(2.0))
    norm = dr.rcp(sx * math.sqrt(2.0 * math.pi))
    half = 0.5 * side
    mass = dr.zeros(type(ox))
    for node, weight in zip(*_GL4, strict=True):
        x = ox + half * (1.0 + node)
        my = beta * x
        band = dr.erf((oy + side - my) * inv_sd) - dr.erf((oy - my) * inv_sd)
        mass += weight * norm * dr.exp(-0.5 * x * x / cov.a) * (0.5 * band)
    return half * mass


def _local_footprint(ai: np.ndarray, c: tuple[Any, Any], cov: Sym2) -> tuple[Any, Any, Sym2]:
    """The footprint in the example's local frame, ``ai = A^-1``: ``c_l = A^-1 c`` and
    ``Sigma_l = A^-1 Sigma A^-T``, as ``(c_lx, c_ly, Sigma_l)``."""
    clx = float(ai[0, 0]) * c[0] + float(ai[0, 1]) * c[1]
    cly = float(ai[1, 0]) * c[0] + float(ai[1, 1]) * c[1]
    r00, r01, r10, r11 = (float(v) for v in ai.ravel())
    a = r00 * r00 * cov.a + 2 * r00 * r01 * cov.b + r01 * r01 * cov.d
    b = r00 * r10 * cov.a + (r00 * r11 + r01 * r10) * cov.b + r01 * r11 * cov.d
    d = r10 * r10 * cov.a + 2 * r10 * r11 * cov.b + r11 * r11 * cov.d
    return clx, cly, Sym2(a, b, d)


def _flat_level(mi: types.ModuleType, dr: Any, cl: Sym2, levels: int) -> tuple[Any, Any, Any]:
    """``(lambda_min, target, level)`` of the local footprint ``cl`` (lod_level): the
    coarsest level with tile side ``2^(l+1) <= target = FLATNESS sigma_min``."""
    half_tr = 0.5 * (cl.a + cl.d)
    lam = half_tr - dr.sqrt(dr.maximum(dr.square(0.5 * (cl.a - cl.d)) + cl.b * cl.b, 0.0))
    target = FLATNESS * dr.sqrt(dr.maximum(lam, 1e-30))
    level = dr.minimum(mi.Int32(dr.floor(dr.log2(dr.maximum(target, 1e-30)))) - 1, levels - 1)
    return lam, target, level


@dataclass(frozen=True)
class _TileGrid:
    """The tiles of level ``lv`` (side ``side`` texels, ``r`` per period of the example)
    that the local footprint ``N((clx, cly), Sigma_l)`` may reach: the support box at
    :data:`SUPPORT_SIGMAS` plus ``5 sigma_h``, ``nx`` per row from ``(t0x, t0y)``, ``count``
    of them (at most ``max_items``; 0 where the maps are not used); ``inv_l`` and
    ``norm_l``: the footprint Gaussian's inverse covariance and normalisation."""

    mi: types.ModuleType
    dr: Any
    clx: Any
    cly: Any
    lv: Any
    side: Any
    r: Any
    t0x: Any
    t0y: Any
    nx: Any
    count: Any
    inv_l: Sym2
    norm_l: Any

    def tile(self, i: Any) -> tuple[Any, Any]:
        """The ``i``-th tile's index ``(tx, ty)`` (not wrapped)."""
        return self.t0x + i % self.nx, self.t0y + i // self.nx

    def flat_mass(self, tx: Any, ty: Any) -> Any:
        """The tile's footprint mass: 2 x 2 Gauss-Legendre on ``[t side, (t + 1) side]^2``."""
        mi, dr, side = self.mi, self.dr, self.side
        ox = (mi.Float(tx) + 0.5) * side - self.clx
        oy = (mi.Float(ty) + 0.5) * side - self.cly
        d = 0.5 * side * _GL2
        mass = dr.zeros(mi.Float)
        for sx in (-d, d):
            for sy in (-d, d):
                mass += _gauss(dr, self.inv_l, self.norm_l, ox + sx, oy + sy)
        return mass * (0.25 * side * side)

    def wrap(self, tx: Any, ty: Any) -> tuple[Any, Any]:
        """The tile's index in the example's period: ``(tx mod r, ty mod r)``."""
        mi, dr, r = self.mi, self.dr, self.r
        wx = tx - r * mi.Int32(dr.floor(mi.Float(tx) / mi.Float(r)))
        wy = ty - r * mi.Int32(dr.floor(mi.Float(ty) / mi.Float(r)))
        return wx, wy


def _tile_grid(
    mi: types.ModuleType, maps: JitMaps, lobes: JitLobes, clx: Any, cly: Any, cl: Sym2,
    level: Any, use_maps: Any, max_items: int,
) -> _TileGrid:  # fmt: skip
    """The :class:`_TileGrid` of ``level`` (negative: the finest) for the local footprint
    ``N((clx, cly), cl)``, what :func:`tiny_pndf` and :func:`tiny_sample` loop over."""
    import drjit as dr

    lv = dr.maximum(level, 0)
    side = dr.exp2(mi.Float(lv + 1))
    r = mi.Int32(maps.n) // mi.Int32(side)
    reach = 5.0 * lobes.sigma_h
    hx = SUPPORT_SIGMAS * dr.sqrt(cl.a) + reach
    hy = SUPPORT_SIGMAS * dr.sqrt(cl.d) + reach
    t0x = mi.Int32(dr.floor((clx - hx) / side))
    t0y = mi.Int32(dr.floor((cly - hy) / side))
    nx = mi.Int32(dr.floor((clx + hx) / side)) - t0x + 1
    ny = mi.Int32(dr.floor((cly + hy) / side)) - t0y + 1
    count = dr.select(use_maps, dr.minimum(nx * ny, max_items), 0)
    inv_l = cl.inverse(dr)
    norm_l = dr.rcp(2.0 * math.pi * dr.sqrt(cl.det()))
    return _TileGrid(mi, dr, clx, cly, lv, side, r, t0x, t0y, nx, count, inv_l, norm_l)


def tiny_pndf(
    mi: types.ModuleType,
    maps: JitMaps,
    lobes: JitLobes,
    transform: tuple[np.ndarray, np.ndarray],
    c: tuple[Any, Any],
    cov: Sym2,
    q: tuple[Any, Any],
    active: Any = True,
    *,
    max_items: int = 1 << 16,
    lookup: str = "flat",
) -> Any:
    """The tiny-example P-NDF of a tiled example under ``transform = (A, o)``
    (:class:`~materials.glints.surface.Transform`): footprint ``N(c, cov)`` in global
    texels, query ``q`` global; the twin of :func:`materials.glints.footprint.tiny_pndf`
    for the tiled distribution, with its ``lookup`` rule."""
    import drjit as dr

    if lookup not in LOOKUPS:
        raise ValueError(f"lookup must be one of {LOOKUPS}, got {lookup!r}")

    a_mat, off = (np.asarray(x, dtype=np.float64) for x in transform)
    ai = np.linalg.inv(a_mat)
    det_a = float(abs(np.linalg.det(a_mat)))
    # Local frame: c_l = A^-1 c, Sigma_l = A^-1 Sigma A^-T, q_l = A^T (q - o).
    clx, cly, cl = _local_footprint(ai, c, cov)
    dqx, dqy = q[0] - float(off[0]), q[1] - float(off[1])
    qlx = float(a_mat[0, 0]) * dqx + float(a_mat[1, 0]) * dqy
    qly = float(a_mat[0, 1]) * dqx + float(a_mat[1, 1]) * dqy
    lam, target, level = _flat_level(mi, dr, cl, maps.levels)
    if lookup == "paper":  # footprint.paper_uses_lobes
        minor = 2.0 * COVER_SIGMAS * dr.sqrt(dr.maximum(lam, 0.0))
        use_maps = mi.Bool(active) & (minor >= 2.0)
        use_lobes = mi.Bool(active) & (minor < 2.0)
        level = dr.zeros(mi.Int32)
    else:
        use_maps = mi.Bool(active) & (target >= 2.0)
        use_lobes = mi.Bool(active) & (target < 2.0)

    from_lobes = lobes_pndf(mi, lobes, (clx, cly), cl, (qlx, qly), use_lobes, max_items=max_items)

    grid = _tile_grid(mi, maps, lobes, clx, cly, cl, level, use_maps, max_items)
    base = dr.gather(mi.UInt32, maps.offsets, mi.UInt32(grid.lv), use_maps)
    big_r = maps.resolution
    cell = 2.0 * maps.extent / big_r
    px = (qlx + maps.extent) / cell - 0.5
    py = (qly + maps.extent) / cell - 0.5
    ix0, iy0 = mi.Int32(dr.floor(px)), mi.Int32(dr.floor(py))
    fx, fy = px - dr.floor(px), py - dr.floor(py)
    corners = []
    for dy in (0, 1):
        for dx in (0, 1):
            ix, iy = ix0 + dx, iy0 + dy
            ok = (ix >= 0) & (ix < big_r) & (iy >= 0) & (iy < big_r)
            w = (fx if dx else 1.0 - fx) * (fy if dy else 1.0 - fy)
            corners.append((mi.UInt32(dr.select(ok, iy * big_r + ix, 0)), dr.select(ok, w, 0.0)))
    inv_l = grid.inv_l

    def paper_body(i: Any, acc: Any) -> tuple[Any, Any]:
        tx, ty = grid.tile(i)
        # The coarsest covered ancestor (covered is monotone: children of a covered tile
        # are covered), searched from the top; -1: the finest tile is not covered.
        found = mi.Int32(-1)
        ax, ay = mi.Int32(tx), mi.Int32(ty)
        k2 = COVER_SIGMAS * COVER_SIGMAS
        for m in range(maps.levels - 1, 0, -1):
            sm = float(2 << m)
            cx_m = mi.Int32(dr.floor(mi.Float(tx) / float(1 << m)))
            cy_m = mi.Int32(dr.floor(mi.Float(ty) / float(1 << m)))
            ox = mi.Float(cx_m) * sm - clx
            oy = mi.Float(cy_m) * sm - cly
            inside = mi.Bool(True)
            for ex_ in (0.0, sm):
                for ey_ in (0.0, sm):
                    inside &= inv_l.quad(ox + ex_, oy + ey_) <= k2
            take = (found < 0) & inside
            found = dr.select(take, m, found)
            ax = dr.select(take, cx_m, ax)
            ay = dr.select(take, cy_m, ay)
        lv_t = dr.maximum(found, 0)
        anchor = (tx == ax * (mi.Int32(1) << lv_t)) & (ty == ay * (mi.Int32(1) << lv_t))
        side_t = dr.exp2(mi.Float(lv_t + 1))
        mass = _box_mass(dr, cl, mi.Float(ax) * side_t - clx, mi.Float(ay) * side_t - cly, side_t)
        r_t = mi.Int32(maps.n) // mi.Int32(side_t)
        wx = ax - r_t * mi.Int32(dr.floor(mi.Float(ax) / mi.Float(r_t)))
        wy = ay - r_t * mi.Int32(dr.floor(mi.Float(ay) / mi.Float(r_t)))
        read = use_maps & ((found < 0) | anchor)
        base_t = dr.gather(mi.UInt32, maps.offsets, mi.UInt32(lv_t), read)
        img = base_t + mi.UInt32((wy * r_t + wx) * (big_r * big_r))
        value = dr.zeros(mi.Float)
        for idx, w in corners:
            value += w * dr.gather(mi.Float, maps.data, img + idx, read)
        return i + 1, acc + dr.select(read, mass * value, 0.0)

    def body(i: Any, acc: Any) -> tuple[Any, Any]:
        tx, ty = grid.tile(i)
        mass = grid.flat_mass(tx, ty)
        wx, wy = grid.wrap(tx, ty)
        img = base + mi.UInt32((wy * grid.r + wx) * (big_r * big_r))
        value = dr.zeros(mi.Float)
        for idx, w in corners:
            value += w * dr.gather(mi.Float, maps.data, img + idx)
        return i + 1, acc + mass * value

    _, acc = dr.while_loop(
        (mi.Int32(0), dr.zeros(mi.Float)),
        lambda i, acc: i < grid.count,
        paper_body if lookup == "paper" else body,
        label="glint: tiles",
    )
    return det_a * dr.select(use_maps, acc, from_lobes)


@dataclass(frozen=True)
class LobeTerms:
    """Eq. 1's terms for one footprint: the support box's texels ``x0 .. x0 + nx - 1`` by
    ``y0 .. y0 + ny - 1`` (global, not wrapped), ``count`` of them visited (at most
    ``max_items``; 0 where inactive), and ``at(tx, ty, j) -> (g, mean_x, mean_y, ncov)``:
    texel ``(tx, ty)``'s ``j``-th lobe, its spatial weight and its normal Gaussian given
    the footprint (the map tiles: any texel is valid)."""

    count: Any
    x0: Any
    y0: Any
    nx: Any
    ny: Any
    at: Any

    def lobe(self, i: Any, j: int) -> tuple[Any, Any, Any, Sym2]:
        """The box's ``i``-th texel's (row-major) ``j``-th lobe."""
        return self.at(self.x0 + i % self.nx, self.y0 + i // self.nx, j)


def lobe_terms(
    mi: types.ModuleType, lobes: JitLobes, c: tuple[Any, Any], cov: Sym2, active: Any,
    max_items: int,
) -> LobeTerms:  # fmt: skip
    """What :func:`lobes_pndf`, :func:`lobes_sample` and the hierarchical evaluation
    (:mod:`materials.glints.pndf_yan_hier`) share: the support box at
    :data:`SUPPORT_SIGMAS` plus ``5 sigma_h`` and each lobe's term (:class:`LobeTerms`)."""
    import drjit as dr

    n, k2 = lobes.n, lobes.rate * lobes.rate
    h2 = lobes.sigma_h**2
    cx, cy = c
    inv_p = cov.inverse(dr)
    s_mat = Sym2(inv_p.a + 1.0 / h2, inv_p.b, inv_p.d + 1.0 / h2).inverse(dr)
    px = inv_p.a * cx + inv_p.b * cy
    py = inv_p.b * cx + inv_p.d * cy
    bx = s_mat.a * px + s_mat.b * py
    by = s_mat.b * px + s_mat.d * py
    spatial = Sym2(cov.a + h2, cov.b, cov.d + h2)
    sp_inv = spatial.inverse(dr)
    sp_norm = dr.rcp(2.0 * math.pi * dr.sqrt(spatial.det()))
    reach = 5.0 * lobes.sigma_h
    hx = SUPPORT_SIGMAS * dr.sqrt(cov.a) + reach
    hy = SUPPORT_SIGMAS * dr.sqrt(cov.d) + reach
    x0 = mi.Int32(dr.floor(cx - hx))
    y0 = mi.Int32(dr.floor(cy - hy))
    nx = mi.Int32(dr.floor(cx + hx)) - x0 + 1
    ny = mi.Int32(dr.floor(cy + hy)) - y0 + 1
    count = dr.select(mi.Bool(active), dr.minimum(nx * ny, max_items), 0)
    r2 = lobes.sigma_r**2
    ux_a, uy_a, sx_a, sy_a, j00_a, j01_a, j10_a, j11_a = lobes.arrays

    def at(tx: Any, ty: Any, j: int) -> tuple[Any, Any, Any, Sym2]:
        wx, wy = _pmod(mi, dr, tx, n), _pmod(mi, dr, ty, n)
        idx = mi.UInt32((wy * n + wx) * k2) + j
        ux = dr.gather(mi.Float, ux_a, idx) + mi.Float(tx - wx)
        uy = dr.gather(mi.Float, uy_a, idx) + mi.Float(ty - wy)
        g = _gauss(dr, sp_inv, sp_norm, cx - ux, cy - uy)
        mx = s_mat.a * ux + s_mat.b * uy
        my = s_mat.b * ux + s_mat.d * uy
        dux = mx / h2 + bx - ux
        duy = my / h2 + by - uy
        j00 = dr.gather(mi.Float, j00_a, idx)
        j01 = dr.gather(mi.Float, j01_a, idx)
        j10 = dr.gather(mi.Float, j10_a, idx)
        j11 = dr.gather(mi.Float, j11_a, idx)
        mean_x = dr.gather(mi.Float, sx_a, idx) + j00 * dux + j01 * duy
        mean_y = dr.gather(mi.Float, sy_a, idx) + j10 * dux + j11 * duy
        t00 = j00 * s_mat.a + j01 * s_mat.b
        t01 = j00 * s_mat.b + j01 * s_mat.d
        t10 = j10 * s_mat.a + j11 * s_mat.b
        t11 = j10 * s_mat.b + j11 * s_mat.d
        ncov = Sym2(t00 * j00 + t01 * j01 + r2, t00 * j10 + t01 * j11, t10 * j10 + t11 * j11 + r2)
        return g, mean_x, mean_y, ncov

    return LobeTerms(count, x0, y0, nx, ny, at)


def lobes_sample(
    mi: types.ModuleType,
    lobes: JitLobes,
    c: tuple[Any, Any],
    cov: Sym2,
    u1: Any,
    u2: tuple[Any, Any],
    active: Any = True,
    *,
    max_items: int = 1 << 16,
    total_only: bool = False,
) -> tuple[Any, Any, Any]:
    """Draw a projected normal from :func:`lobes_pndf`'s P-NDF itself (Eq. 1 is a mixture of
    Gaussians over ``s``: lobe ``i`` with weight ``g_i``, its spatial overlap with the
    footprint): a lobe by ``u1`` in proportion to ``g_i`` (two passes over the same lobes),
    then its Gaussian by Box-Muller on ``u2``. Returns ``(s_x, s_y, total)``: the sample and
    ``total = weight sum_i g_i``, the P-NDF's integral over the plane, so that the sample's
    density is ``lobes_pndf(...) / total``. ``total_only``: the first pass alone (the
    returned sample is 0)."""
    import drjit as dr

    terms = lobe_terms(mi, lobes, c, cov, active, max_items)
    count, lobe = terms.count, terms.lobe
    k2 = lobes.rate * lobes.rate

    def total_body(i: Any, acc: Any) -> tuple[Any, Any]:
        for j in range(k2):
            acc += lobe(i, j)[0]
        return i + 1, acc

    _, total = dr.while_loop(
        (mi.Int32(0), dr.zeros(mi.Float)), lambda i, acc: i < count, total_body,
        label="glint: lobe total",
    )  # fmt: skip
    if total_only:
        zero = dr.zeros(mi.Float)
        return zero, zero, dr.select(mi.Bool(active), lobes.weight * total, 0.0)
    target = u1 * total
    zero = dr.zeros(mi.Float)

    def pick_body(
        i: Any, acc: Any, mx: Any, my: Any, ca: Any, cb: Any, cd: Any, done: Any
    ) -> tuple[Any, ...]:
        for j in range(k2):
            g, mean_x, mean_y, ncov = lobe(i, j)
            acc += g
            take = ~done & (acc >= target)
            mx, my = dr.select(take, mean_x, mx), dr.select(take, mean_y, my)
            ca, cb, cd = (
                dr.select(take, v, w) for v, w in ((ncov.a, ca), (ncov.b, cb), (ncov.d, cd))
            )
            done |= take
        return i + 1, acc, mx, my, ca, cb, cd, done

    state = (mi.Int32(0), zero, zero, zero, zero, zero, zero, mi.Bool(False))
    _, _, mx, my, ca, cb, cd, done = dr.while_loop(
        state, lambda i, *rest: (i < count) & ~rest[-1], pick_body, label="glint: lobe pick"
    )
    # Cholesky of the chosen lobe's covariance; Box-Muller.
    l00 = dr.sqrt(dr.maximum(ca, 1e-30))
    l10 = cb / l00
    l11 = dr.sqrt(dr.maximum(cd - l10 * l10, 1e-30))
    rad = dr.sqrt(-2.0 * dr.log(dr.maximum(1.0 - u2[0], 1e-30)))
    sin_p, cos_p = dr.sincos(2.0 * math.pi * u2[1])
    zx, zy = rad * cos_p, rad * sin_p
    sx = mx + l00 * zx
    sy = my + l10 * zx + l11 * zy
    # A lane whose lobes hold no weight (or that ran out of them) draws nothing: total 0.
    total = dr.select(mi.Bool(active) & done, lobes.weight * total, 0.0)
    return sx, sy, total


@dataclass(frozen=True)
class JitMapSampler:
    """What drawing from the maps needs (:func:`tiny_sample`): per tile of every level, the
    cumulative masses of the ``(R + 1)^2`` bilinear patches of its NDF image (normalised to 1;
    a patch lies between four cell centres, the outer ones reaching the image's border,
    where the lookup's corners outside are 0) and the image's integral over the plane
    (``cell^2`` times the sum of its values). Laid out like :class:`JitMaps`."""

    cdf: Any
    cdf_offsets: Any  # mi.UInt32 per level
    integrals: Any
    int_offsets: Any  # mi.UInt32 per level
    patches: int  # R + 1

    @property
    def nbytes(self) -> int:
        return int(4 * (dr_width(self.cdf) + dr_width(self.integrals)))


def dr_width(x: Any) -> int:
    import drjit as dr

    return int(dr.width(x))


def jit_map_sampler(mi: types.ModuleType, maps: list[np.ndarray], extent: float) -> JitMapSampler:
    """Upload the patch CDFs and integrals of ``maps`` (float64 sums, float32 stored)."""
    cdfs, ints = [], []
    big_r = int(maps[0].shape[-1])
    cell = 2.0 * extent / big_r
    for m in maps:
        v = np.pad(m.astype(np.float64), ((0, 0), (0, 0), (1, 1), (1, 1)))
        patch = 0.25 * (v[..., :-1, :-1] + v[..., 1:, :-1] + v[..., :-1, 1:] + v[..., 1:, 1:])
        flat = patch.reshape(m.shape[0], m.shape[1], -1)
        cum = np.cumsum(flat, axis=-1)
        tot = cum[..., -1:]
        cdfs.append((cum / np.where(tot > 0, tot, 1.0)).astype(np.float32).ravel())
        ints.append(
            (cell * cell * m.astype(np.float64).sum(axis=(-2, -1))).astype(np.float32).ravel()
        )
    c_off = np.cumsum([0] + [len(c) for c in cdfs[:-1]]).astype(np.uint32)
    i_off = np.cumsum([0] + [len(i) for i in ints[:-1]]).astype(np.uint32)
    return JitMapSampler(
        cdf=mi.Float(np.concatenate(cdfs)),
        cdf_offsets=mi.UInt32(c_off),
        integrals=mi.Float(np.concatenate(ints)),
        int_offsets=mi.UInt32(i_off),
        patches=big_r + 1,
    )


def _linear_warp(dr: Any, a: Any, b: Any, u: Any) -> Any:
    """Inverse CDF on [0, 1] of the density proportional to ``a (1 - x) + b x``."""
    root = dr.sqrt(dr.maximum((1.0 - u) * a * a + u * b * b, 0.0))
    return dr.select(a + b > 0.0, u * (a + b) / dr.maximum(a + root, 1e-30), u)


def tiny_sample(
    mi: types.ModuleType,
    maps: JitMaps,
    sampler: JitMapSampler,
    lobes: JitLobes,
    transform: tuple[np.ndarray, np.ndarray],
    c: tuple[Any, Any],
    cov: Sym2,
    u1: Any,
    u2: tuple[Any, Any],
    active: Any = True,
    *,
    max_items: int = 1 << 16,
    total_only: bool = False,
) -> tuple[Any, Any, Any]:
    """Draw a global projected normal from :func:`tiny_pndf`'s P-NDF (``lookup="flat"``)
    itself: below the finest tile from the lobes (:func:`lobes_sample`); else a tile by
    ``u1`` in proportion to its footprint mass times its image's integral, a patch of its
    image by the rest of ``u1`` (the patch CDF), and a point of the bilinear patch by
    ``u2`` (linear marginal, then linear conditional). Returns ``(s_x, s_y, total)``, the
    sample's density being ``tiny_pndf(...) / total``; ``total_only``: the totals alone."""
    import drjit as dr

    a_mat, off = (np.asarray(x, dtype=np.float64) for x in transform)
    ai = np.linalg.inv(a_mat)
    clx, cly, cl = _local_footprint(ai, c, cov)
    r00, r01, r10, r11 = (float(v) for v in ai.ravel())
    _, target, level = _flat_level(mi, dr, cl, maps.levels)
    use_maps = mi.Bool(active) & (target >= 2.0)
    use_lobes = mi.Bool(active) & (target < 2.0)
    lsx, lsy, ltot = lobes_sample(
        mi, lobes, (clx, cly), cl, u1, u2, use_lobes, max_items=max_items, total_only=total_only
    )

    grid = _tile_grid(mi, maps, lobes, clx, cly, cl, level, use_maps, max_items)
    lv, count = grid.lv, grid.count
    ibase = dr.gather(mi.UInt32, sampler.int_offsets, mi.UInt32(lv), use_maps)

    def weight(i: Any) -> tuple[Any, Any]:
        """Tile ``i``'s mass times its image's integral (as :func:`tiny_pndf`'s body)."""
        tx, ty = grid.tile(i)
        mass = grid.flat_mass(tx, ty)
        wx, wy = grid.wrap(tx, ty)
        tile = mi.UInt32(wy * grid.r + wx)
        return mass * dr.gather(mi.Float, sampler.integrals, ibase + tile, use_maps), tile

    def total_body(i: Any, acc: Any) -> tuple[Any, Any]:
        return i + 1, acc + weight(i)[0]

    _, total = dr.while_loop(
        (mi.Int32(0), dr.zeros(mi.Float)), lambda i, acc: i < count, total_body,
        label="glint: tile total",
    )  # fmt: skip
    if total_only:
        zero = dr.zeros(mi.Float)
        return zero, zero, dr.select(use_maps, total, ltot)
    goal = u1 * total
    zero = dr.zeros(mi.Float)

    def pick_body(
        i: Any, acc: Any, tile: Any, before: Any, g_t: Any, done: Any
    ) -> tuple[Any, ...]:  # fmt: skip
        g, t = weight(i)
        take = ~done & (acc + g >= goal) & (g > 0.0)
        tile = dr.select(take, t, tile)
        before = dr.select(take, acc, before)
        g_t = dr.select(take, g, g_t)
        return i + 1, acc + g, tile, before, g_t, done | take

    state = (mi.Int32(0), zero, mi.UInt32(0), zero, zero, mi.Bool(False))
    _, _, tile, before, g_t, done = dr.while_loop(
        state, lambda i, *rest: (i < count) & ~rest[-1], pick_body, label="glint: tile pick"
    )
    u_patch = dr.clip((goal - before) / dr.maximum(g_t, 1e-30), 0.0, 1.0)
    p = sampler.patches
    cbase = dr.gather(mi.UInt32, sampler.cdf_offsets, mi.UInt32(lv), use_maps) + tile * (p * p)
    pick = use_maps & done
    k = dr.binary_search(
        0, p * p - 1, lambda j: dr.gather(mi.Float, sampler.cdf, cbase + j, pick) < u_patch
    )
    # Patch k = (py, px) between cell centres px - 1 .. px (cells outside are 0).
    px, py = mi.Int32(k % p), mi.Int32(k // p)
    big_r = maps.resolution
    img = dr.gather(mi.UInt32, maps.offsets, mi.UInt32(lv), use_maps) + tile * (big_r * big_r)

    def value(ix: Any, iy: Any) -> Any:
        ok = pick & (ix >= 0) & (ix < big_r) & (iy >= 0) & (iy < big_r)
        return dr.gather(
            mi.Float, maps.data, img + mi.UInt32(dr.select(ok, iy * big_r + ix, 0)), ok
        )

    v00, v10 = value(px - 1, py - 1), value(px, py - 1)
    v01, v11 = value(px - 1, py), value(px, py)
    fx = _linear_warp(dr, v00 + v01, v10 + v11, u2[0])
    fy = _linear_warp(dr, (1.0 - fx) * v00 + fx * v10, (1.0 - fx) * v01 + fx * v11, u2[1])
    cell = 2.0 * maps.extent / big_r
    msx = -maps.extent + (mi.Float(px) - 0.5 + fx) * cell
    msy = -maps.extent + (mi.Float(py) - 0.5 + fy) * cell
    qlx = dr.select(use_maps, msx, lsx)
    qly = dr.select(use_maps, msy, lsy)
    total = dr.select(use_maps, dr.select(pick, total, 0.0), ltot)
    # Back to global normals: q = A^-T q_l + o.
    qx = r00 * qlx + r10 * qly + float(off[0])
    qy = r01 * qlx + r11 * qly + float(off[1])
    return qx, qy, total


@dataclass(frozen=True)
class JitPlacement:
    """A stochastic distribution's table (:class:`~materials.glints.surface.Surface`'s
    seeded instances, ``period x period`` cells of side ``spacing``) as Dr.Jit arrays, row
    ``cy * period + cx``: jitter (cells), ``A^-1`` and ``A`` row-major, ``|det A|``.

    ``candidates``: per sub-cell of the period (the four quadrants of each cell, class
    ``((cy * period + cx) * 2 + qy) * 2 + qx``), the cells whose instance may cover a point
    of it, as offsets ``(dx, dy)`` from the point's cell, nearest centre first (to the
    sub-cell's centre, the distance Fig. 3's rule minimises); ``starts[k]`` where class
    ``k``'s list begins (``k + 1``'s: where it ends). Fig. 3's owner is the first that
    covers the point."""

    period: int
    spacing: float
    reach: float
    n: int
    arrays: tuple[Any, ...]  # jx, jy, i00, i01, i10, i11, a00, a01, a10, a11, det
    candidates: tuple[Any, Any]  # dx, dy (mi.Int32)
    starts: Any  # mi.UInt32


def jit_placement(mi: types.ModuleType, surface: Any) -> JitPlacement:
    """Upload the table of a stochastic ``surface`` (:class:`materials.glints.surface.Surface`)."""
    d = surface.dist
    if d.kind != "stochastic":
        raise ValueError("jit_placement needs a stochastic surface")
    cols: list[list[float]] = [[] for _ in range(11)]
    for row in surface.table:
        for inst in row:
            ai, a = inst.transform.inverse, inst.transform.a
            vals = [*inst.centre, *ai.ravel(), *a.ravel(), inst.transform.density_scale]
            for col, v in zip(cols, vals, strict=True):
                col.append(float(v))
    reach = 0.75 * surface.n * max(d.scale_range) + d.jitter * surface.spacing
    dxs, dys, starts = _candidates(surface, reach)
    return JitPlacement(
        period=int(d.period),
        spacing=float(surface.spacing),
        reach=float(reach),
        n=int(surface.n),
        arrays=tuple(mi.Float(np.asarray(c, np.float32)) for c in cols),
        candidates=(mi.Int32(dxs), mi.Int32(dys)),
        starts=mi.UInt32(starts),
    )


def _candidates(surface: Any, reach: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:class:`JitPlacement`'s candidate lists: for each sub-cell, the cells whose instance
    centre lies within ``reach`` plus the sub-cell's half-diagonal of its centre (an
    instance covers only points within ``reach`` of its centre, the square's
    half-diagonal being at most ``0.75 n`` times the largest scale), sorted by distance
    (ties: row-major order of the offsets, stable)."""
    d = surface.dist
    per, sp = int(d.period), float(surface.spacing)
    jit = np.array([[inst.centre for inst in row] for row in surface.table])  # (cy, cx, 2)
    r = int(math.ceil(reach / sp)) + 2
    off = np.arange(-r, r + 1)
    oy, ox = (a.ravel() for a in np.meshgrid(off, off, indexing="ij"))
    dxs, dys, starts = [], [], [0]
    limit = reach + 0.25 * math.sqrt(2.0) * sp
    for cy in range(per):
        for cx in range(per):
            for qy in range(2):
                for qx in range(2):
                    sub = np.array([cx + (qx + 0.5) / 2.0, cy + (qy + 0.5) / 2.0]) * sp
                    j = jit[(cy + oy) % per, (cx + ox) % per]
                    ctr = (np.stack([cx + ox, cy + oy], axis=1) + 0.5 + j) * sp
                    dist = np.linalg.norm(ctr - sub, axis=1)
                    keep = np.flatnonzero(dist <= limit)
                    order = keep[np.argsort(dist[keep], kind="stable")]
                    dxs.append(ox[order])
                    dys.append(oy[order])
                    starts.append(starts[-1] + len(order))
    return (
        np.concatenate(dxs).astype(np.int32),
        np.concatenate(dys).astype(np.int32),
        np.asarray(starts, np.uint32),
    )


def stochastic_pndf(
    mi: types.ModuleType,
    maps: JitMaps,
    lobes: JitLobes,
    place: JitPlacement,
    c: tuple[Any, Any],
    cov: Sym2,
    q: tuple[Any, Any],
    active: Any = True,
    *,
    max_items: int = 1 << 16,
) -> Any:
    """The tiny-example P-NDF of a stochastic surface: the twin of
    :func:`materials.glints.footprint.tiny_pndf` for ``stochastic`` distributions (the
    ``flat`` lookup). For each instance near the footprint (a loop over table cells), the
    footprint and query in its frame, its level by :func:`lod_level`'s rule, and its tiles
    (or its finest tiles' lobes) that meet the support inside its square, each counted
    when Fig. 3's rule gives the point (a tile's centre, a lobe's seed) to this instance (an
    inner loop over the instances near that point)."""
    import drjit as dr

    n, per, sp = place.n, place.period, place.spacing
    jx_a, jy_a, i00_a, i01_a, i10_a, i11_a, a00_a, a01_a, a10_a, a11_a, det_a = place.arrays
    cx, cy = c
    hx0 = SUPPORT_SIGMAS * dr.sqrt(cov.a)
    hy0 = SUPPORT_SIGMAS * dr.sqrt(cov.d)
    k0x = mi.Int32(dr.floor((cx - hx0 - place.reach) / sp))
    k0y = mi.Int32(dr.floor((cy - hy0 - place.reach) / sp))
    knx = dr.maximum(mi.Int32(dr.floor((cx + hx0 + place.reach) / sp)) - k0x + 1, 1)
    kny = mi.Int32(dr.floor((cy + hy0 + place.reach) / sp)) - k0y + 1
    count = dr.select(mi.Bool(active), knx * kny, 0)

    def inst(kx: Any, ky: Any, on: Any) -> tuple[Any, ...]:
        row = mi.UInt32(_pmod(mi, dr, ky, per) * per + _pmod(mi, dr, kx, per))
        g = [dr.gather(mi.Float, a, row, on) for a in place.arrays]
        ox = (mi.Float(kx) + 0.5 + g[0]) * sp
        oy = (mi.Float(ky) + 0.5 + g[1]) * sp
        return (ox, oy, *g[2:])

    cdx, cdy = place.candidates

    def owns(px: Any, py: Any, kx: Any, ky: Any, on: Any) -> Any:
        """Fig. 3: does instance ``(kx, ky)`` own global point ``(px, py)``? The first
        candidate of the point's sub-cell (nearest first) that covers it owns it."""
        gx, gy = dr.floor(px / sp), dr.floor(py / sp)
        qx_ = mi.Int32(dr.clip(dr.floor((px / sp - gx) * 2.0), 0.0, 1.0))
        qy_ = mi.Int32(dr.clip(dr.floor((py / sp - gy) * 2.0), 0.0, 1.0))
        cgx, cgy = mi.Int32(gx), mi.Int32(gy)
        cls = ((_pmod(mi, dr, cgy, per) * per + _pmod(mi, dr, cgx, per)) * 2 + qy_) * 2 + qx_
        first = dr.gather(mi.UInt32, place.starts, mi.UInt32(cls), on)
        last = dr.gather(mi.UInt32, place.starts, mi.UInt32(cls) + 1, on)

        def obody(j: Any, bx: Any, by: Any, found: Any) -> tuple[Any, ...]:
            ox_ = cgx + dr.gather(mi.Int32, cdx, j)
            oy_ = cgy + dr.gather(mi.Int32, cdy, j)
            ccx, ccy, i00, i01, i10, i11 = inst(ox_, oy_, on)[:6]
            lx = i00 * (px - ccx) + i01 * (py - ccy) + 0.5 * n
            ly = i10 * (px - ccx) + i11 * (py - ccy) + 0.5 * n
            covers = (lx >= 0.0) & (lx < n) & (ly >= 0.0) & (ly < n)
            return j + 1, dr.select(covers, ox_, bx), dr.select(covers, oy_, by), covers

        _, bx, by, found = dr.while_loop(
            (first, mi.Int32(0), mi.Int32(0), mi.Bool(False)),
            lambda j, bx, by, found: on & (j < last) & ~found, obody, label="glint: owner",
        )  # fmt: skip
        return on & found & (bx == kx) & (by == ky)

    big_r = maps.resolution
    cell = 2.0 * maps.extent / big_r
    h2 = lobes.sigma_h**2
    r2 = lobes.sigma_r**2
    k2 = lobes.rate * lobes.rate
    ux_a, uy_a, sx_a, sy_a, j00_a, j01_a, j10_a, j11_a = lobes.arrays

    def body(i: Any, acc: Any) -> tuple[Any, Any]:
        kx, ky = k0x + i % knx, k0y + i // knx
        on = mi.Bool(active)
        ccx, ccy, i00, i01, i10, i11, a00, a01, a10, a11, det = inst(kx, ky, on)
        # Local frame: c_l = A^-1 (c - centre) + n / 2, Sigma_l = A^-1 Sigma A^-T, q_l = A^T q.
        clx = i00 * (cx - ccx) + i01 * (cy - ccy) + 0.5 * n
        cly = i10 * (cx - ccx) + i11 * (cy - ccy) + 0.5 * n
        cl = Sym2(
            i00 * i00 * cov.a + 2 * i00 * i01 * cov.b + i01 * i01 * cov.d,
            i00 * i10 * cov.a + (i00 * i11 + i01 * i10) * cov.b + i01 * i11 * cov.d,
            i10 * i10 * cov.a + 2 * i10 * i11 * cov.b + i11 * i11 * cov.d,
        )
        qlx = a00 * q[0] + a10 * q[1]
        qly = a01 * q[0] + a11 * q[1]
        hx = SUPPORT_SIGMAS * dr.sqrt(cl.a)
        hy = SUPPORT_SIGMAS * dr.sqrt(cl.d)
        on &= (clx + hx > 0.0) & (cly + hy > 0.0) & (clx - hx < n) & (cly - hy < n)
        half_tr = 0.5 * (cl.a + cl.d)
        lam = half_tr - dr.sqrt(dr.maximum(dr.square(0.5 * (cl.a - cl.d)) + cl.b * cl.b, 0.0))
        target = FLATNESS * dr.sqrt(dr.maximum(lam, 1e-30))
        level = dr.minimum(
            mi.Int32(dr.floor(dr.log2(dr.maximum(target, 1e-30)))) - 1, maps.levels - 1
        )
        use_maps = on & (target >= 2.0)
        lv = dr.maximum(level, 0)
        side = dr.exp2(mi.Float(lv + 1))
        r = mi.Int32(n) // mi.Int32(side)
        reach = 5.0 * lobes.sigma_h
        t0x = dr.maximum(mi.Int32(dr.floor((clx - hx - reach) / side)), 0)
        t0y = dr.maximum(mi.Int32(dr.floor((cly - hy - reach) / side)), 0)
        t1x = dr.minimum(mi.Int32(dr.floor((clx + hx + reach) / side)), r - 1)
        t1y = dr.minimum(mi.Int32(dr.floor((cly + hy + reach) / side)), r - 1)
        # An empty box (the support outside the square) gives nx or ny <= 0: count 0, and
        # the divisor clamped to 1 (a masked SIMD lane still divides; 0 would trap).
        nx, ny = t1x - t0x + 1, t1y - t0y + 1
        nxd = dr.maximum(nx, 1)
        inv_l = cl.inverse(dr)
        norm_l = dr.rcp(2.0 * math.pi * dr.sqrt(cl.det()))

        def to_global(lx: Any, ly: Any) -> tuple[Any, Any]:
            return (a00 * (lx - 0.5 * n) + a01 * (ly - 0.5 * n) + ccx,
                    a10 * (lx - 0.5 * n) + a11 * (ly - 0.5 * n) + ccy)  # fmt: skip

        # Maps: tiles of the level inside the instance's square.
        base = dr.gather(mi.UInt32, maps.offsets, mi.UInt32(lv), use_maps)
        px = (qlx + maps.extent) / cell - 0.5
        py = (qly + maps.extent) / cell - 0.5
        ix0, iy0 = mi.Int32(dr.floor(px)), mi.Int32(dr.floor(py))
        fx, fy = px - dr.floor(px), py - dr.floor(py)
        tcount = dr.select(use_maps & (nx > 0) & (ny > 0), dr.minimum(nx * ny, max_items), 0)

        def tbody(t: Any, tacc: Any) -> tuple[Any, Any]:
            tx, ty = t0x + t % nxd, t0y + t // nxd
            ox = (mi.Float(tx) + 0.5) * side - clx
            oy = (mi.Float(ty) + 0.5) * side - cly
            gx_, gy_ = to_global((mi.Float(tx) + 0.5) * side, (mi.Float(ty) + 0.5) * side)
            mine = owns(gx_, gy_, kx, ky, use_maps)
            d = 0.5 * side * _GL2
            mass = dr.zeros(mi.Float)
            for sx in (-d, d):
                for sy in (-d, d):
                    mass += _gauss(dr, inv_l, norm_l, ox + sx, oy + sy)
            mass *= 0.25 * side * side
            img = base + mi.UInt32((ty * r + tx) * (big_r * big_r))
            value = dr.zeros(mi.Float)
            for dy in (0, 1):
                for dx in (0, 1):
                    ix, iy = ix0 + dx, iy0 + dy
                    ok = mine & (ix >= 0) & (ix < big_r) & (iy >= 0) & (iy < big_r)
                    w = (fx if dx else 1.0 - fx) * (fy if dy else 1.0 - fy)
                    idx = mi.UInt32(dr.select(ok, iy * big_r + ix, 0))
                    value += dr.select(ok, w, 0.0) * dr.gather(mi.Float, maps.data, img + idx, ok)
            return t + 1, tacc + dr.select(mine, mass * value, 0.0)

        _, from_maps = dr.while_loop(
            (mi.Int32(0), dr.zeros(mi.Float)), lambda t, a: t < tcount, tbody,
            label="glint: instance tiles",
        )  # fmt: skip

        # Lobes (below the finest tile): the texels of the finest tiles in the box.
        use_lobes = on & (target < 2.0)
        inv_p = inv_l
        s_mat = Sym2(inv_p.a + 1.0 / h2, inv_p.b, inv_p.d + 1.0 / h2).inverse(dr)
        ppx = inv_p.a * clx + inv_p.b * cly
        ppy = inv_p.b * clx + inv_p.d * cly
        bx = s_mat.a * ppx + s_mat.b * ppy
        by = s_mat.b * ppx + s_mat.d * ppy
        spatial = Sym2(cl.a + h2, cl.b, cl.d + h2)
        sp_inv = spatial.inverse(dr)
        sp_norm = dr.rcp(2.0 * math.pi * dr.sqrt(spatial.det()))
        f0x = dr.maximum(mi.Int32(dr.floor((clx - hx - reach) / 2.0)), 0) * 2
        f0y = dr.maximum(mi.Int32(dr.floor((cly - hy - reach) / 2.0)), 0) * 2
        f1x = dr.minimum(mi.Int32(dr.floor((clx + hx + reach) / 2.0)), n // 2 - 1) * 2 + 1
        f1y = dr.minimum(mi.Int32(dr.floor((cly + hy + reach) / 2.0)), n // 2 - 1) * 2 + 1
        lnx, lny = f1x - f0x + 1, f1y - f0y + 1
        lnxd = dr.maximum(lnx, 1)
        lcount = dr.select(use_lobes & (lnx > 0) & (lny > 0), dr.minimum(lnx * lny, max_items), 0)

        def lbody(t: Any, lacc: Any) -> tuple[Any, Any]:
            tx, ty = f0x + t % lnxd, f0y + t // lnxd
            base_l = mi.UInt32((ty * n + tx) * k2)
            for j in range(k2):
                idx = base_l + j
                ux = dr.gather(mi.Float, ux_a, idx, use_lobes)
                uy = dr.gather(mi.Float, uy_a, idx, use_lobes)
                gx_, gy_ = to_global(ux, uy)
                mine = owns(gx_, gy_, kx, ky, use_lobes)
                g = _gauss(dr, sp_inv, sp_norm, clx - ux, cly - uy)
                mx = s_mat.a * ux + s_mat.b * uy
                my = s_mat.b * ux + s_mat.d * uy
                dux = mx / h2 + bx - ux
                duy = my / h2 + by - uy
                j00 = dr.gather(mi.Float, j00_a, idx, use_lobes)
                j01 = dr.gather(mi.Float, j01_a, idx, use_lobes)
                j10 = dr.gather(mi.Float, j10_a, idx, use_lobes)
                j11 = dr.gather(mi.Float, j11_a, idx, use_lobes)
                mean_x = dr.gather(mi.Float, sx_a, idx, use_lobes) + j00 * dux + j01 * duy
                mean_y = dr.gather(mi.Float, sy_a, idx, use_lobes) + j10 * dux + j11 * duy
                t00 = j00 * s_mat.a + j01 * s_mat.b
                t01 = j00 * s_mat.b + j01 * s_mat.d
                t10 = j10 * s_mat.a + j11 * s_mat.b
                t11 = j10 * s_mat.b + j11 * s_mat.d
                ncov = Sym2(
                    t00 * j00 + t01 * j01 + r2, t00 * j10 + t01 * j11, t10 * j10 + t11 * j11 + r2
                )
                ninv = ncov.inverse(dr)
                nnorm = dr.rcp(2.0 * math.pi * dr.sqrt(ncov.det()))
                dens = g * _gauss(dr, ninv, nnorm, qlx - mean_x, qly - mean_y)
                lacc += dr.select(mine, dens, 0.0)
            return t + 1, lacc

        _, from_lobes = dr.while_loop(
            (mi.Int32(0), dr.zeros(mi.Float)), lambda t, a: t < lcount, lbody,
            label="glint: instance lobes",
        )  # fmt: skip
        part = dr.select(use_maps, from_maps, lobes.weight * from_lobes)
        return i + 1, acc + dr.select(on, det * part, 0.0)

    _, acc = dr.while_loop(
        (mi.Int32(0), dr.zeros(mi.Float)), lambda i, acc: i < count, body,
        label="glint: instances",
    )  # fmt: skip
    return acc
