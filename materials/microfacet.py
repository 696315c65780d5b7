"""Microfacet building blocks: GGX and Beckmann NDFs, Smith shadowing, Fresnel terms.

One implementation of each formula, over numpy float64 arrays of cosines (any shape, all
broadcastable); the Dr.Jit plugins keep a thin twin tested against these.

Conventions: directions live in the local shading frame, z up; ``alpha`` is the isotropic
roughness (the slope-space standard deviation times sqrt(2) for Beckmann, the GGX width);
``cos_*`` are cosines of polar angles to the normal, ``cos_d = dot(wi, h)``. Values are
plain BRDFs in 1/sr (no cosine factor), RGB as ``(..., 3)``.

The defaults reproduce Mitsuba 3 (``include/mitsuba/render/microfacet.h``,
``fresnel.h``) so that tabulating ``roughconductor`` and our analytic conductor agree:
Smith shadowing is the *separable* product ``G1(wi) G1(wo)`` and Beckmann's ``G1`` uses the
rational approximation of Walter et al. 2007 (Eq. 27, < 0.35 % error). The height-correlated
form (Heitz 2014, "Understanding the Masking-Shadowing Function", Eq. 99) and the exact
Beckmann ``G1`` are available as options.

Named conductors: :data:`NAMED_CONDUCTORS` holds the RGB ``(eta, k)`` that Mitsuba 3.9.1's
``llvm_ad_rgb`` variant assigns to ``roughconductor`` with ``material=<name>`` (its spectral
data upsampled to RGB by Mitsuba itself), read through ``mi.traverse`` and stored as float32
values. ``tests/unit/materials/test_microfacet.py`` re-reads every entry from Mitsuba and
fails if they drift; :func:`materials.tabulate.mitsuba_conductor_ior` regenerates one.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import lru_cache
from typing import Literal

import numpy as np
from scipy.special import erf

Distribution = Literal["ggx", "beckmann"]
Shadowing = Literal["separable", "height_correlated"]

#: Mitsuba clamps roughness below this (``MicrofacetDistribution::configure``).
MIN_ALPHA = 1e-4

#: RGB ``(eta, k)`` of Mitsuba 3.9.1's named conductors (see the module docstring).
NAMED_CONDUCTORS: dict[str, tuple[tuple[float, float, float], tuple[float, float, float]]] = {
    "Ag": ((0.1552762, 0.116727956, 0.13838764), (4.8283544, 3.1222224, 2.1469011)),
    "Al": ((1.6575009, 0.8804047, 0.52124447), (9.223811, 6.269502, 4.837004)),
    "Au": ((0.14303598, 0.37530708, 1.4420453), (3.982997, 2.3855565, 1.6033592)),
    "Be": ((4.1850123, 3.1850293, 2.7840612), (3.835466, 3.0101223, 2.868994)),
    "Cr": ((4.3696675, 2.9165053, 1.6549046), (5.206547, 4.231306, 3.7546988)),
    "Cu": ((0.20100547, 0.9237495, 1.1022154), (3.9132621, 2.4530451, 2.1420898)),
    "Cu2O": ((3.5517726, 2.9498696, 2.7518754), (0.11420702, 0.19389686, 0.6061339)),
    "CuO": ((3.247541, 2.4478052, 2.2102196), (0.52108955, 0.57003075, 0.72217894)),
    "Hg": ((2.3989387, 1.440028, 0.9095704), (6.327587, 4.371925, 3.4217637)),
    "HgTe": ((4.77904, 3.2311962, 2.6599011), (1.6316127, 1.5808104, 1.7292874)),
    "Ir": ((3.0863, 2.0821905, 1.6179146), (5.592153, 4.067088, 3.267312)),
    "K": ((0.06404319, 0.046409767, 0.038184915), (2.1041996, 1.34894, 0.9131259)),
    "Li": ((0.26579094, 0.19561832, 0.22094862), (3.540155, 2.3111234, 1.6686072)),
    "Mo": ((4.483974, 3.5251307, 2.7763104), (4.1114373, 3.420827, 3.1506073)),
    "Na_palik": ((0.060269356, 0.056140948, 0.061988432), (3.1792734, 2.1124904, 1.5790411)),
    "Nb": ((3.420074, 2.7900932, 2.3956294), (3.4413946, 2.7376661, 2.5797458)),
    "Ni_palik": ((2.3673046, 1.6633731, 1.4670781), (4.4988117, 3.050153, 2.3454392)),
    "Rh": ((2.5857935, 1.8602164, 1.5542634), (6.7822604, 4.702987, 3.976073)),
    "Se": ((4.0583115, 2.842935, 2.8208535), (0.75404954, 0.6384435, 0.52180755)),
    "Ta": ((2.062721, 2.3929389, 2.6279287), (2.4083598, 1.7414864, 1.9470278)),
    "Te": ((7.3902335, 4.482105, 2.637106), (3.2560222, 3.5270588, 3.2920542)),
    "TiC": ((3.7005284, 2.8374221, 2.582287), (3.265635, 2.3515892, 2.1727905)),
    "TiN": ((1.6484497, 1.150516, 1.3798234), (3.368328, 1.9434981, 1.1020677)),
    "VC": ((3.657566, 2.752736, 2.532672), (3.0683007, 2.1986873, 1.9631927)),
    "VN": ((2.8656023, 2.119189, 1.9400911), (3.0322425, 2.0561156, 1.6163063)),
    "V_palik": ((4.277582, 3.5129488, 2.7610714), (3.4913008, 2.8894548, 3.111522)),
    "W": ((4.3708167, 3.3002465, 2.9984074), (3.5006406, 2.604874, 2.2732332)),
    "a-C": ((2.9440458, 2.2271364, 1.9681617), (0.8874649, 0.7992985, 0.81529)),
    # Mitsuba's default: a perfect mirror (F = 1 at every angle).
    "none": ((0.0, 0.0, 0.0), (1.0, 1.0, 1.0)),
}


def named_conductor(name: str) -> tuple[np.ndarray, np.ndarray]:
    """RGB ``(eta, k)`` (two ``(3,)`` float64 arrays) of a Mitsuba named conductor."""
    try:
        eta, k = NAMED_CONDUCTORS[name]
    except KeyError:
        raise ValueError(
            f"unknown conductor {name!r}; known: {', '.join(sorted(NAMED_CONDUCTORS))}"
        ) from None
    return np.array(eta, dtype=np.float64), np.array(k, dtype=np.float64)


def ndf(cos_m: np.ndarray, alpha: float, distribution: Distribution = "ggx") -> np.ndarray:
    """Normal distribution ``D(m)`` in 1/sr, normalised so ``int D(m) cos_m dm = 1``.

    GGX (Walter et al. 2007, Eq. 33): ``alpha^2 / (pi (cos^2 (alpha^2 - 1) + 1)^2)``.
    Beckmann (Eq. 25): ``exp(-tan^2 / alpha^2) / (pi alpha^2 cos^4)``. Zero for
    ``cos_m <= 0`` and, as in Mitsuba, where ``D cos_m <= 1e-20``.
    """
    alpha = max(float(alpha), MIN_ALPHA)
    c2 = np.clip(np.asarray(cos_m, dtype=np.float64), 0.0, 1.0) ** 2
    a2 = alpha * alpha
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        if distribution == "ggx":
            d = a2 / (np.pi * (c2 * (a2 - 1.0) + 1.0) ** 2)
        elif distribution == "beckmann":
            d = np.exp(-(1.0 - c2) / (c2 * a2)) / (np.pi * a2 * c2 * c2)
        else:
            raise ValueError(f"distribution must be 'ggx' or 'beckmann', got {distribution!r}")
        d = np.where(np.isfinite(d) & (d * np.sqrt(c2) > 1e-20), d, 0.0)
    return d


def smith_lambda(
    cos_v: np.ndarray,
    alpha: float,
    distribution: Distribution = "ggx",
) -> np.ndarray:
    """Smith's ``Lambda(v)`` (Heitz 2014, Eqs. 72 and 86); 0 at normal incidence.

    GGX: ``(-1 + sqrt(1 + alpha^2 tan^2)) / 2``. Beckmann, with ``a = 1 / (alpha tan)``:
    ``(erf(a) - 1) / 2 + exp(-a^2) / (2 a sqrt(pi))``.
    """
    alpha = max(float(alpha), MIN_ALPHA)
    c2 = np.clip(np.abs(np.asarray(cos_v, dtype=np.float64)), 1e-300, 1.0) ** 2
    t2 = np.maximum(1.0 - c2, 0.0) / c2  # tan^2 (either hemisphere)
    if distribution == "ggx":
        return 0.5 * (np.sqrt(1.0 + alpha * alpha * t2) - 1.0)
    with np.errstate(divide="ignore"):
        a = 1.0 / (alpha * np.sqrt(t2))
    lam = 0.5 * (erf(a) - 1.0) + np.exp(-a * a) / (2.0 * a * np.sqrt(np.pi))
    return np.where(np.isfinite(a), lam, 0.0)


def smith_g1(
    cos_v: np.ndarray,
    cos_vm: np.ndarray,
    alpha: float,
    distribution: Distribution = "ggx",
    *,
    exact_beckmann: bool = False,
) -> np.ndarray:
    """Smith masking ``G1(v, m)``; zero unless ``v`` sees the facet front (``cos_vm cos_v > 0``).

    GGX: ``2 / (1 + sqrt(1 + alpha^2 tan^2))`` (= ``1 / (1 + Lambda)``). Beckmann: by default
    the rational approximation of Walter et al. 2007, Eq. 27, in ``a = 1 / (alpha tan)``:
    ``(3.535 a + 2.181 a^2) / (1 + 2.276 a + 2.577 a^2)`` for ``a < 1.6``, else 1 (Mitsuba's
    choice); ``exact_beckmann=True`` uses ``1 / (1 + Lambda)`` with the erf form.
    """
    cos_v = np.asarray(cos_v, dtype=np.float64)
    if distribution == "beckmann" and not exact_beckmann:
        alpha = max(float(alpha), MIN_ALPHA)
        c2 = np.clip(np.abs(cos_v), 1e-300, 1.0) ** 2
        with np.errstate(divide="ignore", invalid="ignore"):
            a = 1.0 / (alpha * np.sqrt(np.maximum(1.0 - c2, 0.0) / c2))
            g = np.where(
                a >= 1.6, 1.0, (3.535 * a + 2.181 * a * a) / (1.0 + 2.276 * a + 2.577 * a * a)
            )
        g = np.where(np.isfinite(a), g, 1.0)
    else:
        g = 1.0 / (1.0 + smith_lambda(cos_v, alpha, distribution))
    return np.where(np.asarray(cos_vm) * cos_v > 0.0, g, 0.0)


def smith_g2(
    cos_i: np.ndarray,
    cos_o: np.ndarray,
    cos_d: np.ndarray,
    alpha: float,
    distribution: Distribution = "ggx",
    shadowing: Shadowing = "separable",
) -> np.ndarray:
    """Masking-shadowing ``G2(wi, wo, h)`` for reflection (``cos_d = dot(wi, h) = dot(wo, h)``).

    ``"separable"``: ``G1(wi) G1(wo)`` (Mitsuba 3's ``MicrofacetDistribution::G``).
    ``"height_correlated"``: ``1 / (1 + Lambda(wi) + Lambda(wo))`` (Heitz 2014, Eq. 99),
    with the exact Lambda for both distributions.
    """
    if shadowing == "separable":
        return smith_g1(cos_i, cos_d, alpha, distribution) * smith_g1(
            cos_o, cos_d, alpha, distribution
        )
    if shadowing != "height_correlated":
        raise ValueError(f"shadowing must be 'separable' or 'height_correlated', got {shadowing!r}")
    g = 1.0 / (
        1.0 + smith_lambda(cos_i, alpha, distribution) + smith_lambda(cos_o, alpha, distribution)
    )
    ok = (np.asarray(cos_d) * cos_i > 0) & (np.asarray(cos_d) * cos_o > 0)
    return np.where(ok, g, 0.0)


def fresnel_conductor(
    cos_i: np.ndarray, eta: np.ndarray | float, k: np.ndarray | float
) -> np.ndarray:
    """Unpolarised Fresnel reflectance of a conductor with complex IOR ``eta + i k``.

    The exact closed form for an absorbing medium (Moeller, "Optics", 1988, as used by
    Mitsuba's ``fresnel_conductor``), relative to the outside medium. ``cos_i`` in ``[0, 1]``
    broadcasts against ``eta`` and ``k`` (e.g. ``(N, 1)`` against ``(3,)`` gives ``(N, 3)``).
    """
    c = np.clip(np.asarray(cos_i, dtype=np.float64), 0.0, 1.0)
    eta = np.asarray(eta, dtype=np.float64)
    k = np.asarray(k, dtype=np.float64)
    c2 = c * c
    s2 = 1.0 - c2
    t1 = eta * eta - k * k - s2
    a2pb2 = np.sqrt(np.maximum(t1 * t1 + 4.0 * eta * eta * k * k, 0.0))
    a = np.sqrt(np.maximum(0.5 * (a2pb2 + t1), 0.0))
    term1 = a2pb2 + c2
    term2 = 2.0 * c * a
    with np.errstate(divide="ignore", invalid="ignore"):
        r_s = (term1 - term2) / (term1 + term2)
        term3 = a2pb2 * c2 + s2 * s2
        term4 = term2 * s2
        r_p = r_s * (term3 - term4) / (term3 + term4)
        f = 0.5 * (r_s + r_p)
    # cos_i = 0 with eta = k = 0 is 0/0; grazing reflectance is 1 for any interface.
    return np.where(np.isfinite(f), f, 1.0)


def fresnel_dielectric(cos_i: np.ndarray, eta: float) -> np.ndarray:
    """Unpolarised Fresnel reflectance of a dielectric interface, relative IOR ``eta``.

    ``cos_i`` in ``[0, 1]`` is measured on the side the light arrives from; ``eta`` is the
    IOR of the far side over the near side. Total internal reflection gives 1.
    """
    c = np.clip(np.asarray(cos_i, dtype=np.float64), 0.0, 1.0)
    s2_t = (1.0 - c * c) / (eta * eta)
    tir = s2_t >= 1.0
    ct = np.sqrt(np.maximum(1.0 - s2_t, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        r_s = (c - eta * ct) / (c + eta * ct)
        r_p = (eta * c - ct) / (eta * c + ct)
        f = 0.5 * (r_s * r_s + r_p * r_p)
    return np.where(tir | ~np.isfinite(f), 1.0, f)


def specular_brdf(
    wi: np.ndarray,
    wo: np.ndarray,
    alpha: float,
    fresnel: Callable[[np.ndarray], np.ndarray],
    *,
    distribution: Distribution = "ggx",
    shadowing: Shadowing = "separable",
) -> np.ndarray:
    """Microfacet reflection ``f = D(h) G2 F(dot(wi, h)) / (4 cos_i cos_o)`` (Walter 2007, Eq. 20).

    Parameters
    ----------
    wi, wo
        ``(N, 3)`` unit directions, local frame, z up.
    fresnel
        Maps ``cos_d`` of shape ``(N, 1)`` to reflectance ``(N, 3)`` (or broadcastable).

    Returns
    -------
    ``(N, 3)`` float64 BRDF in 1/sr; 0 where ``wi`` or ``wo`` is at or below the horizon.
    """
    wi = np.asarray(wi, dtype=np.float64)
    wo = np.asarray(wo, dtype=np.float64)
    cos_i, cos_o = wi[:, 2], wo[:, 2]
    h = wi + wo
    h = h / np.maximum(np.linalg.norm(h, axis=1, keepdims=True), 1e-30)
    cos_d = np.einsum("ij,ij->i", wi, h)
    d = ndf(h[:, 2], alpha, distribution)
    g = smith_g2(cos_i, cos_o, cos_d, alpha, distribution, shadowing)
    above = (cos_i > 0) & (cos_o > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        scalar = np.where(above, d * g / (4.0 * cos_i * cos_o), 0.0)
    # Fresnel terms can be costly (thin films): evaluate them only where the lobe is non-zero.
    live = scalar > 0
    out = np.zeros((len(wi), 3))
    out[live] = scalar[live, None] * np.broadcast_to(fresnel(cos_d[live, None]), (live.sum(), 3))
    return out


@lru_cache(maxsize=8)
def _gauss_legendre(nodes: int) -> tuple[np.ndarray, np.ndarray]:
    x, w = np.polynomial.legendre.leggauss(nodes)
    x.setflags(write=False)
    w.setflags(write=False)
    return x, w


def specular_albedo(
    cos_i: np.ndarray,
    alpha: float,
    fresnel: Callable[[np.ndarray], np.ndarray],
    *,
    distribution: Distribution = "ggx",
    shadowing: Shadowing = "separable",
    nodes: int = 64,
) -> np.ndarray:
    """Directional albedo ``E(wi) = int f_spec(wi, wo) cos_o dwo`` of a microfacet lobe.

    Integrated over microfacet normals, ``E = int F G2 D dot(wi, m) / cos_i dm`` (the
    ``4 dot(wi, m)`` Jacobian of the reflection map cancels the denominator), by
    ``nodes x nodes`` Gauss-Legendre quadrature after mapping ``m`` through the inverse CDF
    of ``D cos_m`` (Walter 2007, Eqs. 28 and 35), which concentrates nodes where ``D`` is.

    Parameters
    ----------
    cos_i
        ``(M,)`` cosines of incidence in ``(0, 1]`` (the azimuth does not matter).
    fresnel
        Maps ``dot(wi, m)`` of shape ``(M, K)`` to scalar reflectance of the same shape.

    Returns
    -------
    ``(M,)`` albedo in ``[0, 1]``.
    """
    cos_i = np.clip(np.asarray(cos_i, dtype=np.float64), 1e-6, 1.0)
    alpha = max(float(alpha), MIN_ALPHA)
    x, w = _gauss_legendre(nodes)
    u = 0.5 * (x + 1.0)
    # The azimuth integrand is even in phi_m about the plane of incidence: use [0, pi].
    phi = 0.5 * np.pi * (x + 1.0)
    if distribution == "ggx":
        tan2 = alpha * alpha * u / (1.0 - u)
    else:
        tan2 = -alpha * alpha * np.log1p(-u)
    cm = 1.0 / np.sqrt(1.0 + tan2)
    sm = np.sqrt(np.maximum(1.0 - cm * cm, 0.0))
    mx = (sm[:, None] * np.cos(phi)[None, :]).ravel()
    mz = np.repeat(cm, nodes)
    # (u, phi) uniform on [0,1] x [0,2pi) has solid-angle density p(m) = D cos_m, so
    # E = 1/pi int_0^1 int_0^pi (g / p) dphi du; the Gauss-Legendre maps give w_i/2, w_j pi/2.
    weight = (np.outer(w, w) * 0.25).ravel()
    si = np.sqrt(np.maximum(1.0 - cos_i * cos_i, 0.0))
    cos_im = si[:, None] * mx[None, :] + cos_i[:, None] * mz[None, :]
    cos_o = 2.0 * cos_im * mz[None, :] - cos_i[:, None]
    g = smith_g2(cos_i[:, None], cos_o, cos_im, alpha, distribution, shadowing)
    # g / p = F G2 dot(wi, m) / (cos_i cos_m): D cancels.
    val = fresnel(np.clip(cos_im, 0.0, 1.0)) * g * cos_im / (cos_i[:, None] * mz[None, :])
    val = np.where((cos_o > 0) & (cos_im > 0), val, 0.0)
    return np.clip(val @ weight, 0.0, 1.0)


def specular_transmittance(
    cos_i: np.ndarray,
    alpha: float,
    eta: float,
    *,
    distribution: Distribution = "ggx",
    nodes: int = 64,
) -> np.ndarray:
    """Directional transmittance of a rough dielectric interface (relative IOR ``eta``).

    ``T(wi) = int (1 - F(dot(wi, m))) G1(wi, m) G1(wt, m) D(m) dot(wi, m) / cos_i dm`` with
    ``wt`` the refraction of ``wi`` through ``m`` (Walter 2007, Eqs. 21 and 40): the energy
    that crosses the interface, the quantity Mitsuba's ``eval_transmittance`` computes for
    ``roughplastic``. Same quadrature as :func:`specular_albedo`; ``(M,)`` in, ``(M,)`` out.
    """
    cos_i = np.clip(np.asarray(cos_i, dtype=np.float64), 1e-6, 1.0)
    alpha = max(float(alpha), MIN_ALPHA)
    x, w = _gauss_legendre(nodes)
    u = 0.5 * (x + 1.0)
    phi = 0.5 * np.pi * (x + 1.0)
    tan2 = alpha * alpha * u / (1.0 - u) if distribution == "ggx" else -alpha * alpha * np.log1p(-u)
    cm = 1.0 / np.sqrt(1.0 + tan2)
    sm = np.sqrt(np.maximum(1.0 - cm * cm, 0.0))
    mx = (sm[:, None] * np.cos(phi)[None, :]).ravel()
    mz = np.repeat(cm, nodes)
    weight = (np.outer(w, w) * 0.25).ravel()  # as in specular_albedo
    si = np.sqrt(np.maximum(1.0 - cos_i * cos_i, 0.0))
    cos_im = si[:, None] * mx[None, :] + cos_i[:, None] * mz[None, :]
    # Refraction through m (Walter 2007, Eq. 40): wt = -wi/eta + (c_i/eta - c_t) m.
    s2_t = (1.0 - cos_im * cos_im) / (eta * eta)
    c_t = np.sqrt(np.maximum(1.0 - s2_t, 0.0))
    wt_z = -cos_i[:, None] / eta + (cos_im / eta - c_t) * mz[None, :]
    wt_m = -c_t  # dot(wt, m)
    g = smith_g1(cos_i[:, None], cos_im, alpha, distribution) * smith_g1(
        wt_z, wt_m, alpha, distribution
    )
    val = (1.0 - fresnel_dielectric(cos_im, eta)) * g * cos_im / (cos_i[:, None] * mz[None, :])
    val = np.where((wt_z < 0) & (cos_im > 0) & (s2_t < 1.0), val, 0.0)
    return np.clip(val @ weight, 0.0, 1.0)
