"""Point BSDF of a yarn (Eq. 1-2): SGGX fibre flakes, SpongeCake slab, blended Lambertian.

Oracles (``slab_reference.py``, written from Heitz et al. 2015 and Wang et al. 2022, not
from ``shading.py``): SGGX with explicit 3x3 matrices; the single-scattering slab by
numerical integration over optical depth instead of the closed forms; the SGGX identities
(normalised phase function, sigma as the projected area of D) by spherical quadrature;
energy: reflection plus transmission of a white slab equals its single-scattered fraction,
below ``1 - exp(-T rho Lambda_i)``; reciprocity of the specular term.
"""

from __future__ import annotations

import numpy as np
import pytest

from materials.fabric import shading
from materials.fabric.array_ops import NumpyOps
from tests.helpers.slab_reference import (
    direction,
    hemisphere_quadrature,
    sggx_matrix,
    sggx_ndf,
    sggx_sigma,
    slab_specular,
    sphere_quadrature,
)

OPS = NumpyOps()


def random_frame(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A random ply normal near +z and a unit fibre direction orthogonal to it."""
    n = rng.normal(size=3) * 0.4 + np.array([0, 0, 1.0])
    n /= np.linalg.norm(n)
    t = np.cross(n, rng.normal(size=3))
    return n, t / np.linalg.norm(t)


def cols(a: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return a[:, 0], a[:, 1], a[:, 2]


def vec(v: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return cols(np.broadcast_to(v, (count, 3)))


@pytest.mark.parametrize("alpha", [0.15, 0.4, 1.0])
def test01_sggx_matches_explicit_matrices(alpha: float) -> None:
    rng = np.random.default_rng(1)
    n, t = random_frame(rng)
    s = sggx_matrix(n, t, alpha)
    w = rng.normal(size=(500, 3))
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    np.testing.assert_allclose(shading.fiber_ndf(OPS, w @ t, alpha), sggx_ndf(w, s), rtol=1e-10)
    np.testing.assert_allclose(shading.fiber_sigma(OPS, w @ t, alpha), sggx_sigma(w, s), rtol=1e-10)


@pytest.mark.parametrize("alpha", [0.3, 0.6, 1.0])
def test02_sggx_identities_by_quadrature(alpha: float) -> None:
    """sigma(w) = int <w.m>+ D(m) dm and the phase function D(h)/(4 sigma) integrates to 1."""
    rng = np.random.default_rng(2)
    n, t = random_frame(rng)
    dirs, weights = sphere_quadrature(200, 400)
    d = shading.fiber_ndf(OPS, dirs @ t, alpha)
    for w in (direction(10, 30), direction(60, 100), t):
        projected = np.sum(np.maximum(dirs @ w, 0.0) * d * weights)
        sigma = float(shading.fiber_sigma(OPS, np.array([w @ t]), alpha)[0])
        assert projected == pytest.approx(sigma, rel=2e-3)
        h = dirs + w
        h /= np.linalg.norm(h, axis=1, keepdims=True)
        phase = shading.fiber_ndf(OPS, h @ t, alpha) / (4 * sigma)
        assert np.sum(phase * weights) == pytest.approx(1.0, rel=5e-3)


@pytest.mark.parametrize("alpha", [0.2, 0.5])
def test03_slab_closed_forms_match_depth_integration(alpha: float) -> None:
    rng = np.random.default_rng(3)
    n, t = random_frame(rng)
    wi = rng.normal(size=(400, 3))
    wo = rng.normal(size=(400, 3))
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    ours = shading.specular_bsdf(OPS, cols(wi), cols(wo), vec(n, 400), vec(t, 400), alpha)
    ref = slab_specular(wi, wo, n, t, alpha)
    both_sides = (wi @ n) * (wo @ n)
    assert np.any(both_sides > 0) and np.any(both_sides < 0)  # reflection and transmission
    np.testing.assert_allclose(ours, ref, rtol=1e-6)


def test04_transmission_limit_of_equal_lambdas() -> None:
    """G_T at L_i = L_o is T rho exp(-T rho L): the series branch is continuous."""
    lam = np.array([0.3, 1.0, 2.5])
    for eps in (0.0, 1e-7, 1e-3):
        g = shading.slab_transmission_g(OPS, lam, lam + eps, 2.0)
        np.testing.assert_allclose(g, 2.0 * np.exp(-2.0 * lam), rtol=2e-3)
    g_r = shading.slab_reflection_g(OPS, np.array([1e-9]), np.array([0.0]), 2.0)
    assert g_r[0] == pytest.approx(2.0, rel=1e-6)


def test05_specular_is_reciprocal_in_reflection_and_transmission() -> None:
    rng = np.random.default_rng(5)
    for _ in range(5):
        n, t = random_frame(rng)
        wi = rng.normal(size=(300, 3))
        wo = rng.normal(size=(300, 3))
        wi /= np.linalg.norm(wi, axis=1, keepdims=True)
        wo /= np.linalg.norm(wo, axis=1, keepdims=True)
        f = shading.specular_bsdf(OPS, cols(wi), cols(wo), vec(n, 300), vec(t, 300), 0.3)
        g = shading.specular_bsdf(OPS, cols(wo), cols(wi), vec(n, 300), vec(t, 300), 0.3)
        np.testing.assert_allclose(f, g, rtol=1e-10)
        dw = shading.diffuse_bsdf(OPS, cols(wi), cols(wo), vec(n, 300), 1.0)
        dr = shading.diffuse_bsdf(OPS, cols(wo), cols(wi), vec(n, 300), 1.0)
        ok = (wi[:, 2] > 0) & (wo[:, 2] > 0)  # diffuse is lit from above only
        np.testing.assert_allclose(dw[ok], dr[ok], rtol=1e-10)


@pytest.mark.parametrize("theta_i", [0.0, 45.0, 80.0])
def test06_white_slab_energy(theta_i: float) -> None:
    """R + T of a white slab = its single-scattered energy < 1 - exp(-T rho Lambda_i)."""
    rng = np.random.default_rng(6)
    n = np.array([0.0, 0.0, 1.0])
    t = np.array([1.0, 0.0, 0.0])
    wi = direction(theta_i, 30.0)
    dirs, weights = sphere_quadrature(200, 400)
    count = len(dirs)
    f = shading.specular_bsdf(OPS, vec(wi, count), cols(dirs), vec(n, count), vec(t, count), 0.4)
    energy = np.sum(f * np.abs(dirs[:, 2]) * weights)
    ref = np.sum(
        slab_specular(np.broadcast_to(wi, dirs.shape), dirs, n, t, 0.4)
        * np.abs(dirs[:, 2])
        * weights
    )
    lam_i = float(shading.fiber_sigma(OPS, np.array([wi @ t]), 0.4)[0]) / max(wi[2], 1e-6)
    assert energy == pytest.approx(ref, rel=1e-3)
    assert 0.0 < energy < 1.0 - np.exp(-2.0 * lam_i)
    del rng


@pytest.mark.parametrize("w", [0.0, 0.5, 1.0])
def test07_blended_lambertian_albedo(w: float) -> None:
    """Albedo about the ply normal: w + (1 - w) min(1, <wi.n_s> / <wi.n_p>) <= 1 (closed form)."""
    dirs, weights = hemisphere_quadrature()
    count = len(dirs)
    n = np.array([np.sin(0.4), 0.0, np.cos(0.4)])  # a ply tilted by 23 deg
    # Rotate the quadrature hemisphere onto the ply's hemisphere.
    z = n
    x = np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    wo = dirs @ np.stack([x, y, z])
    for wi in (direction(30, 0), direction(30, 180), direction(70, 90)):
        f = shading.diffuse_bsdf(OPS, vec(wi, count), cols(wo), vec(n, count), w)
        albedo = np.sum(f * (wo @ n) * weights)
        ci, cs = wi @ n, wi[2]
        assert albedo == pytest.approx(w + (1 - w) * min(1.0, cs / ci), rel=1e-3)
        assert albedo <= 1.0 + 1e-6
    flat = shading.diffuse_bsdf(
        OPS, vec(direction(40, 0), 3), vec(direction(20, 5), 3), vec(np.array([0, 0, 1.0]), 3), w
    )
    np.testing.assert_allclose(flat, 1.0 / np.pi)


def test08_no_diffuse_from_below_and_no_nan_at_grazing() -> None:
    n = np.array([0.0, 0.0, 1.0])
    t = np.array([0.0, 1.0, 0.0])
    below = direction(120, 10)
    up = direction(30, 200)
    f = shading.diffuse_bsdf(OPS, vec(below, 1), vec(up, 1), vec(n, 1), 0.6)
    assert f[0] == 0.0
    graze = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.6, 0.8, 0.0]])
    for a, b in ((graze, graze[::-1]), (graze, -graze)):
        s = shading.specular_bsdf(OPS, cols(a), cols(b), vec(n, 3), vec(t, 3), 0.3)
        assert np.all(np.isfinite(s)) and np.all(s >= 0)
