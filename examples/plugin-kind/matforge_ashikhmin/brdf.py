"""The isotropic Ashikhmin-Shirley BRDF and its fit to measured values. numpy and scipy only.

Ashikhmin and Shirley 2000, "An Anisotropic Phong BRDF Model", Eq. 4-5 with
``n_u = n_v = n`` (so ``sqrt((n_u + 1)(n_v + 1)) = n + 1``):

- specular: ``rho_s = (n + 1) / (8 pi) * (n.h)^n / ((h.k) max(n.k1, n.k2)) * F(h.k)``, with
  Schlick's Fresnel ``F = Rs + (1 - Rs)(1 - h.k)^5``;
- diffuse: ``rho_d = 28 Rd / (23 pi) (1 - Rs) (1 - (1 - n.k1 / 2)^5) (1 - (1 - n.k2 / 2)^5)``.

The constant ``28 / (23 pi)`` makes the diffuse term's directional albedo exactly
``Rd (1 - Rs) (1 - (1 - cos(theta_i) / 2)^5)``, at most ``31/32 Rd (1 - Rs)``: energy is
conserved, and the test checks that closed form by quadrature.

Conventions: directions are ``(N, 3)`` unit vectors in the local shading frame, z up;
values are the plain BRDF in 1/sr (no cosine), linear RGB ``(N, 3)``; 0 where either
direction is at or below the horizon.

The fit: for a fixed exponent ``n`` the model is linear in ``Rs`` and ``Rd' = Rd (1 - Rs)``
(``f = S c5 + Rs S (1 - c5) + Rd' D``), so each channel is a 2-variable bounded linear
least-squares problem (``scipy.optimize.lsq_linear``, ``0 <= Rs, Rd' <= 1``), in relative
error (weights ``1 / (ref + tau)``, :data:`TAU_FRACTION`), like the SMAPE it is scored
with. ``n`` is shared by the channels: the best of a log-spaced grid, refined by a bounded
scalar search in ``log n`` between its grid neighbours. Deterministic for fixed inputs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import lsq_linear, minimize_scalar

#: Bounds of the Phong-like exponent ``n``.
N_MIN, N_MAX = 1.0, 1.0e4
#: Relative-error weights ``1 / (ref + tau)``, ``tau = TAU_FRACTION x`` the channel's mean:
#: a floor so that table zeros do not dominate the fit.
TAU_FRACTION = 0.05
#: Floats per fitted material: Rs (RGB), Rd (RGB), n.
FLOATS_PER_MATERIAL = 7


@dataclass(frozen=True)
class AshikhminShirley:
    """One isotropic Ashikhmin-Shirley material.

    Attributes:
        rs: RGB specular reflectance at normal incidence, each in ``[0, 1]``.
        rd: RGB diffuse reflectance, each in ``[0, 1]``.
        n: the Phong-like exponent, ``N_MIN <= n <= N_MAX``.
    """

    rs: tuple[float, float, float]
    rd: tuple[float, float, float]
    n: float

    def __post_init__(self) -> None:
        for name in ("rs", "rd"):
            v = np.asarray(getattr(self, name), dtype=np.float64)
            if v.shape != (3,) or not np.all(np.isfinite(v)) or np.any((v < 0) | (v > 1)):
                raise ValueError(f"{name} must be 3 values in [0, 1], got {getattr(self, name)!r}")
        if not (math.isfinite(self.n) and N_MIN <= self.n <= N_MAX):
            raise ValueError(f"n must be in [{N_MIN}, {N_MAX}], got {self.n!r}")

    def eval(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        """``(N, 3)`` BRDF values (1/sr) at ``(N, 3)`` direction pairs."""
        s, c5, d = terms(wi, wo, self.n)
        rs, rd = np.asarray(self.rs), np.asarray(self.rd)
        spec = s[:, None] * (rs + (1.0 - rs) * c5[:, None])
        return spec + d[:, None] * (rd * (1.0 - rs))

    def document(self) -> dict[str, object]:
        """``{"rs": [r, g, b], "rd": [r, g, b], "n": n}``."""
        return {"rs": list(self.rs), "rd": list(self.rd), "n": self.n}


def terms(wi: np.ndarray, wo: np.ndarray, n: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The model's parts at ``(N, 3)`` pairs, each ``(N,)``: ``S`` (the specular lobe
    without Fresnel), ``c5 = (1 - h.k)^5`` (Schlick) and ``D`` (the diffuse term without
    ``Rd (1 - Rs)``); all 0 below the horizon."""
    wi, wo = np.asarray(wi, dtype=np.float64), np.asarray(wo, dtype=np.float64)
    ci, co = wi[:, 2], wo[:, 2]
    above = (ci > 0) & (co > 0)
    h = wi + wo
    norm = np.linalg.norm(h, axis=1)
    h = h / np.where(norm > 0, norm, 1.0)[:, None]
    nh = np.clip(h[:, 2], 0.0, 1.0)
    hk = np.clip(np.sum(h * wi, axis=1), 1e-12, 1.0)
    denom = hk * np.maximum(np.maximum(ci, co), 1e-12)
    s = np.where(above, (n + 1.0) / (8.0 * math.pi) * nh**n / denom, 0.0)
    c5 = (1.0 - hk) ** 5
    cpos, opos = np.clip(ci, 0.0, 1.0), np.clip(co, 0.0, 1.0)
    d = np.where(
        above,
        28.0 / (23.0 * math.pi) * (1.0 - (1.0 - cpos / 2.0) ** 5) * (1.0 - (1.0 - opos / 2.0) ** 5),
        0.0,
    )
    return s, c5, d


def _solve(wi: np.ndarray, wo: np.ndarray, ref: np.ndarray, w: np.ndarray, n: float) -> tuple[
    float, np.ndarray, np.ndarray
]:  # fmt: skip
    """The best ``(loss, rs, rd)`` for exponent ``n`` (see the module docstring)."""
    s, c5, d = terms(wi, wo, n)
    rs, rd = np.zeros(3), np.zeros(3)
    loss = 0.0
    for c in range(3):
        a = np.stack([s * (1.0 - c5), d], axis=1) * w[:, c : c + 1]
        b = (ref[:, c] - s * c5) * w[:, c]
        x = lsq_linear(a, b, bounds=(0.0, 1.0), method="bvls").x
        r_s = float(np.clip(x[0], 0.0, 1.0))
        r_d_eff = float(np.clip(x[1], 0.0, 1.0 - r_s))  # Rd' = Rd (1 - Rs) with Rd <= 1
        loss += float(np.sum((a @ np.array([r_s, r_d_eff]) - b) ** 2))
        rs[c] = r_s
        rd[c] = r_d_eff / (1.0 - r_s) if r_s < 1.0 else 0.0
    return loss, rs, np.clip(rd, 0.0, 1.0)


def fit(
    wi: np.ndarray, wo: np.ndarray, ref: np.ndarray, *, exponents: int = 32
) -> tuple[AshikhminShirley, float]:
    """Fit the model to measured ``ref`` ``(N, 3)`` (1/sr) at ``(N, 3)`` pairs with
    non-negative values; returns the material and its weighted squared relative error.

    Raises ``ValueError`` for mismatched shapes, negative or non-finite values, or fewer
    than 16 pairs.
    """
    ref = np.asarray(ref, dtype=np.float64)
    if ref.ndim != 2 or ref.shape[1] != 3 or np.shape(wi) != ref.shape or np.shape(wo) != ref.shape:
        raise ValueError(f"wi, wo and ref must all be (N, 3), got {np.shape(wi)}, "
                         f"{np.shape(wo)}, {ref.shape}")  # fmt: skip
    if len(ref) < 16 or not np.all(np.isfinite(ref)) or np.any(ref < 0):
        raise ValueError("ref needs at least 16 pairs of finite, non-negative values")
    if exponents < 4:
        raise ValueError(f"exponents must be at least 4, got {exponents}")
    tau = TAU_FRACTION * np.maximum(ref.mean(axis=0), 1e-12)
    w = 1.0 / (ref + tau)
    grid = np.geomspace(N_MIN, N_MAX, exponents)
    losses = [_solve(wi, wo, ref, w, float(n))[0] for n in grid]
    best = int(np.argmin(losses))
    lo, hi = math.log(grid[max(best - 1, 0)]), math.log(grid[min(best + 1, exponents - 1)])
    res = minimize_scalar(
        lambda t: _solve(wi, wo, ref, w, math.exp(t))[0],
        bounds=(lo, hi),
        method="bounded",
        options={"xatol": 1e-4},
    )
    n = float(math.exp(res.x)) if res.fun <= losses[best] else float(grid[best])
    n = min(max(n, N_MIN), N_MAX)
    loss, rs, rd = _solve(wi, wo, ref, w, n)
    material = AshikhminShirley(
        rs=(float(rs[0]), float(rs[1]), float(rs[2])),
        rd=(float(rd[0]), float(rd[1]), float(rd[2])),
        n=n,
    )
    return material, loss
