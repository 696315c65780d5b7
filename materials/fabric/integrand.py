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
iterations; ``march="plain"`` tests every point.
"""

from __future__ import annotations

import math
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
    wz = ops.maximum(w[2], 1e-4)
    rise = ops.maximum(geo.h_max - h0, 0.0)
    travel = rise * ops.sqrt(w[0] * w[0] + w[1] * w[1]) / wz  # physical, horizontal
    count = ops.minimum(ops.floor(travel * (1.0 / step)) + 1.0, float(max_steps))
    if need is not None:
        count = ops.where(need, count, 0.0)
    # Horizontal travel per unit rise, converted from physical to tile units.
    ds = w[0] / (wz * geo.tile[0])
    dt = w[1] / (wz * geo.tile[1])
    rise_step = rise / ops.maximum(count, 1.0)

    if mip is None:
        lanes: tuple[Array, ...] = (s, t, h0, ds, dt, rise_step, jitter)

        def plain(k: Array, lane: tuple[Array, ...]) -> tuple[Array, Array]:
            s_, t_, h_, ds_, dt_, rs, jit = lane
            r = rs * (k + 1.0 - jit)
            hq = yarn.height(ops, geo, tab, s_ + ds_ * r, t_ + dt_ * r)
            return hq > h_ + r + _MARCH_EPS, k + 1.0

        blocked = ops.march(count, max_steps, lanes, h0 < -1e30, plain)
        return ops.where(blocked, 0.0, 1.0)

    big = 1e30
    inv_ds = 1.0 / ops.maximum(ops.abs(ds), 1.0 / big)
    inv_dt = 1.0 / ops.maximum(ops.abs(dt), 1.0 / big)
    inv_rs = 1.0 / ops.maximum(rise_step, 1e-30)
    lanes = (s, t, h0, ds, dt, rise_step, jitter, inv_ds, inv_dt, inv_rs)

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

    blocked = ops.march(count, max_steps, lanes, h0 < -1e30, hierarchical)
    return ops.where(blocked, 0.0, 1.0)


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
    ``march``: ``"hierarchical"`` (the max mip-map of ``march.py`` skips clear space) or
    ``"plain"`` (every step tested); both give the same visibility up to float32 round-off.
    """
    if march not in MARCHES:
        raise ValueError(f"march must be one of {MARCHES}, got {march!r}")
    surf = yarn.surface(ops, geo, tab, s, t)
    n = surf.normal
    jac = 1.0 / n[2]  # Eq. 4: |dx_p / dp| = 1 / <n_s . n_p>
    above = wi[2] > 0.0
    ci = dot(wi, n)
    c_in = ops.where(above, ops.maximum(ci, 0.0), ops.maximum(-ci, 0.0))
    co = ops.maximum(dot(wo, n), 0.0)
    if with_visibility:
        step, cap = march_step, march_max_steps
        mip = upload(ops, max_mip(geo)) if march == "hierarchical" else None
        # Only samples with a non-zero weight need a march (V multiplies co and c_in).
        v_o = visibility(
            ops,
            geo,
            tab,
            s,
            t,
            surf.height,
            wo,
            jitter,
            need=co > 0.0,
            step=step,
            max_steps=cap,
            mip=mip,
        )
        wi_up = (wi[0], wi[1], ops.abs(wi[2]))
        # The same jitter for both marches: the numerator of Eq. 3 is then exactly symmetric
        # in (wi, wo) for reflection (reciprocity of f_P A_P), whatever the march resolves.
        v_i = ops.where(
            above,
            visibility(
                ops,
                geo,
                tab,
                s,
                t,
                surf.height,
                wi_up,
                jitter,
                need=above & (c_in > 0.0),
                step=step,
                max_steps=cap,
                mip=mip,
            ),
            1.0,
        )
        both = v_i * v_o * jac
    else:
        v_o = v_i = 1.0
        both = jac
    alpha = ops.where(surf.warp, params.alpha.warp, params.alpha.weft)
    spec = shading.specular_response(ops, wi, wo, n, surf.tangent, alpha, params.t_rho)
    spec = ops.where((c_in > 0.0) & (co > 0.0), spec * both, 0.0)
    diff = shading.diffuse_response(ops, wi, wo, n, params.w) * both
    return Terms(
        c_warp=ops.where(surf.warp, diff, 0.0),
        c_weft=ops.where(surf.weft, diff, 0.0),
        s_warp=ops.where(surf.warp, spec, 0.0),
        s_weft=ops.where(surf.weft, spec, 0.0),
        area=co * v_o * jac,
        area_in=c_in * v_i * jac,
    )


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
