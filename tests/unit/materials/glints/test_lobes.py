"""4D Gaussian lobes and the closed forms of Eq. 1 (Yan et al. 2016; Xing et al. 2024).

Oracles, none of them the closed forms under test:

- the bilinear field reproduces the texel normals at texel centres, and its Jacobian
  matches central finite differences;
- a lobe's normal marginal against Monte Carlo samples of the 4D Gaussian it stands for;
- Eq. 1 against numerical quadrature of ``G_P(u) G_i(u, s)`` over ``u``;
- a flat example (all normals up) gives the Gaussian of width sigma_r, and the P-NDF of a
  footprint of a few texels integrates to 1 over ``s`` (Riemann sum).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from materials.glints.examples import procedural_example
from materials.glints.footprint import yan_pndf
from materials.glints.lobes import bilinear, make_lobes, pndf


@pytest.fixture(scope="module")
def normals() -> np.ndarray:
    return procedural_example("leather", 16, np.random.default_rng(5))


def test01_bilinear_field(normals: np.ndarray) -> None:
    y, x = np.mgrid[0:16, 0:16] + 0.5
    s, _ = bilinear(normals, np.stack([x.ravel(), y.ravel()], axis=1))
    assert np.allclose(s, normals[..., :2].reshape(-1, 2), atol=1e-7)
    u = np.random.default_rng(0).uniform(0, 16, (200, 2))
    u = u[np.all(np.abs((u - 0.5) % 1.0 - 0.5) > 0.01, axis=1)]  # off the kinks
    _, jac = bilinear(normals, u)
    eps = 1e-5
    for b in (0, 1):
        d = np.zeros(2)
        d[b] = eps
        fd = (bilinear(normals, u + d)[0] - bilinear(normals, u - d)[0]) / (2 * eps)
        assert np.allclose(jac[:, :, b], fd, atol=1e-6)


def test02_normal_marginal_against_monte_carlo(normals: np.ndarray) -> None:
    """N(s; s_i, sigma_r^2 I + sigma_h^2 J J^T) is the s-marginal of the 4D lobe."""
    lobes = make_lobes(normals, rate=2, sigma_r=0.03)
    i = int(np.argmax(np.abs(lobes.jac).sum(axis=(1, 2))))  # the most sheared lobe
    rng = np.random.default_rng(1)
    n = 400_000
    du = rng.normal(0.0, lobes.sigma_h, (n, 2))
    s = lobes.s[i] + du @ lobes.jac[i].T + rng.normal(0.0, lobes.sigma_r, (n, 2))
    cov = np.cov(s.T)
    # Sample covariance: relative standard error about sqrt(2 / n) = 0.2 %; 5 sigma.
    assert np.allclose(cov, lobes.normal_covariances()[i], rtol=0.012, atol=1e-7)
    assert np.allclose(s.mean(axis=0), lobes.s[i], atol=5 * math.sqrt(cov.max() / n))


def test03_eq1_against_quadrature(normals: np.ndarray) -> None:
    """Eq. 1's closed form for one lobe = the u-integral of G_P(u) G_i(u, s) on a grid."""
    lobes = make_lobes(normals, rate=2, sigma_r=0.02)
    i = 200
    c = lobes.u[i] + np.array([0.1, -0.07])
    cov = np.array([[0.09, 0.02], [0.02, 0.05]])
    s = lobes.s[i] + np.random.default_rng(2).normal(0.0, 0.03, (20, 2))
    closed = pndf(lobes, c, cov, s, index=np.array([i]))
    g = np.linspace(-3, 3, 601)
    uu = np.stack(np.meshgrid(g, g, indexing="ij"), axis=-1).reshape(-1, 2) + lobes.u[i]
    du = uu - lobes.u[i]
    inv = np.linalg.inv(cov)
    d = uu - c
    gp = np.exp(-0.5 * np.einsum("ka,ab,kb->k", d, inv, d)) / (
        2 * math.pi * math.sqrt(np.linalg.det(cov))
    )
    gu = np.exp(-0.5 * (du**2).sum(1) / lobes.sigma_h**2) / (2 * math.pi * lobes.sigma_h**2)
    mean = lobes.s[i] + du @ lobes.jac[i].T
    r2 = lobes.sigma_r**2
    dens = np.exp(-0.5 * ((s[:, None, :] - mean[None]) ** 2).sum(-1) / r2) / (2 * math.pi * r2)
    quad = lobes.weight * (dens * (gp * gu)[None]).sum(axis=1) * (g[1] - g[0]) ** 2
    assert np.allclose(closed, quad, rtol=1e-6, atol=1e-9 * closed.max())


def test04_flat_example_is_a_gaussian_of_width_sigma_r() -> None:
    flat = np.zeros((16, 16, 3), np.float32)
    flat[..., 2] = 1.0
    sr = 0.05
    lobes = make_lobes(flat, rate=2, sigma_r=sr)
    s = np.random.default_rng(3).uniform(-0.15, 0.15, (50, 2))
    got = yan_pndf(lobes, np.array([3.3, 9.1]), np.eye(2) * 2.0, s)
    want = np.exp(-0.5 * (s**2).sum(1) / sr**2) / (2 * math.pi * sr**2)
    # The seeds' Gaussians sum to 1 up to a ripple exp(-2 pi^2 (sigma_h^2 + Sigma_P) / h^2),
    # negligible for a footprint of 1.4 texels; the reference leaves out seeds beyond the
    # footprint's support box (3.5 sigma + 5 sigma_h per axis): 2 x 2 Phi(-4.2) = 5e-5.
    assert np.allclose(got, want, rtol=1e-4)


def test05_pndf_integrates_to_one(normals: np.ndarray) -> None:
    lobes = make_lobes(normals, rate=2, sigma_r=0.02)
    g = np.linspace(-1.2, 1.2, 241)
    s = np.stack(np.meshgrid(g, g, indexing="ij"), axis=-1).reshape(-1, 2)
    for c, sig in (((4.0, 5.0), 1.0), ((15.5, 0.2), 2.0)):
        d = yan_pndf(lobes, np.array(c), np.eye(2) * sig**2, s)
        # Riemann sum with steps of sigma_r / 2 (exact to ~1e-9 for Gaussians that fine);
        # the support box holds all but ~1e-4; the seed ripple is below 1e-3 here.
        assert d.sum() * (g[1] - g[0]) ** 2 == pytest.approx(1.0, abs=2e-3)
