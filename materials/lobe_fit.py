"""A GGX lobe fitted to a tabulated BRDF, for importance sampling it.

The MERL table BSDF (:mod:`evaluators.render.bsdfs.merl_table`) samples a one-sample
mixture of a GGX lobe and the cosine lobe (De Oliveira et al., Sec. 5.2: "MIS between
cosine sampling and GGX lobe sampling"); this module fits the lobe's ``alpha`` and the
mixture weight to the table. The trained BRDF models use the same weight bounds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import nnls

from materials import halfdiff as hd
from materials.microfacet import ndf, smith_g1, specular_albedo

#: Bounds of the probability of sampling the GGX lobe: each strategy keeps at least 10 %
#: of the samples, so neither a lobe missed by the fit nor a diffuse floor missed by the
#: GGX strategy leaves unbounded sample weights.
SPECULAR_WEIGHT_BOUNDS = (0.1, 0.9)
#: Roughness grid of the fit (GGX alpha), log-spaced.
ALPHA_GRID = np.geomspace(2e-3, 1.0, 160)


@dataclass(frozen=True)
class SamplingLobe:
    """A GGX lobe fitted to a table, used only to importance-sample it.

    Attributes
    ----------
    alpha
        GGX roughness of the lobe.
    diffuse
        ``k_d``: the constant (Lambertian) part, BRDF value in 1/sr (channel mean).
    specular
        ``k_s``: scale of the unit-Fresnel GGX lobe (about ``F0``), dimensionless.
    specular_weight
        Probability that ``sample`` draws from the GGX lobe, in
        :data:`SPECULAR_WEIGHT_BOUNDS`.
    residual
        RMS relative residual of the fit over the bins used.
    """

    alpha: float
    diffuse: float
    specular: float
    specular_weight: float
    residual: float


def fit_sampling_lobe(
    rgb: np.ndarray, *, max_theta_d_deg: float = 10.0, max_theta_h_deg: float = 80.0
) -> SamplingLobe:
    """Fit ``k_d + k_s D(theta_h) G1(theta_h)^2 / (4 cos^2 theta_h)`` to a MERL table.

    Parameters
    ----------
    rgb
        ``(90, 90, P, 3)`` physical BRDF in 1/sr (``MerlTable.rgb``), negative = missing.
    max_theta_d_deg, max_theta_h_deg
        The fit uses the channel mean of the valid bins with ``theta_d`` below
        ``max_theta_d_deg`` (averaged over theta_d and phi_d: one value per theta_h bin) and
        ``theta_h`` below ``max_theta_h_deg``.

    Near ``theta_d = 0`` a microfacet BRDF is ``D G F / (4 cos_i cos_o)`` with
    ``cos_i = cos_o = cos theta_h`` and ``F = F(0)`` (Walter et al. 2007, Eq. 20), which is
    the model above with ``k_s = F(0)``. For each GGX ``alpha`` of :data:`ALPHA_GRID` the
    model is linear in ``(k_d, k_s)``, solved by non-negative least squares on relative
    residuals (so the tails weigh as much as the peak); the best alpha wins. The mixture
    weight is the lobe's share of the albedo at normal incidence,
    ``E_s / (E_s + pi k_d)`` with ``E_s = k_s`` times the unit-Fresnel GGX albedo
    (:func:`materials.microfacet.specular_albedo`), clipped to
    :data:`SPECULAR_WEIGHT_BOUNDS`.
    """
    rgb = np.asarray(rgb, dtype=np.float64)
    if rgb.ndim != 4 or rgb.shape[:2] != (90, 90) or rgb.shape[3] != 3:
        raise ValueError(f"table must have shape (90, 90, P, 3), got {rgb.shape}")
    theta_h, theta_d, _ = hd.bin_centers(rgb.shape[2])
    n_d = max(1, int(np.count_nonzero(theta_d < math.radians(max_theta_d_deg))))
    block = rgb[:, :n_d]
    valid = np.all(block >= 0, axis=-1)
    total = np.where(valid, block.mean(axis=-1), 0.0).sum(axis=(1, 2))
    count = valid.sum(axis=(1, 2))
    use = (count > 0) & (theta_h < math.radians(max_theta_h_deg))
    if np.count_nonzero(use) < 3:
        raise ValueError("too few valid bins near theta_d = 0 to fit a sampling lobe")
    f = total[use] / count[use]
    cos_h = np.cos(theta_h[use])
    scale = 1.0 / np.maximum(f, 1e-6 * max(float(f.max()), 1e-12))
    best: tuple[float, float, float, float] | None = None
    for alpha in ALPHA_GRID:
        lobe = (
            ndf(cos_h, alpha)
            * smith_g1(cos_h, np.ones_like(cos_h), alpha) ** 2
            / (4.0 * cos_h * cos_h)
        )
        design = np.stack([np.ones_like(cos_h), lobe], axis=1) * scale[:, None]
        (k_d, k_s), res = nnls(design, f * scale)
        if best is None or res < best[0]:
            best = (float(res), float(alpha), float(k_d), float(k_s))
    assert best is not None
    res, alpha, k_d, k_s = best
    e_s = k_s * float(specular_albedo(np.array([1.0]), alpha, np.ones_like)[0])
    e_d = math.pi * k_d
    lo, hi = SPECULAR_WEIGHT_BOUNDS
    weight = e_s / (e_s + e_d) if e_s + e_d > 0 else 0.5
    return SamplingLobe(
        alpha=alpha,
        diffuse=k_d,
        specular=k_s,
        specular_weight=float(np.clip(weight, lo, hi)),
        residual=res / math.sqrt(len(f)),
    )
