"""The ``glint`` BSDF and the Dr.Jit twins of the P-NDF evaluators.

Oracles:

- the numpy P-NDF evaluators of :mod:`materials.glints.footprint` (written over numpy,
  tested against brute force), for the Dr.Jit twins, to float32 precision;
- the numpy microfacet building blocks of :mod:`materials.microfacet` (Smith G1, the exact
  conductor Fresnel) with the numpy P-NDF, for the BSDF's value;
- reciprocity ``f(wi, wo) = f(wo, wi)`` (same footprint);
- an energy bound: the albedo of every ``wi`` is at most 1 (Monte Carlo, 3 standard errors);
- Mitsuba's chi-square harness for ``sample`` against ``pdf`` (:mod:`mitsuba.chi2`).
"""

from __future__ import annotations

import math
import types
from typing import Any

import numpy as np
import pytest

from evaluators.render.bsdfs.glint import (
    GLINT_BSDF_NAME,
    GlintLayer,
    put_layers,
    register_glint_bsdf,
)
from materials.glints.examples import procedural_example
from materials.glints.footprint import TinyExample, heckbert_covariance, tiny_pndf, yan_pndf
from materials.glints.lobes import make_lobes
from materials.glints.ndf_maps import auto_extent, ndf_maps
from materials.glints.pndf_drjit import Sym2, jit_lobes, jit_maps, lobes_pndf
from materials.glints.pndf_drjit import tiny_pndf as jit_tiny
from materials.glints.surface import Distribution, Surface, Transform
from materials.microfacet import NAMED_CONDUCTORS, fresnel_conductor, smith_g1
from tests.helpers.mitsuba_probes import direction_chi2

TEXELS_PER_UV = 64.0
TRANSFORM = Transform.compose(rotation_deg=25.0, scale=(1.1, 0.9))


@pytest.fixture(scope="module")
def example() -> TinyExample:
    normals = procedural_example("anisotropic_noise", 16, np.random.default_rng(9))
    lobes = make_lobes(normals, rate=2, sigma_r=0.03)
    e = auto_extent(lobes)
    return TinyExample(lobes, ndf_maps(lobes, 48, e), e)


def _floats(mi: types.ModuleType, v: float, n: int) -> object:
    return mi.Float(np.full(n, v, np.float32))


@pytest.mark.parametrize("sigma", [0.3, 1.5, 6.0, 14.0])
def test01_drjit_twins_match_numpy(
    mi: types.ModuleType, example: TinyExample, sigma: float
) -> None:
    """Float32 against float64, and a 2 x 2 Gauss-Legendre tile mass against 8 nodes:
    1e-3 in relative L1 (measured below 2e-4)."""
    q = np.random.default_rng(2).uniform(-0.45, 0.45, (1500, 2))
    c = np.array([9.3, 35.2])
    cov = np.array([[1.0, 0.35], [0.35, 0.7]]) * sigma**2
    n = len(q)
    fc = (_floats(mi, c[0], n), _floats(mi, c[1], n))
    fcov = Sym2(_floats(mi, cov[0, 0], n), _floats(mi, cov[0, 1], n), _floats(mi, cov[1, 1], n))
    fq = (mi.Float(q[:, 0].astype(np.float32)), mi.Float(q[:, 1].astype(np.float32)))
    jl = jit_lobes(mi, example.lobes)
    got = np.asarray(lobes_pndf(mi, jl, fc, fcov, fq).numpy())
    want = yan_pndf(example.lobes, c, cov, q)
    assert np.abs(got - want).sum() < 1e-3 * np.abs(want).sum()
    surf_ex = Surface(np.zeros((16, 16, 3)), Distribution(transform=TRANSFORM))
    got = jit_tiny(
        mi,
        jit_maps(mi, example.maps, example.extent),
        jl,
        (TRANSFORM.a, TRANSFORM.offset),
        fc,
        fcov,
        fq,
    )
    want = tiny_pndf(example, surf_ex, c, cov, q)
    got = np.asarray(got.numpy())
    assert np.abs(got - want).sum() < 1e-3 * np.abs(want).sum()


def _bsdf(mi: types.ModuleType, example: TinyExample, method: str = "tiny_example") -> Any:
    register_glint_bsdf(mi)
    eta, k = NAMED_CONDUCTORS["Al"]
    layer = GlintLayer(
        method=method,
        lobes=jit_lobes(mi, example.lobes),
        maps=jit_maps(mi, example.maps, example.extent),
        transform=(TRANSFORM.a, TRANSFORM.offset),
        texel_scale=1.0,
        fresnel=("conductor", eta, k),
        alpha=0.3,
        fallback_texels=16.0,
    )
    key = put_layers(f"test-{method}", layer)
    return mi.load_dict({"type": GLINT_BSDF_NAME, "layers": key, "texels_per_uv": TEXELS_PER_UV})


def _interaction(
    mi: types.ModuleType, wi: np.ndarray, duv: float, uv: np.ndarray | None = None
) -> object:
    import drjit as dr

    si = dr.zeros(mi.SurfaceInteraction3f, len(wi))
    si.wi = mi.Vector3f(*wi.T.astype(np.float32))
    si.uv = mi.Point2f(0.3, 0.7) if uv is None else mi.Point2f(*uv.T.astype(np.float32))
    si.duv_dx = mi.Vector2f(duv, 0.2 * duv)
    si.duv_dy = mi.Vector2f(-0.1 * duv, duv)
    return si


def _hemisphere(rng: np.random.Generator, n: int, max_deg: float = 80.0) -> np.ndarray:
    z = rng.uniform(math.cos(math.radians(max_deg)), 1.0, n)
    phi = rng.uniform(0.0, 2 * math.pi, n)
    r = np.sqrt(1 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


@pytest.mark.parametrize("duv", [0.01, 0.1])
def test02_value_against_numpy(mi: types.ModuleType, example: TinyExample, duv: float) -> None:
    """eval = D_P(h) G F / (4 cos_i cos_o) cos_o, with D_P, G and F from the numpy modules."""
    rng = np.random.default_rng(5)
    wi, wo = _hemisphere(rng, 400), _hemisphere(rng, 400)
    bsdf = _bsdf(mi, example)
    value = np.asarray(
        bsdf.eval(
            mi.BSDFContext(), _interaction(mi, wi, duv), mi.Vector3f(*wo.T.astype(np.float32))
        ),
        np.float64,
    ).T
    h = wi + wo
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    t = TEXELS_PER_UV
    c = np.array([0.3, 0.7]) * t
    cov = heckbert_covariance(np.array([duv, 0.2 * duv]) * t, np.array([-0.1 * duv, duv]) * t)
    cov += (1e-6 - 1e-8) * np.eye(2)  # the plugin's floor
    surf = Surface(np.zeros((16, 16, 3)), Distribution(transform=TRANSFORM))
    d = tiny_pndf(example, surf, c, cov, h[:, :2])
    g = smith_g1(wi[:, 2], np.sum(wi * h, 1), 0.3) * smith_g1(wo[:, 2], np.sum(wo * h, 1), 0.3)
    eta, k = NAMED_CONDUCTORS["Al"]
    cos_d = np.clip(np.sum(wi * h, 1), 0, 1)
    f = np.stack([fresnel_conductor(cos_d, eta[i], k[i]) for i in range(3)], axis=1)
    want = f * (d * g / (4 * wi[:, 2] * wo[:, 2]))[:, None] * wo[:, 2:3]
    assert np.allclose(value, want, rtol=2e-3, atol=2e-3 * want.max())


@pytest.mark.parametrize("method", ["tiny_example", "yan"])
def test03_reciprocity(mi: types.ModuleType, example: TinyExample, method: str) -> None:
    rng = np.random.default_rng(6)
    wi, wo = _hemisphere(rng, 500), _hemisphere(rng, 500)
    bsdf = _bsdf(mi, example, method)
    ctx = mi.BSDFContext()
    fw = (
        np.asarray(
            bsdf.eval(ctx, _interaction(mi, wi, 0.05), mi.Vector3f(*wo.T.astype(np.float32))),
            np.float64,
        ).T
        / wo[:, 2:3]
    )
    bw = (
        np.asarray(
            bsdf.eval(ctx, _interaction(mi, wo, 0.05), mi.Vector3f(*wi.T.astype(np.float32))),
            np.float64,
        ).T
        / wi[:, 2:3]
    )
    # float32: the half vector and footprint computed from swapped inputs round differently.
    assert np.allclose(fw, bw, rtol=1e-3, atol=1e-4 * fw.max())


@pytest.mark.parametrize("duv", [0.005, 0.2])
def test04_albedo_at_most_one(mi: types.ModuleType, example: TinyExample, duv: float) -> None:
    """The surface's albedo, ``int f cos dwo`` averaged over positions, is at most 1 for
    every ``wi`` (uniform-hemisphere Monte Carlo over random positions, 3 standard errors).

    Averaged over positions: the P-NDF of a footprint smaller than the microstructure's
    features is a few facets, and a facet tilted towards a grazing light catches more than
    ``cos theta_i`` per unit area, so one small footprint may reflect more than it receives
    (Yan et al.'s model is not energy-conserving per footprint); its mean over the surface
    is the bounded quantity."""
    rng = np.random.default_rng(7)
    bsdf = _bsdf(mi, example)
    n = 1 << 18
    for deg in (0.0, 40.0, 70.0):
        t = math.radians(deg)
        wi = np.tile([[math.sin(t), 0.0, math.cos(t)]], (n, 1))
        z = rng.uniform(0.0, 1.0, n)
        phi = rng.uniform(0.0, 2 * math.pi, n)
        r = np.sqrt(1 - z * z)
        wo = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)
        uv = rng.uniform(0.0, 1.0, (n, 2))
        si = _interaction(mi, wi, duv, uv)
        v = bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(*wo.T.astype(np.float32)))
        est = np.asarray(v, np.float64) * 2 * math.pi  # / pdf of the uniform hemisphere
        mean, err = est.mean(axis=1), est.std(axis=1) / math.sqrt(n)
        assert np.all(mean <= 1.0 + 3 * err), (deg, mean, err)


def test05_chi2_sampling(mi: types.ModuleType, example: TinyExample) -> None:
    """The directions ``sample`` draws follow ``pdf`` (1 M draws)."""
    _bsdf(mi, example)
    plugin = {
        "type": GLINT_BSDF_NAME,
        "layers": "test-tiny_example",
        "texels_per_uv": TEXELS_PER_UV,
    }
    ok, p, messages = direction_chi2(
        mi, plugin, (math.sin(0.5), 0.0, math.cos(0.5)), duv=((0.02, 0.0), (0.0, 0.02))
    )
    assert ok, messages


def _smooth(mi: types.ModuleType, alphas: tuple[float, float], alpha: float) -> Any:
    register_glint_bsdf(mi)
    eta, k = NAMED_CONDUCTORS["Al"]
    layer = GlintLayer(
        method="smooth_ggx",
        lobes=None,
        maps=None,
        transform=(np.eye(2), np.zeros(2)),
        texel_scale=1.0,
        fresnel=("conductor", eta, k),
        alpha=alpha,
        fallback_texels=16.0,
        alphas=alphas,
    )
    key = put_layers(f"test-smooth-{alphas}-{alpha}", layer)
    return mi.load_dict({"type": GLINT_BSDF_NAME, "layers": key, "texels_per_uv": TEXELS_PER_UV})


def test06_smooth_ggx_is_mitsubas_roughconductor(mi: types.ModuleType) -> None:
    """Isotropic ``smooth_ggx`` (``alphas = (a, a)``, Smith G of the same ``a``) is the
    microfacet conductor Mitsuba ships: its ``roughconductor`` (GGX) with Al's complex IOR."""
    rng = np.random.default_rng(11)
    wi, wo = _hemisphere(rng, 500), _hemisphere(rng, 500)
    eta, k = NAMED_CONDUCTORS["Al"]
    ref = mi.load_dict(
        {
            "type": "roughconductor",
            "distribution": "ggx",
            "alpha": 0.25,
            "eta": {"type": "rgb", "value": [float(v) for v in eta]},
            "k": {"type": "rgb", "value": [float(v) for v in k]},
        }
    )
    ctx = mi.BSDFContext()
    si = _interaction(mi, wi, 0.05)
    vo = mi.Vector3f(*wo.T.astype(np.float32))
    got = np.asarray(_smooth(mi, (0.25, 0.25), 0.25).eval(ctx, si, vo), np.float64)
    want = np.asarray(ref.eval(ctx, si, vo), np.float64)
    assert np.allclose(got, want, rtol=1e-4, atol=1e-5 * want.max())


def test07_smooth_ggx_anisotropic_closed_form(mi: types.ModuleType) -> None:
    """Anisotropic: ``D(h) = 1 / (pi a_u a_v (h_x^2 / a_u^2 + h_y^2 / a_v^2 + h_z^2)^2)``
    (Heitz 2014, Eq. 85) with the layer's isotropic Smith G and Al's Fresnel, in numpy."""
    rng = np.random.default_rng(12)
    wi, wo = _hemisphere(rng, 500), _hemisphere(rng, 500)
    au, av, alpha = 0.08, 0.35, 0.2
    value = np.asarray(
        _smooth(mi, (au, av), alpha).eval(
            mi.BSDFContext(), _interaction(mi, wi, 0.05), mi.Vector3f(*wo.T.astype(np.float32))
        ),
        np.float64,
    ).T
    h = wi + wo
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    q = h[:, 0] ** 2 / au**2 + h[:, 1] ** 2 / av**2 + h[:, 2] ** 2
    d = 1.0 / (math.pi * au * av * q**2)
    g = smith_g1(wi[:, 2], np.sum(wi * h, 1), alpha) * smith_g1(wo[:, 2], np.sum(wo * h, 1), alpha)
    eta, k = NAMED_CONDUCTORS["Al"]
    cos_d = np.clip(np.sum(wi * h, 1), 0, 1)
    f = np.stack([fresnel_conductor(cos_d, eta[i], k[i]) for i in range(3)], axis=1)
    want = f * (d * g / (4 * wi[:, 2] * wo[:, 2]))[:, None] * wo[:, 2:3]
    assert np.allclose(value, want, rtol=2e-3, atol=2e-4 * want.max())


def test08_slope_alphas_recover_beckmann_roughness() -> None:
    """Beckmann slopes are Gaussian with variance ``alpha^2 / 2`` per axis (Walter et al.
    2007, Eq. 25): normals drawn so give back ``(alpha_u, alpha_v)``; ``sigma_r`` adds
    ``2 sigma_r^2`` to each ``alpha^2``; the mean of the squares is matching_alpha's."""
    from evaluators.render.sources.glint import matching_alpha, slope_alphas

    rng = np.random.default_rng(13)
    au, av = 0.1, 0.3
    su = rng.normal(0.0, au / math.sqrt(2.0), 400_000)
    sv = rng.normal(0.0, av / math.sqrt(2.0), 400_000)
    n = np.stack([-su, -sv, np.ones_like(su)], axis=1)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    got = slope_alphas(n, 0.0)
    assert got == pytest.approx((au, av), rel=5e-3)
    r = 0.05 * math.sqrt(2.0)
    assert slope_alphas(n, 0.05) == pytest.approx((math.hypot(au, r), math.hypot(av, r)), rel=5e-3)
    # The isotropic match of the same sample: alpha^2 = (alpha_u^2 + alpha_v^2) / 2.
    normals = procedural_example("brushed_metal", 16, np.random.default_rng(1))
    surf = Surface(normals, Distribution(transform=Transform.compose()))
    from materials.glints.surface import export_normal_map

    u, v = slope_alphas(export_normal_map(surf, 64), 0.02)
    assert matching_alpha(surf, 0.02) == pytest.approx(math.sqrt((u * u + v * v) / 2), rel=1e-6)
    assert u > 1.5 * v or v > 1.5 * u  # brushing: one direction much rougher
