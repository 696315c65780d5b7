"""A Mitsuba 3 BSDF that renders MERL tables: interpolated lookup, fitted-lobe sampling.

The plugin (registered as ``"merl_table"`` by :func:`register_merl_bsdf`) is a Python
``mi.BSDF``; in Mitsuba's vectorised RGB variants it is traced into the render kernel. It
needs one (``llvm_ad_rgb`` or ``cuda_ad_rgb``, as ``MATFORGE_VARIANT`` says): it uses only
the variant's own types (``mi.Float``, ``mi.TensorXf``, ``dr.gather``), no backend module
(``tests/unit/evaluators/render/test_variant_generic.py`` guards both), and
``scripts/gpu_check.sh`` renders it on ``cuda_ad_rgb`` on a GPU machine. Under the
``scalar_rgb`` fallback, registration raises ``RuntimeError``. On 2 cores it renders at
about 0.7x the speed of the native BSDF it tabulates (``benchmarks/bench_merl_bsdf.py``;
BENCHMARKS.md): the gap is the table's random reads (17.5 MB, larger than a core's L2),
not arithmetic.

Evaluation
    The multilinear interpolation of :func:`materials.halfdiff.lookup` (``interpolate=True``)
    in Dr.Jit: the Rusinkiewicz angles of :func:`~materials.halfdiff.halfdiff_angles` (the
    trigonometry-free twin of :func:`~materials.halfdiff.halfdiff_components`: three
    ``atan2`` and no ``sin``/``cos``), the MERL bin coordinates of
    :func:`~materials.halfdiff.merl_coordinates` (both called with
    :func:`~materials.halfdiff.drjit_ops`), eight ``dr.gather`` calls of one RGB bin each,
    theta_h and theta_d clamped at the table edges, phi_d periodic. The table is held as
    float32 (17.5 MB for 180 phi_d bins).
Missing entries
    Negative entries are missing (MERL's convention). As in the numpy reference, a missing
    corner gets zero weight and the other corners are renormalised, per channel; where all
    eight corners of a channel are missing the BSDF returns **0** there (the numpy
    reference returns ``MISSING``), so a renderer never sees a negative value. When every
    bin is missing in all its channels or in none (as in matforge's tabulations), the
    lookup tests one channel per corner and keeps one weight sum; the result is the same.
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

import types
from typing import Any

import numpy as np

from evaluators.render.bsdfs.common import MixtureSampling, mixture_reflector_base
from evaluators.render.plugins import register_vectorised_bsdf
from materials import halfdiff as hd
from materials.lobe_fit import SamplingLobe, fit_sampling_lobe
from storage.formats.merl import MerlTable, read_merl

#: The plugin name under which :func:`register_merl_bsdf` registers the BSDF.
MERL_BSDF_NAME = "merl_table"


def register_merl_bsdf(mi: types.ModuleType) -> type:
    """Define and register the ``"merl_table"`` BSDF for Mitsuba's current variant.

    ``mi`` is the module returned by :func:`materials.backend.load_mitsuba`.
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

    class MerlBSDF(mixture_reflector_base(mi)):  # type: ignore[misc]
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
            super().__init__(props)
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
            self.sampling = MixtureSampling(self.alpha, self.specular_weight)
            table = np.ascontiguousarray(rgb, dtype=np.float32)
            valid = table >= 0.0
            # True when every bin is missing in all its channels or in none (tabulations):
            # the lookup then tests one channel and keeps one weight sum.
            self.whole_bins_missing = bool(np.array_equal(valid.all(axis=-1), valid.any(axis=-1)))
            self.table = mi.Float(table.ravel())
            self.m_flags = flags
            self.m_components = [flags]

        # -- the table --------------------------------------------------------------------
        def brdf(self, ctx: Any, wi: Any, wo: Any, active: Any = True) -> Any:
            """Interpolated BRDF (1/sr, ``mi.Color3f``), no cosine; 0 below the horizon
            (``ctx`` is not used)."""
            active = active & (wi.z > 0) & (wo.z > 0)
            theta_h, theta_d, phi_d = hd.halfdiff_angles(wi.x, wi.y, wi.z, wo.x, wo.y, wo.z, ops)
            n_p = self.phi_d_bins
            u_h, u_d, u_p = hd.merl_coordinates(theta_h, theta_d, phi_d, n_p, ops)
            ax_h = corners(u_h, hd.RES_THETA_H, False)
            ax_d = corners(u_d, hd.RES_THETA_D, False)
            ax_p = corners(u_p, n_p, True)
            acc = dr.zeros(mi.Color3f)
            # Per-bin missing entries: one weight sum; per-channel ones: one per channel.
            wsum = dr.zeros(mi.Float if self.whole_bins_missing else mi.Color3f)
            for i_h, w_h in ax_h:
                for i_d, w_d in ax_d:
                    row = (i_h * hd.RES_THETA_D + i_d) * n_p
                    w_hd = w_h * w_d
                    for i_p, w_p in ax_p:
                        v = dr.gather(mi.Color3f, self.table, row + i_p, active)
                        if self.whole_bins_missing:
                            w = dr.select(v.x >= 0.0, w_hd * w_p, 0.0)
                            acc = dr.fma(v, w, acc)
                        else:
                            ok = v >= 0.0
                            w = dr.select(ok, w_hd * w_p, 0.0)
                            acc += dr.select(ok, w * v, 0.0)
                        wsum += w
            value = dr.select(wsum > 0.0, acc / dr.maximum(wsum, 1e-30), 0.0)
            return dr.select(active, value, 0.0)

        def to_string(self) -> str:
            return (
                f"MerlBSDF[phi_d_bins={self.phi_d_bins}, alpha={self.alpha:.4g}, "
                f"specular_weight={self.specular_weight:.3g}]"
            )

    return MerlBSDF
