"""Independent references for the fabric tests, written from the papers, not from our code.

- SGGX with explicit 3x3 matrices (Heitz et al. 2015, Eq. 9 and 11): ``S = R^T diag(1, 1,
  alpha^2) R`` with ``R``'s third row the fibre direction, ``D(m) = 1 / (pi sqrt(det S)
  (m^T S^-1 m)^2)``, ``sigma(w) = sqrt(w^T S w)``, matrix inverse and determinant by numpy.
- SpongeCake single scattering (Wang et al. 2022) by numerical integration over the optical
  depth of the slab (Gauss-Legendre), instead of the closed forms of ``shading.py``:
  ``f = D(h) / (4 |c_i| |c_o|) int_0^{T rho} exp(-tau L_i) exp(-tau' L_o) dtau`` with
  ``tau' = tau`` for reflection and ``T rho - tau`` for transmission.
- Spherical quadrature: Gauss-Legendre in cos(theta) times the midpoint rule in phi.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np


@lru_cache(maxsize=4)
def _gauss(nodes: int) -> tuple[np.ndarray, np.ndarray]:
    return np.polynomial.legendre.leggauss(nodes)


def sggx_matrix(n: np.ndarray, t: np.ndarray, alpha: float) -> np.ndarray:
    """``S = R^T diag(1, 1, alpha^2) R``, R's rows (n x t, n, t); ``(3, 3)`` or ``(N, 3, 3)``."""
    r = np.stack([np.cross(n, t), n, t], axis=-2)
    diag = np.diag([1.0, 1.0, alpha * alpha])
    return np.swapaxes(r, -1, -2) @ diag @ r


def sggx_ndf(m: np.ndarray, s: np.ndarray) -> np.ndarray:
    """D(m) for unit rows m; ``s`` one matrix or one per row."""
    inv = np.linalg.inv(s)
    q = np.einsum("...i,...ij,...j->...", m, inv, m)
    return 1.0 / (np.pi * np.sqrt(np.linalg.det(s)) * q * q)


def sggx_sigma(w: np.ndarray, s: np.ndarray) -> np.ndarray:
    return np.sqrt(np.einsum("...i,...ij,...j->...", w, s, w))


def slab_specular(
    wi: np.ndarray,
    wo: np.ndarray,
    n: np.ndarray,
    t: np.ndarray,
    alpha: float,
    t_rho: float = 2.0,
    nodes: int = 256,
) -> np.ndarray:
    """Specular BSDF (unit albedo) of a fibre-microflake slab, float64.

    ``wi``, ``wo``: ``(N, 3)``; ``n``, ``t``: one ``(3,)`` frame or ``(N, 3)`` per row.
    """
    s = sggx_matrix(n, t, alpha)
    h = wi + wo
    h = h / np.linalg.norm(h, axis=1, keepdims=True)
    d = sggx_ndf(h, s)
    ci = np.einsum("ni,...i->n", wi, n) if n.ndim == 1 else np.einsum("ni,ni->n", wi, n)
    co = np.einsum("ni,...i->n", wo, n) if n.ndim == 1 else np.einsum("ni,ni->n", wo, n)
    lam_i = sggx_sigma(wi, s) / np.abs(ci)
    lam_o = sggx_sigma(wo, s) / np.abs(co)
    x, wq = _gauss(nodes)
    tau = 0.5 * t_rho * (x + 1.0)
    wq = 0.5 * t_rho * wq
    reflect = (ci * co > 0)[:, None]
    tau_out = np.where(reflect, tau[None, :], t_rho - tau[None, :])
    g = (np.exp(-tau[None, :] * lam_i[:, None] - tau_out * lam_o[:, None]) * wq).sum(axis=1)
    return d * g / (4.0 * np.abs(ci) * np.abs(co))


def sphere_quadrature(n_theta: int = 160, n_phi: int = 320) -> tuple[np.ndarray, np.ndarray]:
    """Unit directions over the whole sphere and their solid-angle weights (sum 4 pi)."""
    x, w = np.polynomial.legendre.leggauss(n_theta)
    phi = (np.arange(n_phi) + 0.5) * (2 * np.pi / n_phi)
    ct = np.repeat(x, n_phi)
    st = np.sqrt(1 - ct * ct)
    ph = np.tile(phi, n_theta)
    dirs = np.stack([st * np.cos(ph), st * np.sin(ph), ct], axis=1)
    weights = np.repeat(w, n_phi) * (2 * np.pi / n_phi)
    return dirs, weights


def hemisphere_quadrature(n_theta: int = 64, n_phi: int = 128) -> tuple[np.ndarray, np.ndarray]:
    """Unit directions with z > 0 and their solid-angle weights (sum 2 pi)."""
    x, w = np.polynomial.legendre.leggauss(n_theta)
    ct = 0.5 * (x + 1.0)
    w = 0.5 * w
    phi = (np.arange(n_phi) + 0.5) * (2 * np.pi / n_phi)
    st = np.sqrt(1 - ct * ct)
    c = np.repeat(ct, n_phi)
    s = np.repeat(st, n_phi)
    ph = np.tile(phi, n_theta)
    dirs = np.stack([s * np.cos(ph), s * np.sin(ph), c], axis=1)
    return dirs, np.repeat(w, n_phi) * (2 * np.pi / n_phi)


def direction(theta_deg: float, phi_deg: float) -> np.ndarray:
    th, ph = np.radians(theta_deg), np.radians(phi_deg)
    return np.array([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)])
