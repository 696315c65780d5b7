"""Position-normal 4D Gaussian lobes of a normal map (Yan et al. 2016; Xing et al. 2024, Sec. 3.2).

The normal field ``s(u)`` (projected normals, bilinear between texel centres, tiled; see
:mod:`materials.glints.examples` for the conventions) is covered by seeds on a regular grid
of spacing ``h = 1 / rate`` texels. Seed ``i`` at ``u_i`` carries a 4D Gaussian lobe

    G_i(u, s) = w N(u; u_i, sigma_h^2 I) N(s; s_i + J_i (u - u_i), sigma_r^2 I),

which is the paper's ``c_i exp(-1/2 x^T Sigma_i^-1 x)`` with its ``Sigma_i^-1``: the quadratic
form ``|du|^2 / sigma_h^2 + |ds - J du|^2 / sigma_r^2`` expands to exactly the two blocks of
Sec. 3.2. ``J_i`` is the Jacobian ``ds/du`` of the bilinear field at ``u_i``; ``sigma_h =
h / sqrt(8 ln 2)`` (the seed Gaussians' full width at half maximum is their spacing, as in
Yan et al. 2016), ``sigma_r`` the intrinsic roughness; ``w = h^2`` (texel^2), so that the
seeds' spatial Gaussians sum to about 1 per unit area and ``N(u, s) = sum_i G_i`` is a
density of normals per unit area.

Two closed forms follow, both products of Gaussians:

- the lobe's **normal marginal** (``u`` integrated out): ``N(s; s_i, sigma_r^2 I +
  sigma_h^2 J J^T)`` -- what a tile's NDF image averages (Eq. 2);
- **Eq. 1** against a normalised Gaussian footprint ``G_P(u) = N(u; c, Sigma_P)``:
  ``int G_P G_i du = w N(c; u_i, sigma_h^2 I + Sigma_P) N(s; s_i + J (m - u_i), sigma_r^2 I +
  J S J^T)`` with ``S = (I / sigma_h^2 + Sigma_P^-1)^-1`` and ``m = S (u_i / sigma_h^2 +
  Sigma_P^-1 c)``.

Units: ``u`` in texels of the map, ``s`` dimensionless. Arrays are float64 here; what is
stored (``lobes.npz``) is float32.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: Ratio sigma_h / h: full width at half maximum equal to the seed spacing.
SIGMA_H_PER_SPACING = 1.0 / math.sqrt(8.0 * math.log(2.0))
#: Bytes of one stored lobe: u (2), s (2), J (4) as float32.
LOBE_BYTES = 32


@dataclass(frozen=True)
class Lobes:
    """The lobes of a normal map. ``u`` ``(N, 2)`` seed positions (texels, x then y),
    ``s`` ``(N, 2)`` projected normals there, ``jac`` ``(N, 2, 2)`` with ``jac[:, a, b] =
    ds_a / du_b``; ``size`` the map's side ``n`` (it tiles with that period), ``rate`` seeds
    per texel per axis, ``sigma_h`` and ``sigma_r`` as in the module docstring."""

    u: np.ndarray
    s: np.ndarray
    jac: np.ndarray
    size: int
    rate: int
    sigma_h: float
    sigma_r: float

    @property
    def weight(self) -> float:
        """Each lobe's weight ``w = h^2`` (texel^2)."""
        return 1.0 / (self.rate * self.rate)

    def __len__(self) -> int:
        return int(self.u.shape[0])

    def normal_covariances(self) -> np.ndarray:
        """``(N, 2, 2)`` covariances of the lobes' normal marginals,
        ``sigma_r^2 I + sigma_h^2 J J^T``."""
        jjt = np.einsum("nab,ncb->nac", self.jac, self.jac)
        return self.sigma_r**2 * np.eye(2) + self.sigma_h**2 * jjt

    def arrays(self) -> dict[str, np.ndarray]:
        """The ``lobes.npz`` arrays (float32, plus scalars)."""
        return {
            "u": self.u.astype(np.float32),
            "s": self.s.astype(np.float32),
            "jacobian": self.jac.astype(np.float32),
            "weight": np.array(self.weight, np.float32),
            "sigma_h": np.array(self.sigma_h, np.float32),
            "sigma_r": np.array(self.sigma_r, np.float32),
            "size": np.array(self.size, np.int32),
            "rate": np.array(self.rate, np.int32),
        }


def bilinear(normals: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The bilinear projected-normal field and its Jacobian at points ``u`` ``(N, 2)``.

    Texel centres at ``i + 0.5``, tiled. Returns ``s`` ``(N, 2)`` and ``jac`` ``(N, 2, 2)``
    (``ds_a / du_b``; one-sided where ``u`` sits on a centre line, where the field's
    derivative jumps).
    """
    n = normals.shape[0]
    field = np.asarray(normals[..., :2], dtype=np.float64)
    p = np.asarray(u, dtype=np.float64) - 0.5
    i0 = np.floor(p).astype(np.int64)
    f = p - i0
    x0, y0 = i0[:, 0] % n, i0[:, 1] % n
    x1, y1 = (x0 + 1) % n, (y0 + 1) % n
    s00, s10 = field[y0, x0], field[y0, x1]
    s01, s11 = field[y1, x0], field[y1, x1]
    fx, fy = f[:, 0:1], f[:, 1:2]
    s = (1 - fy) * ((1 - fx) * s00 + fx * s10) + fy * ((1 - fx) * s01 + fx * s11)
    ds_dx = (1 - fy) * (s10 - s00) + fy * (s11 - s01)
    ds_dy = (1 - fx) * (s01 - s00) + fx * (s11 - s10)
    return s, np.stack([ds_dx, ds_dy], axis=-1)


def make_lobes(normals: np.ndarray, *, rate: int = 2, sigma_r: float = 0.02) -> Lobes:
    """Lobes of a ``(n, n, 3)`` normal map: ``rate`` x ``rate`` seeds per texel at the
    centres of its sub-texels, in row-major order of (texel y, texel x, sub y, sub x)."""
    if rate < 1:
        raise ValueError(f"the lobe sampling rate must be >= 1, got {rate}")
    if not sigma_r > 0:
        raise ValueError(f"sigma_r must be > 0, got {sigma_r}")
    n = int(normals.shape[0])
    sub = (np.arange(rate) + 0.5) / rate
    ty, tx, sy, sx = np.meshgrid(np.arange(n), np.arange(n), sub, sub, indexing="ij")
    u = np.stack([(tx + sx).ravel(), (ty + sy).ravel()], axis=1)
    s, jac = bilinear(normals, u)
    return Lobes(
        u=u,
        s=s,
        jac=jac,
        size=n,
        rate=rate,
        sigma_h=SIGMA_H_PER_SPACING / rate,
        sigma_r=float(sigma_r),
    )


def _gauss2(d: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """``N(d; 0, cov)`` for ``d`` ``(..., 2)`` and ``cov`` ``(..., 2, 2)`` (broadcast)."""
    a, b, c = cov[..., 0, 0], cov[..., 0, 1], cov[..., 1, 1]
    det = a * c - b * b
    q = (c * d[..., 0] ** 2 - 2 * b * d[..., 0] * d[..., 1] + a * d[..., 1] ** 2) / det
    return np.exp(-0.5 * q) / (2.0 * math.pi * np.sqrt(det))


def pndf(
    lobes: Lobes,
    centre: np.ndarray,
    cov: np.ndarray,
    s: np.ndarray,
    *,
    index: np.ndarray | None = None,
    shift: np.ndarray | None = None,
) -> np.ndarray:
    """Eq. 1: the P-NDF ``D_P(s) = sum_i int G_P(u) G_i(u, s) du`` at query normals ``s``
    ``(M, 2)`` for the normalised Gaussian footprint ``N(u; centre, cov)`` (texels).

    ``index`` (``(K,)``) restricts the sum to those lobes, each displaced by ``shift``
    (``(K, 2)`` texels, a multiple of the period for tiled copies); by default every lobe,
    unshifted. Returns ``(M,)`` float64 densities over ``s``.
    """
    idx = np.arange(len(lobes)) if index is None else np.asarray(index)
    u_i = lobes.u[idx] + (0.0 if shift is None else np.asarray(shift, dtype=np.float64))
    s_i, jac = lobes.s[idx], lobes.jac[idx]
    c = np.asarray(centre, dtype=np.float64)
    cov_p = np.asarray(cov, dtype=np.float64)
    h2 = lobes.sigma_h**2
    spatial = _gauss2(c - u_i, cov_p + h2 * np.eye(2))  # (K,)
    inv_p = np.linalg.inv(cov_p)
    s_cov = np.linalg.inv(np.eye(2) / h2 + inv_p)  # (2, 2), the same for every lobe
    m = (u_i / h2 + (inv_p @ c)) @ s_cov.T  # (K, 2)
    mean = s_i + np.einsum("kab,kb->ka", jac, m - u_i)
    ncov = lobes.sigma_r**2 * np.eye(2) + np.einsum("kab,bc,kdc->kad", jac, s_cov, jac)
    q = np.asarray(s, dtype=np.float64)
    out = np.zeros(len(q))
    step = max(1, (1 << 22) // max(1, len(q)))  # bounds the (M, K) temporaries
    for lo in range(0, len(spatial), step):
        sl = slice(lo, lo + step)
        dens = _gauss2(q[:, None, :] - mean[None, sl], ncov[None, sl])  # (M, k)
        out += dens @ spatial[sl]
    return lobes.weight * out
