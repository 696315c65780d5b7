"""A Mitsuba 3 BSDF that renders one material of a trained BRDF model through a fused kernel.

De Oliveira et al., "A Hybrid Neural-Microfacet BRDF Model for Real-Time Rendering" (the
paper). The plugin (``"brdf_model"``, registered by :func:`register_model_bsdf`) is a Python
``mi.BSDF``; in Mitsuba's vectorised variants (``llvm_ad_rgb``, ``cuda_ad_rgb``: only the
variant's own types, guarded by ``tests/unit/evaluators/render/test_variant_generic.py``;
``scripts/gpu_check.sh`` renders it on CUDA) it is traced into the render kernel, and the
network with it: the weights and the material's ``z``, ``kd``, ``eta``, ``alpha`` are
baked in as literals (:mod:`models.fused_mlp`), so each SIMD lane evaluates its own MLP.

Evaluation (plain BRDF ``f`` in 1/sr; ``eval`` returns ``f cos theta_o``)
    :func:`models.brdf.fused.model_brdf`: ``hybrid`` ``f = f_c + f_g f_a`` (Eq. 1-3),
    ``neural`` ``f = exp(MLP(...))``, ``analytic`` ``f = f_a``; matched to float32
    precision against the numpy reference :func:`models.brdf.portable.eval_portable`.
Analytic fallback (Sec. 5.3, "selective neural evaluation")
    If the context's ``type_mask`` has the bit :data:`ANALYTIC_ONLY` set, the BSDF evaluates
    ``f_a`` alone (its samples and pdf are unchanged). Native plugins never test that bit,
    so a depth-aware integrator (:mod:`evaluators.render.integrators.neural_depth`) can set it on
    the bounces past ``neural_max_depth`` without touching other materials. Without the bit
    (Mitsuba's own integrators, the chi-square harness) the full model is evaluated.
Importance sampling (Sec. 5.2)
    A one-sample mixture (balance-heuristic MIS) of visible-normal GGX sampling with the
    material's fitted ``alpha`` (Heitz 2018, Mitsuba's ``mi.MicrofacetDistribution``) and
    cosine-hemisphere sampling; no network evaluation. GGX is drawn with probability
    :func:`models.brdf.fused.specular_weight`, the specular share of ``f_a``'s albedo at
    normal incidence, clipped to [0.1, 0.9] (:data:`materials.lobe_fit.SPECULAR_WEIGHT_BOUNDS`,
    the same convention as the MERL table BSDF); the mixture is
    :class:`evaluators.render.bsdfs.common.MixtureSampling`. The neural model, which has no
    ``f_a``, samples the
    cosine lobe only. ``pdf`` is the exact mixture density of ``sample``, never negative.
Frame and sides
    Local shading frame, z up. One-sided: 0 (value and pdf) when ``wi.z <= 0`` or
    ``wo.z <= 0``. Flags: diffuse and glossy reflection, front side, one component.
"""

from __future__ import annotations

import types
from typing import Any

from evaluators.render.bsdfs.common import GlossyDiffuseReflector, MixtureReflector, MixtureSampling
from evaluators.render.plugins import register_vectorised_bsdf
from models.brdf.fused import BakedMaterial, bake_material, model_brdf, read_model

#: The plugin name under which :func:`register_model_bsdf` registers the BSDF.
MODEL_BSDF_NAME = "brdf_model"
#: ``BSDFContext.type_mask`` bit that asks for the analytic part ``f_a`` only (Sec. 5.3).
#: Far above Mitsuba's ``BSDFFlags`` (``All`` = 0x1FF), so native plugins ignore it.
ANALYTIC_ONLY = 1 << 30


def register_model_bsdf(mi: types.ModuleType) -> type:
    """Define and register the ``"brdf_model"`` BSDF for Mitsuba's current variant.

    Idempotent per variant; returns the class. Needs a vectorised RGB variant
    (``llvm_ad_rgb``, ``cuda_ad_rgb``); raises ``RuntimeError`` otherwise.
    """
    return register_vectorised_bsdf(mi, MODEL_BSDF_NAME, ModelBSDF, "model BSDF")


class ModelBSDF(GlossyDiffuseReflector):
    """One material of a trained BRDF model (plugin ``"brdf_model"``).

    ====================  =======  ========  ============================================
    parameter             type     default   meaning
    ====================  =======  ========  ============================================
    ``filename``          string   --        a ``model.json`` (``matforge.brdf-model/1``)
    ``material``          string   --        the material's name in the model
    ``neural_max_depth``  int      none      a rendering hint, stored as the attribute
                                             of that name: :func:`evaluators.
                                             neural_depth_integrator.integrator_for`
                                             reads it to pick the integrator; the BSDF
                                             itself only obeys :data:`ANALYTIC_ONLY`
    ====================  =======  ========  ============================================

    Example (XML, as the chi-square harness loads it)::

        <bsdf type="brdf_model"><string name="filename" value="model.json"/>
            <string name="material" value="gold"/></bsdf>
    """

    def __init__(self, props: Any) -> None:
        MixtureReflector.__init__(self, props)
        mi = self.mi
        flags = (
            mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.FrontSide
        )
        if "filename" not in props or "material" not in props:
            raise ValueError("brdf_model: 'filename' and 'material' are required")
        doc = read_model(str(props["filename"]))
        self.material: BakedMaterial = bake_material(doc, str(props["material"]))
        depth = props.get("neural_max_depth", None)
        if depth is not None and (int(depth) < 0 or not self.material.has_analytic):
            raise ValueError(
                "brdf_model: neural_max_depth needs a model with an analytic part "
                "(hybrid) and a value >= 0"
            )
        self.neural_max_depth: int | None = None if depth is None else int(depth)
        self.specular_weight = self.material.specular_weight
        alpha = self.material.alpha if self.material.alpha is not None else 1.0
        self.sampling = MixtureSampling(alpha, self.specular_weight)
        self.m_flags = flags
        self.m_components = [flags]

    # -- the model ------------------------------------------------------------------------
    def brdf(self, ctx: Any, wi: Any, wo: Any, active: Any) -> Any:
        """``f`` (1/sr, ``Color3f``); ``f_a`` alone under :data:`ANALYTIC_ONLY`."""
        mi, dr = self.mi, self.dr
        # Decided at trace time: never raise here. Mitsuba traces every live instance of
        # a BSDF into every render kernel's call table, used by the scene or not.
        active = active & (wi.z > 0.0) & (wo.z > 0.0)
        neural = not int(ctx.type_mask) & ANALYTIC_ONLY
        value = model_brdf(mi, self.material, wi, wo, neural=neural)
        return dr.select(active, value, 0.0)

    def to_string(self) -> str:
        m = self.material
        return (
            f"ModelBSDF[{m.model} {m.name!r}, alpha={m.alpha}, "
            f"specular_weight={self.specular_weight:.3g}, "
            f"neural_max_depth={self.neural_max_depth}]"
        )
