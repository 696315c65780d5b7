"""Microfacet terms and the analytic sources built on them.

Oracles: Mitsuba 3's own ``roughconductor``, ``diffuse`` and ``roughplastic`` evaluated here
directly (``bsdf.eval / wo.z``); closed forms (normal-incidence Fresnel, total internal
reflection); Walter et al. 2007's stated accuracy of the Beckmann approximation; Monte Carlo
integration for energy conservation; and the symmetry of reciprocal BRDFs.
"""

from __future__ import annotations

import types

import numpy as np
import pytest

from materials import microfacet as mf
from materials.analytic import (
    ANALYTIC_MODELS,
    BeckmannConductor,
    GGXConductor,
    Lambert,
    Plastic,
    ThinFilmGGX,
    build_analytic,
)
from tests.helpers.mitsuba_probes import mitsuba_brdf


@pytest.fixture(scope="module")
def mi() -> types.ModuleType:
    from materials.backend import load_mitsuba

    return load_mitsuba()


def pairs(seed: int, n: int = 20000, min_cos: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)

    def one() -> np.ndarray:
        z = rng.uniform(min_cos, 1.0, n)
        phi = rng.uniform(0, 2 * np.pi, n)
        s = np.sqrt(1 - z * z)
        return np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=1)

    return one(), one()


def relative(a: np.ndarray, b: np.ndarray, floor: float = 1e-6) -> np.ndarray:
    return np.abs(a - b) / np.maximum(np.abs(b), floor)


@pytest.mark.parametrize(
    "source",
    [
        GGXConductor(alpha=0.3, material="Au"),
        GGXConductor(alpha=0.05, material="Cu"),
        GGXConductor(alpha=0.8, eta=(1.2, 0.9, 0.4), k=(4.0, 3.0, 2.5)),
        BeckmannConductor(alpha=0.3, material="Al"),
        BeckmannConductor(alpha=0.7, eta=(1.5, 1.2, 0.3), k=(3.0, 2.0, 1.0)),
    ],
    ids=["ggx-Au-0.3", "ggx-Cu-0.05", "ggx-rgb-0.8", "beckmann-Al-0.3", "beckmann-rgb-0.7"],
)
def test01_conductors_match_mitsuba(mi: types.ModuleType, source) -> None:
    wi, wo = pairs(1)
    ours = source.eval(wi, wo)
    theirs = mitsuba_brdf(mi, source.mitsuba_dict(), wi, wo)
    # Mitsuba computes in float32: relative agreement ~1e-5 where values are not tiny.
    assert np.max(relative(ours, theirs)[theirs > 1e-6]) < 1e-4


def test02_named_conductors_are_mitsubas(mi: types.ModuleType) -> None:
    for name, (eta, k) in mf.NAMED_CONDUCTORS.items():
        params = mi.traverse(mi.load_dict({"type": "roughconductor", "material": name}))
        m_eta = np.broadcast_to(np.array(params["eta.value"], np.float64).ravel(), (3,))
        m_k = np.broadcast_to(np.array(params["k.value"], np.float64).ravel(), (3,))
        # Mitsuba holds them as float32: half an ulp, 6e-8.
        np.testing.assert_allclose(eta, m_eta, rtol=1e-6, err_msg=name)
        np.testing.assert_allclose(k, m_k, rtol=1e-6, err_msg=name)
    with pytest.raises(ValueError, match="unknown conductor"):
        mf.named_conductor("Unobtainium")


def test03_lambert_matches_mitsuba(mi: types.ModuleType) -> None:
    wi, wo = pairs(2, 2000)
    src = Lambert(albedo=(0.2, 0.5, 0.8))
    # Mitsuba's albedo / pi and eval / wo.z in float32: an ulp or so (measured 9.6e-8).
    np.testing.assert_allclose(
        src.eval(wi, wo), mitsuba_brdf(mi, src.mitsuba_dict(), wi, wo), rtol=1e-6
    )


@pytest.mark.parametrize(
    "source",
    [
        Plastic(alpha=0.3, diffuse=(0.2, 0.5, 0.8)),
        Plastic(alpha=0.1),
        Plastic(alpha=0.3, distribution="beckmann", nonlinear=True, diffuse=(0.9, 0.5, 0.1)),
    ],
    ids=["ggx-0.3", "ggx-0.1", "beckmann-nonlinear"],
)
def test04_plastic_matches_mitsuba_roughplastic(mi: types.ModuleType, source: Plastic) -> None:
    # Same model; the rough-interface transmittance and internal reflectance come from
    # different quadratures (ours: 64x64 Gauss-Legendre over NDF-mapped normals; Mitsuba's:
    # 32x32 over visible normals in float32), which differ by a few tenths of a percent.
    wi, wo = pairs(3)
    theirs = mitsuba_brdf(mi, source.mitsuba_dict(), wi, wo)
    assert np.max(relative(source.eval(wi, wo), theirs)) < 1e-2


def test05_fresnel_closed_forms() -> None:
    eta, k = np.array([0.2, 1.1, 2.5]), np.array([3.9, 0.0, 1.0])
    normal = ((eta - 1) ** 2 + k**2) / ((eta + 1) ** 2 + k**2)
    np.testing.assert_allclose(mf.fresnel_conductor(1.0, eta, k), normal, rtol=1e-12)
    np.testing.assert_allclose(mf.fresnel_conductor(0.0, eta, k), 1.0)
    assert mf.fresnel_dielectric(1.0, 1.5) == pytest.approx((0.5 / 2.5) ** 2)
    # k = 0 reduces the conductor formula to the dielectric one.
    c = np.linspace(0.01, 1, 50)
    np.testing.assert_allclose(
        mf.fresnel_conductor(c, 1.5, 0.0), mf.fresnel_dielectric(c, 1.5), rtol=1e-10
    )
    # Total internal reflection from the dense side beyond the critical angle.
    crit = np.sqrt(1 - (1 / 1.5) ** 2)
    assert np.all(mf.fresnel_dielectric(np.array([crit * 0.99, 0.1]), 1 / 1.5) == 1.0)
    assert mf.fresnel_dielectric(0.9, 1 / 1.5) < 1.0


def test06_beckmann_approximation_is_walters() -> None:
    cos_v = np.linspace(0.01, 1.0, 500)
    for alpha in (0.05, 0.3, 1.0):
        approx = mf.smith_g1(cos_v, 1.0, alpha, "beckmann")
        exact = mf.smith_g1(cos_v, 1.0, alpha, "beckmann", exact_beckmann=True)
        assert np.max(np.abs(approx - exact) / exact) < 4e-3  # Walter 2007: < 0.35 %


def test07_ndf_normalised_and_g2_bounds() -> None:
    x, w = np.polynomial.legendre.leggauss(200)
    # int D(m) cos_m dm = 2 pi int_0^1 D(mu) mu dmu, mu = cos_m
    for dist in ("ggx", "beckmann"):
        for alpha in (0.2, 0.6):
            # substitute mu = t^4 to resolve the peak at mu = 1
            t = 0.5 * (x + 1)
            mu = 1 - (1 - t) ** 4
            jac = 4 * (1 - t) ** 3
            integral = 2 * np.pi * np.sum(0.5 * w * mf.ndf(mu, alpha, dist) * mu * jac)
            assert integral == pytest.approx(1.0, rel=2e-3)
    cos = np.linspace(0.05, 1, 20)
    g_sep = mf.smith_g2(cos[:, None], cos[None, :], 1.0, 0.5, "ggx", "separable")
    g_hc = mf.smith_g2(cos[:, None], cos[None, :], 1.0, 0.5, "ggx", "height_correlated")
    # Heitz 2014: the height-correlated form is never below the separable one.
    assert np.all(g_hc >= g_sep - 1e-12) and np.all(g_hc <= 1.0)


@pytest.mark.parametrize(
    "source",
    [
        GGXConductor(alpha=0.3, material="none"),
        GGXConductor(alpha=0.8, material="none"),
        BeckmannConductor(alpha=0.5, material="none"),
        GGXConductor(alpha=0.5, material="Au", shadowing="height_correlated"),
    ],
    ids=["ggx-mirror-0.3", "ggx-mirror-0.8", "beckmann-mirror-0.5", "ggx-hc-Au"],
)
def test08_energy_conservation(source) -> None:
    # Monte Carlo: albedo = int f cos_o dwo <= 1, cosine-weighted sampling of wo.
    rng = np.random.default_rng(8)
    n = 400_000
    u1, u2 = rng.random(n), rng.random(n)
    r, phi = np.sqrt(u1), 2 * np.pi * u2
    wo = np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(1 - u1)], axis=1)
    for theta in (0.0, 0.8, 1.3):
        wi = np.tile([np.sin(theta), 0.0, np.cos(theta)], (n, 1))
        samples = source.eval(wi, wo)[:, 1] * np.pi  # f cos / pdf, pdf = cos / pi
        mean, err = samples.mean(), samples.std() / np.sqrt(n)
        assert mean <= 1.0 + 4 * err
        # The quadrature albedo of the same lobe agrees with the Monte Carlo estimate.
        quad = mf.specular_albedo(
            np.array([np.cos(theta)]),
            source.alpha,
            lambda c, s=source: mf.fresnel_conductor(c, s.eta[1], s.k[1]),
            distribution=source.distribution,
            shadowing=source.shadowing,
        )[0]
        assert abs(quad - mean) < 5 * err + 1e-3


@pytest.mark.parametrize("name", sorted(ANALYTIC_MODELS))
def test09_reciprocity(name: str) -> None:
    wi, wo = pairs(9, 3000)
    src = build_analytic(
        {"model": name, "material": "Cu"}
        if name in ("ggx", "beckmann", "thin_film_ggx")
        else {"model": name}
    )
    np.testing.assert_allclose(src.eval(wi, wo), src.eval(wo, wi), rtol=1e-9, atol=1e-12)


def test10_registry_and_validation() -> None:
    src = build_analytic({"model": "ggx", "alpha": 0.2, "eta": [1, 1, 1], "k": [3, 3, 3]})
    assert isinstance(src, GGXConductor) and src.eta == (1.0, 1.0, 1.0)
    assert isinstance(build_analytic({"model": "thin_film_ggx", "material": "Al"}), ThinFilmGGX)
    with pytest.raises(ValueError, match="unknown analytic model"):
        build_analytic({"model": "phong"})
    with pytest.raises(ValueError, match="no parameter"):
        build_analytic({"model": "lambert", "roughness": 1})
    with pytest.raises(ValueError, match="alpha"):
        GGXConductor(alpha=0.0, material="Au")
    with pytest.raises(ValueError, match="either material or eta"):
        GGXConductor(alpha=0.1, material="Au", eta=(1, 1, 1), k=(1, 1, 1))
    with pytest.raises(ValueError, match="albedo"):
        Lambert(albedo=(1.2, 0.5, 0.5))
    with pytest.raises(ValueError, match="eta"):
        Plastic(eta=1.0)
