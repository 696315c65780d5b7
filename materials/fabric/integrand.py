"""Per-sample terms of the aggregated patch BSDF, Eq. 3-5 of Chen et al. 2024 (Zhu et al. 2023a).

``f_P(wi, wo) = 1 / A_P(wo) int_P f_p(wi, wo) <wi.n_p> V(x_p, wi) A(p, wo) k_P(p) dp`` (Eq. 3)
with ``A(p, wo) = <wo.n_p> / <n_s.n_p> V(x_p, wo)`` (Eq. 4) and
``A_P(wo) = int_P A(p, wo) k_P(p) dp`` (Eq. 5). One sample ``p ~ k_P`` contributes, per
component of Eq. 7 (unit albedos; ``J = 1 / <n_s.n_p>``):

- ``S_yarn = D(h) G / 4 * V_i V_o J`` where the top yarn is ``yarn`` -- the specular
  response of ``shading.py``, whose ``1 / (|cos_i| |cos_o|)`` cancels Eq. 3's cosines;
- ``C_yarn = (w c_i + (1 - w) min(c_i, <wi.n_s>)) c_o / pi * V_i V_o J`` (blended Lambertian);
- ``area = <wo.n_p> V_o J`` (Eq. 4) and ``area_in = c_i V_i J`` (the same for the light).

The estimator (``aggregate.py``) divides the sample means: ``f_c = mean(c) / mean(area)``.
So ``f_P`` is Eq. 3 itself: it *includes* the incident cosine (flat yarns give
``f_P = f_p |cos theta_i|``), the role of Mitsuba's ``eval()`` with our ``wi`` as the light.
``area_in`` lets a white-furnace test bound the albedo: ``int f_P A_P(wo) dwo <= A_P^in(wi)``.

Light from below (transmission): ``c_i = <-wi.n_p>``, the ply's underside is lit through
the SpongeCake slab, and ``V_i = 1``: the fabric is one height-field layer whose underside
we treat as unoccluded (the crossing yarn beneath a float is not represented, as in Jin et
al.'s single-layer maps). The viewer is always above (``wo_z > 0``).

Kernel ``k_P`` (the paper does not specify it): ``"box"``, uniform over the axis-aligned
square of side ``size`` (tile units) centred on the footprint centre, or ``"gaussian"``, an
isotropic normal with the box's variance (standard deviation ``size / sqrt(12)`` per axis).

Visibility ``V`` (binary, Eq. 3-4) by marching the height field of ``yarn.py`` from the
surface point ``(s, t, h)`` along ``w`` until the ray rises above the tile's highest point
``h_max``. The ray's horizontal travel ``d = (h_max - h) tan(theta)`` is cut into
``n = min(floor(d / step) + 1, max_steps)`` equal steps (defaults: ``step`` = 0.05 cells,
``max_steps`` = 64) and the height field is tested at rises ``(k + 1 - j) / n (h_max - h)``,
``k = 0 .. n - 1``, with a per-sample jitter ``j in [0, 1)`` that turns the stepping's
aliasing into noise. The ray is blocked where the height field lies more than ``1e-3``
(physical units, 0.1 % of a cell) above it. Resolution: horizontal steps of at most 0.05
cells while ``d <= 3.2`` cells (e.g. ``h_max - h = 0.5`` up to 81 deg from the normal),
coarser beyond, so occluders narrower than a step can be missed at grazing angles (a bias
in V only). Measured against a 0.01-cell march on the benchmark's query mix (three
materials, 2048 samples), the defaults shift the summed components by -0.2 to -0.5 % on
average, 0.6 to 3 standard errors at N = 2048; pass a finer ``march_step`` for reference
data. Samples whose weight is zero anyway (``<wo.n_p> <= 0`` or ``c_i = 0``) skip their
march, and flat yarns (``h_max = 0``) skip it altogether: V = 1.

The march is hierarchical by default (``march.py``): a max mip-map over the tile's height
field proves runs of test points clear (the ray above every yarn beneath them), and the
march jumps over them. It tests a subset of the points above and skips only points that
cannot be blocked, so it returns the same visibility, up to float32 round-off, in fewer
iterations; ``march="plain"`` tests every point. ``march="batched"`` (the estimator's
default) marches the rays of several samples in one loop (:func:`visibilities`,
:func:`sample_terms_batch`): on SIMD packets, a lane that is done with one ray goes on to
its next, so a packet costs its lanes' total iterations, not each ray's slowest lane.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Literal, NamedTuple

from materials.fabric import shading, yarn
from materials.fabric.array_ops import Array, ArrayOps, Vec3, dot
from materials.fabric.march import MARCHES, March, MipTables, clear_jump, max_mip, upload
from materials.fabric.params import FabricParams
from materials.fabric.yarn import YarnGeometry, YarnTables

#: The four components of Eq. 7, in the order used by every array in this package.
COMPONENTS: tuple[str, str, str, str] = ("C_warp", "C_weft", "S_warp", "S_weft")

Kernel = Literal["box", "gaussian"]
KERNELS: tuple[str, ...] = ("box", "gaussian")

#: Default horizontal step of the visibility march, physical units (1/20 of a cell).
MARCH_STEP = 0.05
#: Default cap on the number of march steps per ray.
MARCH_MAX_STEPS = 64
#: Height tolerance of the march, physical units.
_MARCH_EPS = 1e-3


class Terms(NamedTuple):
    """Per-sample contributions (backend arrays); see the module docstring."""

    c_warp: Array
    c_weft: Array
    s_warp: Array
    s_weft: Array
    area: Array
    area_in: Array


def footprint_positions(
    ops: ArrayOps,
    centre: tuple[Array, Array],
    size: Array,
    u1: Array,
    u2: Array,
    kernel: Kernel = "box",
) -> tuple[Array, Array]:
    """Map uniform ``(u1, u2) in [0, 1)^2`` to tile points ``(s, t)`` distributed as ``k_P``."""
    if kernel == "box":
        return centre[0] + (u1 - 0.5) * size, centre[1] + (u2 - 0.5) * size
    if kernel == "gaussian":
        # Inverse normal CDF: sqrt(2) erfinv(2u - 1); sigma = size / sqrt(12) (box variance).
        scale = size * (math.sqrt(2.0) / math.sqrt(12.0))
        lo, hi = 1e-6, 1.0 - 1e-6
        g1 = ops.erfinv(2.0 * ops.minimum(ops.maximum(u1, lo), hi) - 1.0)
        g2 = ops.erfinv(2.0 * ops.minimum(ops.maximum(u2, lo), hi) - 1.0)
        return centre[0] + g1 * scale, centre[1] + g2 * scale
    raise ValueError(f"kernel must be one of {KERNELS}, got {kernel!r}")


class _Ray(NamedTuple):
    """One visibility march, ready for :meth:`ArrayOps.march`: ``count`` test points and
    the per-element inputs ``lanes`` of the step function."""

    count: Array
    lanes: tuple[Array, ...]


class _Direction(NamedTuple):
    """What a march needs of its direction ``w`` alone (shared by rays along one ``w``)."""

    slope: Array  # horizontal travel per unit rise, physical
    ds: Array  # travel along s per unit rise, tile units
    dt: Array
    inv_ds: Array | None  # 1 / |ds| (hierarchical march only)
    inv_dt: Array | None


def _direction(ops: ArrayOps, geo: YarnGeometry, w: Vec3, hierarchical: bool) -> _Direction:
    wz = ops.maximum(w[2], 1e-4)
    slope = ops.sqrt(w[0] * w[0] + w[1] * w[1]) / wz
    # Horizontal travel per unit rise, converted from physical to tile units.
    ds = w[0] / (wz * geo.tile[0])
    dt = w[1] / (wz * geo.tile[1])
    if not hierarchical:
        return _Direction(slope, ds, dt, None, None)
    big = 1e30
    inv_ds = 1.0 / ops.maximum(ops.abs(ds), 1.0 / big)
    inv_dt = 1.0 / ops.maximum(ops.abs(dt), 1.0 / big)
    return _Direction(slope, ds, dt, inv_ds, inv_dt)


def _ray(
    ops: ArrayOps,
    geo: YarnGeometry,
    s: Array,
    t: Array,
    h0: Array,
    d: _Direction,
    jitter: Array,
    need: Array | None,
    step: float,
    max_steps: int,
) -> _Ray:
    rise = ops.maximum(geo.h_max - h0, 0.0)
    travel = rise * d.slope  # physical, horizontal
    count = ops.minimum(ops.floor(travel * (1.0 / step)) + 1.0, float(max_steps))
    if need is not None:
        count = ops.where(need, count, 0.0)
    rise_step = rise / ops.maximum(count, 1.0)
    if d.inv_ds is None or d.inv_dt is None:
        return _Ray(count, (s, t, h0, d.ds, d.dt, rise_step, jitter))
    inv_rs = 1.0 / ops.maximum(rise_step, 1e-30)
    return _Ray(count, (s, t, h0, d.ds, d.dt, rise_step, jitter, d.inv_ds, d.inv_dt, inv_rs))


def _step_function(
    ops: ArrayOps, geo: YarnGeometry, tab: YarnTables, mip: MipTables | None
) -> Callable[[Array, tuple[Array, ...]], tuple[Array, Array]]:
    """The march's step: ``(hit, next k)`` at test point ``k`` of the rays ``lanes``."""
    if mip is None:

        def plain(k: Array, lane: tuple[Array, ...]) -> tuple[Array, Array]:
            s_, t_, h_, ds_, dt_, rs, jit = lane
            r = rs * (k + 1.0 - jit)
            hq = yarn.height(ops, geo, tab, s_ + ds_ * r, t_ + dt_ * r)
            return hq > h_ + r + _MARCH_EPS, k + 1.0

        return plain

    def hierarchical(k: Array, lane: tuple[Array, ...]) -> tuple[Array, Array]:
        s_, t_, h_, ds_, dt_, rs, jit, ids, idt, irs = lane
        r = rs * (k + 1.0 - jit)
        sq, tq = s_ + ds_ * r, t_ + dt_ * r
        x, y = sq - ops.floor(sq), tq - ops.floor(tq)
        ray = h_ + r + _MARCH_EPS
        clear, reach = clear_jump(ops, mip, x, y, ray, ids, idt, ds_ > 0.0, dt_ > 0.0)
        # First k whose test point lies beyond the clear texel: r_k > r + reach.
        k_jump = ops.maximum(ops.floor((r + reach) * irs - 1.0 + jit) + 1.0, k + 1.0)
        hq = yarn.height(ops, geo, tab, sq, tq)
        hit = ~clear & (hq > ray)
        return hit, ops.where(clear, k_jump, k + 1.0)

    return hierarchical


def visibility(
    ops: ArrayOps,
    geo: YarnGeometry,
    tab: YarnTables,
    s: Array,
    t: Array,
    h0: Array,
    w: Vec3,
    jitter: Array,
    *,
    need: Array | None = None,
    step: float = MARCH_STEP,
    max_steps: int = MARCH_MAX_STEPS,
    mip: MipTables | None = None,
) -> Array:
    """Binary V(x_p, w) (1.0 visible, 0.0 blocked) by marching the height field.

    ``w`` must point above the macro surface (``w_z > 0``); ``(s, t)`` in tile units, ``h0``
    the surface height there. Where ``need`` is False the march is skipped and V = 1 (for
    samples whose weight is zero anyway). See the module docstring for the method. With
    ``mip`` (``march.py``'s max mip-map of this geometry) the march jumps over the test
    points that the hierarchy proves clear: the same visibility in fewer iterations.
    """
    if geo.h_max <= 0.0:
        return ops.where(h0 > -1.0, 1.0, 1.0)
    d = _direction(ops, geo, w, mip is not None)
    ray = _ray(ops, geo, s, t, h0, d, jitter, need, step, max_steps)
    body = _step_function(ops, geo, tab, mip)
    blocked = ops.march(ray.count, max_steps, ray.lanes, h0 < -1e30, body)
    return ops.where(blocked, 0.0, 1.0)


class RayQuery(NamedTuple):
    """The arguments of one :func:`visibility` call, for :func:`visibilities`."""

    s: Array
    t: Array
    h0: Array
    w: Vec3
    jitter: Array
    need: Array | None


def visibilities(
    ops: ArrayOps,
    geo: YarnGeometry,
    tab: YarnTables,
    rays: list[RayQuery],
    *,
    step: float = MARCH_STEP,
    max_steps: int = MARCH_MAX_STEPS,
    mip: MipTables | None = None,
) -> list[Array]:
    """:func:`visibility` of each of ``rays``, marched in one loop (:meth:`ArrayOps.march_many`):
    the same values; on SIMD packets a lane goes on to its next ray as soon as one is done."""
    if geo.h_max <= 0.0:
        return [ops.where(r.h0 > -1.0, 1.0, 1.0) for r in rays]
    # Rays along the same direction arrays share its terms (and so, in one loop, the
    # selects between them: ``DrJitOps.march_many``).
    dirs: dict[tuple[int, int, int], _Direction] = {}
    prepared = []
    for r in rays:
        key = (id(r.w[0]), id(r.w[1]), id(r.w[2]))
        if key not in dirs:
            dirs[key] = _direction(ops, geo, r.w, mip is not None)
        prepared.append(
            _ray(ops, geo, r.s, r.t, r.h0, dirs[key], r.jitter, r.need, step, max_steps)
        )
    body = _step_function(ops, geo, tab, mip)
    blocked = ops.march_many(
        [p.count for p in prepared], max_steps, [p.lanes for p in prepared], body
    )
    return [ops.where(b, 0.0, 1.0) for b in blocked]


class SamplePoint(NamedTuple):
    """The per-sample arguments of :func:`sample_terms`, for :func:`sample_terms_batch`."""

    s: Array
    t: Array
    wi: Vec3
    wo: Vec3
    jitter: Array


def sample_terms(
    ops: ArrayOps,
    params: FabricParams,
    geo: YarnGeometry,
    tab: YarnTables,
    s: Array,
    t: Array,
    wi: Vec3,
    wo: Vec3,
    jitter: Array,
    *,
    with_visibility: bool = True,
    march_step: float = MARCH_STEP,
    march_max_steps: int = MARCH_MAX_STEPS,
    march: March = "hierarchical",
) -> Terms:
    """Eq. 3-5 integrand at footprint samples ``(s, t)`` for light ``wi`` and view ``wo``.

    ``wi``, ``wo``: unit, macro frame, ``wo_z > 0``; ``wi_z < 0`` means light from below.
    ``jitter in [0, 1)`` offsets the visibility march. ``with_visibility=False`` sets V = 1.
    ``march``: ``"hierarchical"`` (the max mip-map of ``march.py`` skips clear space),
    ``"batched"`` (the same, with both marches of a sample in one loop) or ``"plain"``
    (every step tested); all give the same visibility up to float32 round-off.
    """
    (terms,) = sample_terms_batch(
        ops,
        params,
        geo,
        tab,
        [SamplePoint(s, t, wi, wo, jitter)],
        with_visibility=with_visibility,
        march_step=march_step,
        march_max_steps=march_max_steps,
        march=march,
    )
    return terms


def sample_terms_batch(
    ops: ArrayOps,
    params: FabricParams,
    geo: YarnGeometry,
    tab: YarnTables,
    points: list[SamplePoint],
    *,
    with_visibility: bool = True,
    march_step: float = MARCH_STEP,
    march_max_steps: int = MARCH_MAX_STEPS,
    march: March = "hierarchical",
) -> list[Terms]:
    """:func:`sample_terms` at each of ``points`` (arrays of one width): with
    ``march="batched"`` every visibility march of all the points runs in one loop
    (:func:`visibilities`), so a SIMD lane that finishes one ray goes on to its next."""
    if march not in MARCHES:
        raise ValueError(f"march must be one of {MARCHES}, got {march!r}")
    surfs = [yarn.surface(ops, geo, tab, p.s, p.t) for p in points]
    pre = []
    for p, surf in zip(points, surfs, strict=True):
        n = surf.normal
        above = p.wi[2] > 0.0
        ci = dot(p.wi, n)
        c_in = ops.where(above, ops.maximum(ci, 0.0), ops.maximum(-ci, 0.0))
        co = ops.maximum(dot(p.wo, n), 0.0)
        pre.append((above, c_in, co))
    v_pairs: list[tuple[Array | float, Array | float]]
    if with_visibility:
        step, cap = march_step, march_max_steps
        mip = upload(ops, max_mip(geo)) if march != "plain" else None
        rays: list[RayQuery] = []
        ups: dict[int, Vec3] = {}  # wi with |wi_z|, once per direction (shared by points)
        for p, surf, (above, c_in, co) in zip(points, surfs, pre, strict=True):
            # Only samples with a non-zero weight need a march (V multiplies co and c_in).
            # The same jitter for both marches: the numerator of Eq. 3 is then exactly
            # symmetric in (wi, wo) for reflection (reciprocity of f_P A_P), whatever the
            # march resolves.
            rays.append(RayQuery(p.s, p.t, surf.height, p.wo, p.jitter, co > 0.0))
            if id(p.wi) not in ups:
                ups[id(p.wi)] = (p.wi[0], p.wi[1], ops.abs(p.wi[2]))
            wi_up = ups[id(p.wi)]
            rays.append(RayQuery(p.s, p.t, surf.height, wi_up, p.jitter, above & (c_in > 0.0)))
        if march == "batched":
            vs = visibilities(ops, geo, tab, rays, step=step, max_steps=cap, mip=mip)
        else:
            vs = [
                visibility(
                    ops,
                    geo,
                    tab,
                    r.s,
                    r.t,
                    r.h0,
                    r.w,
                    r.jitter,
                    need=r.need,
                    step=step,
                    max_steps=cap,
                    mip=mip,
                )
                for r in rays
            ]
        v_pairs = [
            (vs[2 * i], ops.where(pre[i][0], vs[2 * i + 1], 1.0)) for i in range(len(points))
        ]
    else:
        v_pairs = [(1.0, 1.0)] * len(points)
    out = []
    for p, surf, (_above, c_in, co), (v_o, v_i) in zip(points, surfs, pre, v_pairs, strict=True):
        n = surf.normal
        jac = 1.0 / n[2]  # Eq. 4: |dx_p / dp| = 1 / <n_s . n_p>
        both = v_i * v_o * jac
        alpha = ops.where(surf.warp, params.alpha.warp, params.alpha.weft)
        spec = shading.specular_response(ops, p.wi, p.wo, n, surf.tangent, alpha, params.t_rho)
        spec = ops.where((c_in > 0.0) & (co > 0.0), spec * both, 0.0)
        diff = shading.diffuse_response(ops, p.wi, p.wo, n, params.w) * both
        out.append(
            Terms(
                c_warp=ops.where(surf.warp, diff, 0.0),
                c_weft=ops.where(surf.weft, diff, 0.0),
                s_warp=ops.where(surf.warp, spec, 0.0),
                s_weft=ops.where(surf.weft, spec, 0.0),
                area=co * v_o * jac,
                area_in=c_in * v_i * jac,
            )
        )
    return out


def point_components(
    ops: ArrayOps,
    params: FabricParams,
    geo: YarnGeometry,
    tab: YarnTables,
    s: Array,
    t: Array,
    wi: Vec3,
    wo: Vec3,
) -> tuple[Array, Array, Array, Array]:
    """The point BSDF f_p at ``(s, t)`` split as :data:`COMPONENTS`, unit albedos, 1/sr.

    No visibility and no cosines: ``k_d C + k_s S`` is the plain BSDF of Eq. 1 at the point
    (diffuse for light above the macro surface only; zero in gaps).
    """
    surf = yarn.surface(ops, geo, tab, s, t)
    alpha = ops.where(surf.warp, params.alpha.warp, params.alpha.weft)
    spec = shading.specular_bsdf(ops, wi, wo, surf.normal, surf.tangent, alpha, params.t_rho)
    diff = shading.diffuse_bsdf(ops, wi, wo, surf.normal, params.w)
    return (
        ops.where(surf.warp, diff, 0.0),
        ops.where(surf.weft, diff, 0.0),
        ops.where(surf.warp, spec, 0.0),
        ops.where(surf.weft, spec, 0.0),
    )
