"""Point BSDF of a yarn: Eq. 1-2 of Chen et al. 2024 (Jin et al. 2022 on SpongeCake).

Element-wise over an :class:`~materials.fabric.array_ops.ArrayOps` backend (numpy or Dr.Jit),
directions as 3-tuples of arrays in the macro frame (z = n_s up). Values are for *unit*
albedos: Eq. 8 multiplies them by k_s and k_d later. ``wi`` is the light direction, ``wo``
the view direction, both pointing away from the surface.

Frame: the micro-surface of the ply
-----------------------------------
Eq. 3 weights the point BSDF by ``<wi . n_p>`` and Eq. 4 by the projected area of the ply
surface, i.e. each point is a micro-facet with normal ``n_p``. We therefore evaluate Eq. 1-2
in that facet's frame: the SpongeCake layer lies parallel to the ply surface ("cos w" in
Eq. 2 is ``w . n_p``) with its fibre-like microflakes along ``t_p`` (``t_p . n_p = 0``). This
makes each point's BSDF conserve energy about its own normal, which is what bounds the
aggregate's albedo by 1 (``aggregate.py``). For flat yarns (``beta = 0``) n_p = n_s and
this is exactly Jin et al.'s model.

Specular term (Eq. 2), SpongeCake single scattering
---------------------------------------------------
SGGX fibre microflakes (Heitz et al. 2015) with ``S = diag(1, 1, alpha^2)`` in the ply frame,
the third axis being ``t_p``: ``sigma(w) = sqrt(w^T S w) = sqrt(1 - (1 - alpha^2)(w.t_p)^2)``,
``D(h) = 1 / (pi alpha q^2)``, ``q = h^T S^-1 h = 1 + (1 / alpha^2 - 1)(h.t_p)^2``, the specular
phase function ``D(h) / (4 sigma(wi))`` with ``h = (wi + wo) / |wi + wo|``, and the Smith
``Lambda(w) = sigma(w) / |w.n_p|``. A slab of optical thickness ``T rho`` (= 2, Sec. 3.1)
scatters once at depth ``z``; attenuating the way in and the way out and integrating over
``z`` gives ``f = k_s D(h) G / (4 |cos_i| |cos_o|)`` with

- reflection (``wi``, ``wo`` on the same side of the ply):
  ``G_R = (1 - exp(-T rho (L_i + L_o))) / (L_i + L_o)`` -- Eq. 2 exactly;
- transmission (opposite sides), the light crossing the whole slab:
  ``G_T = (exp(-T rho L_o) - exp(-T rho L_i)) / (L_i - L_o)``, limit
  ``T rho exp(-T rho L)`` when ``L_i = L_o``.

Transmission choice: the paper defers its BTDF (Zhu et al. 2023a) to a supplement we do not
have. ``G_T`` above is the same single-scattering integral as Eq. 2's ``G`` with the exit at
the slab's far face (Wang et al. 2022's SpongeCake transmission; it equals the formula with
signed ``Lambda`` used by Tang et al. 2024's public fabric BTDF code). It is reciprocal, and
reflection plus transmission of a white slab equals the single-scattered fraction, at most
``1 - exp(-T rho Lambda_i)``. No delta transmission through gaps (excluded, Sec. 6.5) and no
diffuse transmission: the C components are reflection only.

Diffuse term (Eq. 1), the blended Lambertian
--------------------------------------------
Jin et al.'s term, multiplied by the macro cosine it was written for, is the response
``f_d <wi.n_s> = (k_d / pi) (w <wi.n_p> + (1 - w) <wi.n_s>)``: a fraction ``w`` lit through
the ply normal, ``1 - w`` as if the surface were flat. In the facet frame the same response
is ``f_d <wi.n_p>`` with ``f_d = (k_d / pi) (w + (1 - w) min(1, <wi.n_s> / <wi.n_p>))``: we
keep Jin's response but cap the flat-lit part at the facet's own cosine, so a facet never
scatters more than it receives (albedo <= k_d) and a facet turned away from the light stays
dark. It is non-zero only for light above the macro surface reaching the facet's front.

Reciprocity: the specular term is reciprocal (``D``, ``G_R``, ``G_T`` are symmetric), so is
the diffuse term at ``w = 1``; for ``w < 1`` it depends on ``wi`` alone, as Jin's does.
"""

from __future__ import annotations

import math

from materials.fabric.array_ops import Array, ArrayOps, Vec3, dot, normalize

#: T rho of the SpongeCake layer, "always assigned a value of 2 for fabrics" (Sec. 3.1).
T_RHO = 2.0
#: Cosines below this count as grazing (keeps Lambda finite).
_COS_EPS = 1e-6


def fiber_sigma(ops: ArrayOps, cos_t: Array, alpha: Array | float) -> Array:
    """Projected area ``sigma(w) = sqrt(w^T S w)`` of fibre flakes; ``cos_t = w . t_p`` (Eq. 2)."""
    return ops.sqrt(1.0 - (1.0 - alpha * alpha) * cos_t * cos_t)


def fiber_ndf(ops: ArrayOps, cos_t: Array, alpha: Array | float) -> Array:
    """SGGX ``D(h) = 1 / (pi alpha q^2)``, ``q = 1 + (1/alpha^2 - 1)(h.t_p)^2`` (Eq. 2), in 1/sr."""
    q = 1.0 + (1.0 / (alpha * alpha) - 1.0) * cos_t * cos_t
    return 1.0 / (math.pi * alpha * q * q)


def smith_lambda(ops: ArrayOps, sigma: Array, cos_n: Array) -> Array:
    """``Lambda(w) = sigma(w) / |cos w|`` with ``cos w = w . n_p`` (Eq. 2), always >= 0."""
    return sigma / ops.maximum(ops.abs(cos_n), _COS_EPS)


def _one_minus_exp_over_x(ops: ArrayOps, x: Array) -> Array:
    """``(1 - exp(-x)) / x`` for ``x >= 0``, with its series below 0.01 (no 0/0)."""
    series = 1.0 - x * (0.5 - x * (1.0 / 6.0 - x * (1.0 / 24.0)))
    direct = (1.0 - ops.exp(-x)) / ops.maximum(x, 1e-2)
    return ops.where(x > 1e-2, direct, series)


def slab_reflection_g(ops: ArrayOps, lam_i: Array, lam_o: Array, t_rho: float = T_RHO) -> Array:
    """Eq. 2's attenuation ``G = (1 - exp(-T rho (L_i + L_o))) / (L_i + L_o)``."""
    return t_rho * _one_minus_exp_over_x(ops, t_rho * (lam_i + lam_o))


def slab_transmission_g(ops: ArrayOps, lam_i: Array, lam_o: Array, t_rho: float = T_RHO) -> Array:
    """``G_T = (exp(-T rho L_o) - exp(-T rho L_i)) / (L_i - L_o)``, symmetric, stable at equality.

    Written as ``T rho exp(-T rho min) (1 - exp(-T rho |L_i - L_o|)) / (T rho |L_i - L_o|)``.
    """
    low = ops.minimum(lam_i, lam_o)
    gap = ops.abs(lam_i - lam_o)
    return t_rho * ops.exp(-t_rho * low) * _one_minus_exp_over_x(ops, t_rho * gap)


def specular_response(
    ops: ArrayOps,
    wi: Vec3,
    wo: Vec3,
    normal: Vec3,
    tangent: Vec3,
    alpha: Array | float,
    t_rho: float = T_RHO,
) -> Array:
    """``f_s |wi.n_p| |wo.n_p| = D(h) G / 4`` for unit k_s: the cosine-free specular response.

    Reflection when ``wi`` and ``wo`` lie on the same side of the ply surface, transmission
    otherwise (module docstring). Zero where ``wi = -wo`` (no half vector) or a direction
    lies in the ply plane.
    """
    ci = dot(wi, normal)
    co = dot(wo, normal)
    h, h_len = normalize(ops, (wi[0] + wo[0], wi[1] + wo[1], wi[2] + wo[2]))
    d = fiber_ndf(ops, dot(h, tangent), alpha)
    lam_i = smith_lambda(ops, fiber_sigma(ops, dot(wi, tangent), alpha), ci)
    lam_o = smith_lambda(ops, fiber_sigma(ops, dot(wo, tangent), alpha), co)
    reflect = ci * co > 0.0
    g = ops.where(
        reflect,
        slab_reflection_g(ops, lam_i, lam_o, t_rho),
        slab_transmission_g(ops, lam_i, lam_o, t_rho),
    )
    live = (h_len > 1e-6) & (ops.abs(ci) > _COS_EPS) & (ops.abs(co) > _COS_EPS)
    return ops.where(live, 0.25 * d * g, 0.0)


def specular_bsdf(
    ops: ArrayOps,
    wi: Vec3,
    wo: Vec3,
    normal: Vec3,
    tangent: Vec3,
    alpha: Array | float,
    t_rho: float = T_RHO,
) -> Array:
    """The specular BSDF ``f_s = k_s D(h) G / (4 |cos_i| |cos_o|)`` of Eq. 1-2, unit k_s, 1/sr."""
    ci = ops.maximum(ops.abs(dot(wi, normal)), _COS_EPS)
    co = ops.maximum(ops.abs(dot(wo, normal)), _COS_EPS)
    return specular_response(ops, wi, wo, normal, tangent, alpha, t_rho) / (ci * co)


def diffuse_response(ops: ArrayOps, wi: Vec3, wo: Vec3, normal: Vec3, w: float) -> Array:
    """``f_d <wi.n_p> <wo.n_p>`` for unit k_d: ``(w c_i + (1 - w) min(c_i, <wi.n_s>)) c_o / pi``.

    ``c_i = <wi.n_p>``, ``c_o = <wo.n_p>`` (clamped at 0); zero for light below the macro
    surface (reflection only).
    """
    cs = ops.maximum(wi[2], 0.0)
    ci = ops.where(cs > 0.0, ops.maximum(dot(wi, normal), 0.0), 0.0)
    co = ops.maximum(dot(wo, normal), 0.0)
    return (w * ci + (1.0 - w) * ops.minimum(ci, cs)) * co * (1.0 / math.pi)


def diffuse_bsdf(ops: ArrayOps, wi: Vec3, wo: Vec3, normal: Vec3, w: float) -> Array:
    """Blended Lambertian BSDF in the facet frame (module docstring), unit k_d, 1/sr."""
    ci = ops.maximum(dot(wi, normal), _COS_EPS)
    co = ops.maximum(dot(wo, normal), _COS_EPS)
    return diffuse_response(ops, wi, wo, normal, w) / (ci * co)
