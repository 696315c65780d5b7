"""Mitsuba BSDF ``external_mlp``: a user's BRDF network (``matforge.mlp-brdf/1``) fused into
the render kernel.

The file is read by :func:`models.external.mlp.read_mlp` and traced by
:class:`models.external.fused.FusedMlp`: the same unrolled-literal kernel
(:mod:`models.fused_mlp`) that renders the built-in hybrid model (``brdf_model``), with the
user's encodings, activations and optional analytic Lambert + GGX part around it.

Evaluation
    ``eval`` returns ``f(wi, wo) cos theta_o`` with ``f`` the model's plain BRDF (1/sr),
    matched to float32 precision against the numpy reference
    :meth:`models.external.mlp.MlpMaterial.eval`.
Importance sampling
    As ``brdf_model`` (Sec. 5.2 of De Oliveira et al.): a one-sample mixture (balance
    heuristic) of visible-normal GGX sampling with the analytic part's ``alpha`` and
    cosine-hemisphere sampling, GGX drawn with :func:`models.brdf.fused.specular_weight`
    (:class:`evaluators.render.bsdfs.common.MixtureSampling`). A model without an analytic
    part samples the cosine lobe only. ``pdf`` is the mixture's exact density.
Frame and sides
    Local shading frame, z up; one-sided: 0 when ``wi.z <= 0`` or ``wo.z <= 0``.
"""

from __future__ import annotations

import types
from typing import Any

from evaluators.render.bsdfs.common import GlossyDiffuseReflector, MixtureReflector, MixtureSampling
from evaluators.render.plugins import register_vectorised_bsdf

#: The plugin name.
EXTERNAL_MLP_NAME = "external_mlp"


def register_external_mlp_bsdf(mi: types.ModuleType) -> type:
    """Register ``external_mlp`` for Mitsuba's (vectorised RGB) variant; returns the class."""
    return register_vectorised_bsdf(mi, EXTERNAL_MLP_NAME, ExternalMlpBSDF, "external MLP BSDF")


def fused_mlp(mi: types.ModuleType, props: Any, plugin: str, kind: str) -> Any:
    """The :class:`~models.external.fused.FusedMlp` of the plugin ``plugin``'s ``filename``
    property, a network of ``kind`` (``"brdf"`` or ``"btf"``); ``ValueError`` naming the
    plugin if the property is missing or the file holds the other kind."""
    from models.external.fused import FusedMlp
    from models.external.mlp import read_mlp

    if "filename" not in props:
        raise ValueError(f"{plugin}: 'filename' is required")
    material = read_mlp(str(props["filename"]))
    if material.kind != kind:
        other = "BTF" if kind == "brdf" else "BRDF"
        raise ValueError(f"{plugin}: {material.source} is a {other}, not a {kind.upper()}")
    return FusedMlp(material, mi)


class ExternalMlpBSDF(GlossyDiffuseReflector):
    """A user's BRDF network (plugin ``"external_mlp"``).

    ============  ======  =======  ==============================================
    parameter     type    default  meaning
    ============  ======  =======  ==============================================
    ``filename``  string  --       a ``matforge.mlp-brdf/1`` JSON file
    ============  ======  =======  ==============================================

    Example (XML)::

        <bsdf type="external_mlp"><string name="filename" value="my-brdf.json"/></bsdf>
    """

    def __init__(self, props: Any) -> None:
        MixtureReflector.__init__(self, props)
        mi = self.mi
        flags = (
            mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.FrontSide
        )
        self.fused = fused_mlp(mi, props, "external_mlp", "brdf")
        alpha = self.fused.alpha
        self.specular_weight = self.fused.specular_weight
        self.sampling = MixtureSampling(alpha if alpha is not None else 1.0, self.specular_weight)
        self.m_flags = flags
        self.m_components = [flags]

    def brdf(self, ctx: Any, wi: Any, wo: Any, active: Any) -> Any:
        """``f`` (1/sr, ``Color3f``), 0 below either horizon."""
        dr = self.dr
        active = active & (wi.z > 0.0) & (wo.z > 0.0)
        return dr.select(active, self.fused.eval(wi, wo), 0.0)

    def to_string(self) -> str:
        doc = self.fused.material.doc
        return (
            f"ExternalMlp[{doc.name or self.fused.material.source}, {len(doc.layers)} layers, "
            f"combine={doc.combine}, specular_weight={self.specular_weight:.3g}]"
        )
