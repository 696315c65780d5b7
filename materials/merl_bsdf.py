"""A Mitsuba 3 BSDF that renders MERL tables: interpolated lookup, fitted-lobe sampling.

The plugin (registered as ``"merl_table"`` by :func:`register_merl_bsdf`) is a Python
``mi.BSDF``; in Mitsuba's vectorised RGB variants it is traced into the render kernel. It
needs one (``llvm_ad_rgb``; ``cuda_ad_rgb`` should work but is untested): under the
``scalar_rgb`` fallback, registration raises ``RuntimeError``. On 2 cores it renders at
about 0.5-0.7x the speed of the native BSDF it tabulates
(``benchmarks/bench_merl_bsdf.py``).

Evaluation
    The multilinear interpolation of :func:`materials.halfdiff.lookup` (``interpolate=True``)
    in Dr.Jit: the same Rusinkiewicz angles and MERL bin coordinates
    (:func:`~materials.halfdiff.halfdiff_components`, :func:`~materials.halfdiff.merl_coordinates`
    called with :func:`~materials.halfdiff.drjit_ops`), eight ``dr.gather`` calls of one RGB
    bin each, theta_h and theta_d clamped at the table edges, phi_d periodic. The table is
    held as float32 (17.5 MB for 180 phi_d bins).
Missing entries
    Negative entries are missing (MERL's convention). As in the numpy reference, a missing
    corner gets zero weight and the other corners are renormalised, per channel; where all
    eight corners of a channel are missing the BSDF returns **0** there (the numpy
    reference returns ``MISSING``), so a renderer never sees a negative value.
Frame and sides
    Directions in the local shading frame, z up; ``cos theta_i = si.wi.z``. One-sided: 0 (and
    pdf 0) when ``wi.z <= 0`` or ``wo.z <= 0``. Flags: glossy reflection, front side.
Importance sampling
    A one-sample mixture (the balance heuristic of multiple importance sampling) of
    visible-normal GGX sampling (Heitz 2018, through Mitsuba's own
    ``mi.MicrofacetDistribution``) and cosine-hemisphere sampling, as in Sec. 5.2 of
    De Oliveira et al., "A Hybrid Neural-Microfacet BRDF Model for Real-Time Rendering":
    "MIS between cosine sampling and GGX lobe sampling". The lobe's ``alpha`` and the
    mixture weight come from :func:`fit_sampling_lobe`, a least-squares fit of
    ``k_d + k_s D G1^2 / (4 cos^2 theta_h)`` to the table near the specular configuration.
    ``pdf`` is the exact mixture density of what ``sample`` draws, 0 below the horizon.
"""

from __future__ import annotations

import math
import types
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import nnls

from materials import halfdiff as hd
from materials.microfacet import ndf, smith_g1, specular_albedo
from materials.mitsuba_backend import register_vectorised_bsdf
from storage.formats.merl import MerlTable, read_merl

#: The plugin name under which :func:`register_merl_bsdf` registers the BSDF.
MERL_BSDF_NAME = "merl_table"
#: Bounds of the probability of sampling the GGX lobe: each strategy keeps at least 10 %
#: of the samples, so neither a lobe missed by the fit nor a diffuse floor missed by the
#: GGX strategy leaves unbounded sample weights.
SPECULAR_WEIGHT_BOUNDS = (0.1, 0.9)
#: Roughness grid of the fit (GGX alpha), log-spaced.
ALPHA_GRID = np.geomspace(2e-3, 1.0, 160)

# One class per Mitsuba variant: mi.register_bsdf binds the plugin to the variant set when
# it is called, and the class must subclass that variant's mi.BSDF.


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


def register_merl_bsdf(mi: types.ModuleType) -> type:
    """Define and register the ``"merl_table"`` BSDF for Mitsuba's current variant.

    ``mi`` is the module returned by :func:`materials.mitsuba_backend.load_mitsuba`.
    Idempotent per variant; returns the class. Needs a vectorised RGB variant
    (``llvm_ad_rgb``, ``cuda_ad_rgb``); raises ``RuntimeError`` otherwise.
    """
    return register_vectorised_bsdf(mi, MERL_BSDF_NAME, _define_class, "MERL table BSDF")


def merl_bsdf(mi: types.ModuleType, table: MerlTable, lobe: SamplingLobe | None = None) -> Any:
    """An instantiated table BSDF (``mi.BSDF``) for ``table``; fits the lobe if not given."""
    register_merl_bsdf(mi)
    lobe = lobe or fit_sampling_lobe(table.rgb)
    return mi.load_dict(
        {
            "type": MERL_BSDF_NAME,
            "data": mi.TensorXf(table.rgb.astype(np.float32)),
            "alpha": lobe.alpha,
            "specular_weight": lobe.specular_weight,
        }
    )


def _define_class(mi: types.ModuleType) -> type:
    import drjit as dr

    ops = hd.drjit_ops(dr)
    flags = mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.FrontSide

    def corners(u: Any, n: int, periodic: bool) -> tuple[tuple[Any, Any], tuple[Any, Any]]:
        # As halfdiff._interpolate: bin centres sit at integer p = u - 1/2.
        p = u - 0.5
        lower = dr.floor(p)
        w1 = p - lower
        i0 = mi.Int32(lower)
        i1 = i0 + 1
        if periodic:
            i0 = dr.select(i0 < 0, i0 + n, i0)
            i1 = dr.select(i1 >= n, i1 - n, i1)
        # Clamping also keeps every gather in bounds, whatever the input.
        i0 = mi.UInt32(dr.clip(i0, 0, n - 1))
        i1 = mi.UInt32(dr.clip(i1, 0, n - 1))
        return (i0, 1.0 - w1), (i1, w1)

    class MerlBSDF(mi.BSDF):  # type: ignore[name-defined]
        """MERL table BSDF (plugin ``"merl_table"``).

        =====================  =============  ========  =========================================
        parameter              type           default   meaning
        =====================  =============  ========  =========================================
        ``filename``           string         --        a MERL ``.binary`` file, read and
                                                        validated by
                                                        :func:`storage.formats.merl.read_merl`
        ``data``               ``TensorXf``   --        the table itself, ``(90, 90, P, 3)``
                                                        physical BRDF in 1/sr (instead of a file)
        ``alpha``              float          fitted    GGX roughness of the sampling lobe
        ``specular_weight``    float          fitted    probability of sampling the GGX lobe
        =====================  =============  ========  =========================================

        Example (XML, as the chi-square harness loads it)::

            <bsdf type="merl_table"><string name="filename" value="gold.binary"/></bsdf>
        """

        def __init__(self, props: Any) -> None:
            mi.BSDF.__init__(self, props)
            filename = props.get("filename", None)
            data = props.get("data", None)
            if (filename is None) == (data is None):
                raise ValueError("merl_table: give exactly one of 'filename' and 'data'")
            if filename is not None:
                rgb = read_merl(str(filename)).rgb
            else:
                rgb = np.asarray(data.numpy(), dtype=np.float64)
            if rgb.ndim != 4 or rgb.shape[:2] != (90, 90) or rgb.shape[3] != 3:
                raise ValueError(f"merl_table: table shape must be (90, 90, P, 3), got {rgb.shape}")
            self.phi_d_bins = int(rgb.shape[2])
            if self.phi_d_bins not in hd.PHI_D_VARIANTS:
                raise ValueError(f"merl_table: phi_d bins must be 180 or 360, not {rgb.shape[2]}")
            alpha, weight = props.get("alpha", None), props.get("specular_weight", None)
            if alpha is None or weight is None:
                lobe = fit_sampling_lobe(rgb)
                alpha = lobe.alpha if alpha is None else alpha
                weight = lobe.specular_weight if weight is None else weight
            if not (alpha > 0.0 and 0.0 <= weight <= 1.0):
                raise ValueError("merl_table: need alpha > 0, 0 <= specular_weight <= 1")
            self.alpha, self.specular_weight = float(alpha), float(weight)
            self.table = mi.Float(np.ascontiguousarray(rgb, dtype=np.float32).ravel())
            self.m_flags = flags
            self.m_components = [flags]

        # -- the table --------------------------------------------------------------------
        def brdf(self, wi: Any, wo: Any, active: Any = True) -> Any:
            """Interpolated BRDF (1/sr, ``mi.Color3f``), no cosine; 0 below the horizon."""
            active = active & (wi.z > 0) & (wo.z > 0)
            theta_h, _, theta_d, phi_d = hd.halfdiff_components(
                wi.x, wi.y, wi.z, wo.x, wo.y, wo.z, ops
            )
            n_p = self.phi_d_bins
            u_h, u_d, u_p = hd.merl_coordinates(theta_h, theta_d, phi_d, n_p, ops)
            ax_h = corners(u_h, hd.RES_THETA_H, False)
            ax_d = corners(u_d, hd.RES_THETA_D, False)
            ax_p = corners(u_p, n_p, True)
            acc = dr.zeros(mi.Color3f)
            wsum = dr.zeros(mi.Color3f)
            for i_h, w_h in ax_h:
                for i_d, w_d in ax_d:
                    row = (i_h * hd.RES_THETA_D + i_d) * n_p
                    w_hd = w_h * w_d
                    for i_p, w_p in ax_p:
                        v = dr.gather(mi.Color3f, self.table, row + i_p, active)
                        w = w_hd * w_p
                        valid = v >= 0.0
                        acc += dr.select(valid, w * v, 0.0)
                        wsum += dr.select(valid, w, 0.0)
            value = dr.select(wsum > 0.0, acc / dr.maximum(wsum, 1e-30), 0.0)
            return dr.select(active, value, 0.0)

        # -- sampling density ---------------------------------------------------------------
        def _distribution(self) -> Any:
            return mi.MicrofacetDistribution(mi.MicrofacetType.GGX, self.alpha, True)

        def _pdf(self, wi: Any, wo: Any, active: Any) -> Any:
            active = active & (wi.z > 0) & (wo.z > 0)
            m = dr.normalize(wi + wo)
            dot_om = dr.dot(wo, m)
            # Reflection Jacobian dm/dwo = 1 / (4 wo.m) (Walter et al. 2007, Eq. 14).
            p_spec = self._distribution().pdf(wi, m) / (4.0 * dot_om)
            p_diff = mi.warp.square_to_cosine_hemisphere_pdf(wo)
            w = self.specular_weight
            pdf = w * dr.select(dot_om > 0.0, p_spec, 0.0) + (1.0 - w) * p_diff
            return dr.select(active, dr.maximum(pdf, 0.0), 0.0)

        def _enabled(self, ctx: Any, active: Any) -> Any:
            return active & ctx.is_enabled(mi.BSDFFlags.GlossyReflection, 0)

        # -- the mi.BSDF interface ------------------------------------------------------------
        def eval(self, ctx: Any, si: Any, wo: Any, active: Any = True) -> Any:
            """``f(wi, wo) cos theta_o`` (Mitsuba's convention), ``mi.Spectrum``."""
            active = self._enabled(ctx, active)
            return self.brdf(si.wi, wo, active) * dr.maximum(wo.z, 0.0)

        def pdf(self, ctx: Any, si: Any, wo: Any, active: Any = True) -> Any:
            """Solid-angle density of :meth:`sample` at ``wo``; 0 below the horizon."""
            return self._pdf(si.wi, wo, self._enabled(ctx, active))

        def eval_pdf(self, ctx: Any, si: Any, wo: Any, active: Any = True) -> Any:
            """``(eval, pdf)`` in one call."""
            active = self._enabled(ctx, active)
            value = self.brdf(si.wi, wo, active) * dr.maximum(wo.z, 0.0)
            return value, self._pdf(si.wi, wo, active)

        def sample(self, ctx: Any, si: Any, sample1: Any, sample2: Any, active: Any = True) -> Any:
            """Draw ``wo`` from the lobe/cosine mixture; returns ``(BSDFSample3f, f cos / pdf)``."""
            active = self._enabled(ctx, active) & (si.wi.z > 0)
            wi = si.wi
            m, _ = self._distribution().sample(wi, sample2)
            wo_spec = mi.reflect(wi, m)
            wo_diff = mi.warp.square_to_cosine_hemisphere(sample2)
            wo = dr.select(sample1 < self.specular_weight, wo_spec, wo_diff)
            pdf = self._pdf(wi, wo, active)
            active &= pdf > 0.0
            value = self.brdf(wi, wo, active) * dr.maximum(wo.z, 0.0)
            bs = dr.zeros(mi.BSDFSample3f)
            bs.wo = wo
            bs.pdf = pdf
            bs.eta = 1.0
            bs.sampled_type = mi.UInt32(+mi.BSDFFlags.GlossyReflection)
            bs.sampled_component = mi.UInt32(0)
            weight = dr.select(active, value / dr.maximum(pdf, 1e-30), 0.0)
            return bs, weight

        def to_string(self) -> str:
            return (
                f"MerlBSDF[phi_d_bins={self.phi_d_bins}, alpha={self.alpha:.4g}, "
                f"specular_weight={self.specular_weight:.3g}]"
            )

    return MerlBSDF
