"""Probes shared by the material tests: random directions, Mitsuba surface interactions,
plain BRDF values from Mitsuba plugins, and the two reference plugin dicts.

Directions are in the local shading frame, z up, ``(N, 3)`` float32 unless stated.
"""

from __future__ import annotations

import math
import types
from typing import Any

import numpy as np

#: Mitsuba's GGX gold conductor, alpha 0.3 (the tabulation and MERL-BSDF references).
AU_03 = {"type": "roughconductor", "distribution": "ggx", "alpha": 0.3, "material": "Au"}
#: Mitsuba's GGX plastic, alpha 0.3, blue diffuse base.
PLASTIC_03 = {
    "type": "roughplastic",
    "distribution": "ggx",
    "alpha": 0.3,
    "diffuse_reflectance": {"type": "rgb", "value": [0.2, 0.5, 0.8]},
}


def hemisphere(rng: np.random.Generator, n: int, max_deg: float = 90.0) -> np.ndarray:
    """``(n, 3)`` float32 directions, uniform in solid angle, ``theta <= max_deg``."""
    z = rng.uniform(math.cos(math.radians(max_deg)), 1.0, n)
    phi = rng.uniform(0.0, 2.0 * math.pi, n)
    r = np.sqrt(1.0 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1).astype(np.float32)


def interaction(mi: types.ModuleType, wi: np.ndarray) -> Any:
    """A ``SurfaceInteraction3f`` of ``len(wi)`` lanes with local ``wi`` (``(N, 3)``)."""
    import drjit as dr

    si = dr.zeros(mi.SurfaceInteraction3f, len(wi))
    si.wi = mi.Vector3f(*wi.T)
    return si


def mitsuba_brdf(mi: types.ModuleType, plugin: dict, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """``(N, 3)`` float64 plain BRDF from Mitsuba: eval (= f cos_o) divided by the float32
    ``wo.z`` it saw, at the float32-rounded pairs ``wi``, ``wo`` (``(N, 3)``)."""
    import drjit as dr

    bsdf = mi.load_dict(plugin)
    wi32, wo32 = wi.astype(np.float32), wo.astype(np.float32)
    si = dr.zeros(mi.SurfaceInteraction3f, len(wi))
    si.n = mi.Normal3f(0, 0, 1)
    si.sh_frame = mi.Frame3f(si.n)
    si.wi = mi.Vector3f(*wi32.T)
    value = np.array(bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(*wo32.T)), np.float64).T
    return value / wo32[:, 2:3].astype(np.float64)


def check_pdf_and_sampling(
    mi: types.ModuleType, bsdf: Any, deg: float, n: int, rng: np.random.Generator
) -> tuple[float, float, np.ndarray]:
    """A BSDF's pdf and sampling checked against its own eval at incidence ``deg``.

    - pdf >= 0 on the whole sphere (uniform directions), 0 below the surface, and its
      integral ``4 pi E[pdf]`` in (0.8, 1] within 4 standard errors;
    - ``eval_pdf`` is ``(eval, pdf)``; ``sample``'s pdf equals ``pdf(wo)``, and its weight
      equals ``eval(wo) / pdf(wo)`` where the pdf is positive, 0 elsewhere, always finite.

    Returns the pdf integral, its standard error and the sample weights ``(3, n)``.
    """
    import drjit as dr

    ctx = mi.BSDFContext()
    t = math.radians(deg)
    wi = np.tile(np.array([[math.sin(t), 0.0, math.cos(t)]], np.float32), (n, 1))
    si = interaction(mi, wi)
    v = rng.normal(size=(n, 3))
    v = (v / np.linalg.norm(v, axis=1, keepdims=True)).astype(np.float32)
    pdf = np.asarray(bsdf.pdf(ctx, si, mi.Vector3f(*v.T)), np.float64)
    integral = 4.0 * math.pi * pdf.mean()
    stderr = 4.0 * math.pi * pdf.std() / math.sqrt(n)
    assert pdf.min() >= 0.0 and np.all(pdf[v[:, 2] <= 0] == 0.0)
    assert 0.8 < integral < 1.0 + 4.0 * stderr, (deg, integral, stderr)
    u = rng.random((n, 3)).astype(np.float32)
    bs, weight = bsdf.sample(ctx, si, mi.Float(u[:, 0]), mi.Vector2f(u[:, 1], u[:, 2]))
    value, pdf2 = bsdf.eval_pdf(ctx, si, bs.wo)
    assert dr.allclose(value, bsdf.eval(ctx, si, bs.wo))
    assert dr.allclose(pdf2, bsdf.pdf(ctx, si, bs.wo))
    # float32: sample() reaches its pdf and weight by its own path, a few ulps from pdf()
    # and eval() / pdf() (the weight measured at 0.1 % of this bound); a wrong pdf is O(1).
    assert dr.allclose(bs.pdf, pdf2, rtol=1e-4, atol=1e-6)
    w, val, p = (np.asarray(a, np.float64) for a in (weight, value, pdf2))
    ok = p > 0
    assert np.allclose(w[:, ok], val[:, ok] / p[ok], rtol=1e-4, atol=1e-6)
    assert np.all(w[:, ~ok] == 0.0) and np.all(np.isfinite(w))
    return integral, stderr, w


def direction_chi2(
    mi: types.ModuleType,
    plugin: dict[str, Any],
    wi: tuple[float, float, float],
    *,
    uv: tuple[float, float] = (0.5, 0.5),
    duv: tuple[tuple[float, float], tuple[float, float]] = ((0.0, 0.0), (0.0, 0.0)),
    test_count: int = 1,
) -> tuple[bool, float, list[str]]:
    """Mitsuba's chi-square test (:mod:`mitsuba.chi2`, the independent oracle) of the
    directions a BSDF's ``sample`` draws against its ``pdf``, over the whole sphere.

    Unlike the harness's own ``BSDFAdapter``, a drawn direction counts whatever its weight:
    Mitsuba's adapter drops zero-weight samples as failed draws, which is right for BSDFs
    whose weight is ``f cos / pdf`` with ``f > 0`` wherever they sample, but not for our
    stochastic fabric BSDFs, whose one-sample estimate of ``f`` may be 0 at a direction the
    sampler did draw (an occluded footprint sample). A draw counts when its own pdf is
    positive. ``uv`` and the uv partials ``duv`` give the footprint. Returns
    ``(passed, p_value, messages)`` at significance 0.01 (Sidak-corrected over
    ``test_count`` tests).
    """
    import drjit as dr
    from mitsuba.chi2 import ChiSquareTest, SphericalDomain

    bsdf = mi.load_dict(plugin)
    ctx = mi.BSDFContext()

    def interaction_of(n: int) -> Any:
        si = dr.zeros(mi.SurfaceInteraction3f, n)
        si.wi = mi.Vector3f(*wi)
        si.uv = mi.Point2f(*uv)
        si.duv_dx = mi.Vector2f(*duv[0])
        si.duv_dy = mi.Vector2f(*duv[1])
        si.time = dr.arange(mi.Float, n) / max(n, 1)
        return si

    def sample_func(sample: Any, *args: Any) -> Any:
        n = dr.width(sample)
        bs, _ = bsdf.sample(ctx, interaction_of(n), sample[0], mi.Vector2f(sample[1], sample[2]))
        return bs.wo, dr.select(bs.pdf > 0.0, 1.0, 0.0)

    def pdf_func(wo: Any, *args: Any) -> Any:
        return bsdf.pdf(ctx, interaction_of(dr.width(wo)), wo)

    chi2: Any = ChiSquareTest(
        domain=SphericalDomain(), sample_func=sample_func, pdf_func=pdf_func, sample_dim=3
    )
    ok = bool(chi2.run(significance_level=0.01, test_count=test_count, quiet=True))
    return ok, float(chi2.p_value), list(chi2.messages)
