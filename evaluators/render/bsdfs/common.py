"""What our BSDF plugins share: the GGX/cosine sampling mixture and the sample record.

The MERL table BSDF and the trained-model BSDF both importance-sample a one-sample mixture
(the balance heuristic of multiple importance sampling) of visible-normal GGX sampling
(Heitz 2018, through Mitsuba's own ``mi.MicrofacetDistribution``) and cosine-hemisphere
sampling, as in Sec. 5.2 of De Oliveira et al., "A Hybrid Neural-Microfacet BRDF Model for
Real-Time Rendering": "MIS between cosine sampling and GGX lobe sampling". The GGX lobe is
drawn with probability ``specular_weight``; a weight of 0 samples the cosine lobe only.

Directions are in the local shading frame, z up, Dr.Jit arrays of the current variant;
both BSDFs are one-sided reflectors, so the density is 0 when ``wi.z <= 0`` or ``wo.z <= 0``.
:class:`MixtureReflector` is their shared base class: it owns the ``mi.BSDF`` interface
(``eval``, ``pdf``, ``eval_pdf``, ``sample``), and a subclass supplies the plain BRDF.
:class:`~evaluators.render.plugins.VariantPlugin` and
:func:`~evaluators.render.plugins.class_for_variant` turn such a module-level class into the
per-variant ``mi.BSDF`` subclass that Mitsuba instantiates.
"""

from __future__ import annotations

import types
from dataclasses import dataclass
from typing import Any

from evaluators.render.plugins import VariantPlugin, class_for_variant


@dataclass(frozen=True)
class MixtureSampling:
    """The GGX/cosine mixture: GGX ``alpha`` and the GGX probability ``specular_weight``."""

    alpha: float
    specular_weight: float

    def _ggx(self, mi: types.ModuleType) -> Any:
        return mi.MicrofacetDistribution(mi.MicrofacetType.GGX, self.alpha, True)

    def pdf(self, mi: types.ModuleType, wi: Any, wo: Any, active: Any) -> Any:
        """Solid-angle density of :meth:`sample` at ``wo`` (``mi.Float``), never negative;
        0 below the horizon or where ``active`` is false."""
        import drjit as dr

        active = active & (wi.z > 0.0) & (wo.z > 0.0)
        w = self.specular_weight
        pdf = (1.0 - w) * mi.warp.square_to_cosine_hemisphere_pdf(wo)
        if w > 0.0:
            m = dr.normalize(wi + wo)
            dot_om = dr.dot(wo, m)
            # Reflection Jacobian dm/dwo = 1 / (4 wo.m) (Walter et al. 2007, Eq. 14).
            p_spec = self._ggx(mi).pdf(wi, m) / (4.0 * dot_om)
            pdf += w * dr.select(dot_om > 0.0, p_spec, 0.0)
        return dr.select(active, dr.maximum(pdf, 0.0), 0.0)

    def sample(self, mi: types.ModuleType, wi: Any, sample1: Any, sample2: Any) -> Any:
        """A direction ``wo`` (``mi.Vector3f``): the GGX reflection of ``wi`` about a
        visible normal drawn from ``sample2`` where ``sample1 < specular_weight``, else a
        cosine-weighted direction from ``sample2``."""
        import drjit as dr

        wo = mi.warp.square_to_cosine_hemisphere(sample2)
        if self.specular_weight > 0.0:
            m, _ = self._ggx(mi).sample(wi, sample2)
            wo = dr.select(sample1 < self.specular_weight, mi.reflect(wi, m), wo)
        return wo


def sample_record(mi: types.ModuleType, wo: Any, pdf: Any, sampled_type: Any = None) -> Any:
    """A ``mi.BSDFSample3f`` for a drawn ``wo`` of density ``pdf``: ``eta`` 1, component 0,
    ``sampled_type`` glossy reflection unless given (a ``mi.UInt32``)."""
    import drjit as dr

    bs = dr.zeros(mi.BSDFSample3f)
    bs.wo = wo
    bs.pdf = pdf
    bs.eta = 1.0
    bs.sampled_type = (
        mi.UInt32(+mi.BSDFFlags.GlossyReflection) if sampled_type is None else sampled_type
    )
    bs.sampled_component = mi.UInt32(0)
    return bs


class MixtureReflector(VariantPlugin):
    """A one-sided reflector sampled by :class:`MixtureSampling` (the module docstring).

    It owns the ``mi.BSDF`` interface (``eval``, ``pdf``, ``eval_pdf``, ``sample``). A
    subclass sets ``self.sampling`` (a :class:`MixtureSampling`), ``m_flags`` and
    ``m_components`` in ``__init__``, and defines ``brdf(ctx, wi, wo, active)``: the plain
    BRDF ``f`` (1/sr, ``mi.Color3f``, no cosine), 0 below the horizon. It may override
    ``enabled(ctx, active)`` (default: the context enables glossy reflection).
    """

    sampling: MixtureSampling

    def brdf(self, ctx: Any, wi: Any, wo: Any, active: Any) -> Any:
        """The plain BRDF ``f`` (1/sr, ``mi.Color3f``); defined by the subclass."""
        raise NotImplementedError

    def enabled(self, ctx: Any, active: Any) -> Any:
        """``active`` where the context asks for this BSDF's lobe."""
        return active & ctx.is_enabled(self.mi.BSDFFlags.GlossyReflection, 0)

    def _pdf(self, wi: Any, wo: Any, active: Any) -> Any:
        return self.sampling.pdf(self.mi, wi, wo, active)

    def eval(self, ctx: Any, si: Any, wo: Any, active: Any = True) -> Any:
        """``f(wi, wo) cos theta_o`` (Mitsuba's convention), ``mi.Spectrum``."""
        dr = self.dr
        active = self.enabled(ctx, active)
        return self.brdf(ctx, si.wi, wo, active) * dr.maximum(wo.z, 0.0)

    def pdf(self, ctx: Any, si: Any, wo: Any, active: Any = True) -> Any:
        """Solid-angle density of :meth:`sample` at ``wo``; 0 below the horizon."""
        return self._pdf(si.wi, wo, self.enabled(ctx, active))

    def eval_pdf(self, ctx: Any, si: Any, wo: Any, active: Any = True) -> Any:
        """``(eval, pdf)`` in one call."""
        dr = self.dr
        active = self.enabled(ctx, active)
        value = self.brdf(ctx, si.wi, wo, active) * dr.maximum(wo.z, 0.0)
        return value, self._pdf(si.wi, wo, active)

    def sample(self, ctx: Any, si: Any, sample1: Any, sample2: Any, active: Any = True) -> Any:
        """Draw ``wo`` from the mixture; returns ``(BSDFSample3f, f cos / pdf)``."""
        mi, dr = self.mi, self.dr
        active = self.enabled(ctx, active) & (si.wi.z > 0.0)
        wi = si.wi
        wo = self.sampling.sample(mi, wi, sample1, sample2)
        pdf = self._pdf(wi, wo, active)
        active &= pdf > 0.0
        value = self.brdf(ctx, wi, wo, active) * dr.maximum(wo.z, 0.0)
        bs = sample_record(mi, wo, pdf)
        return bs, dr.select(active, value / dr.maximum(pdf, 1e-30), 0.0)


class GlossyDiffuseReflector(MixtureReflector):
    """A :class:`MixtureReflector` whose lobe is glossy and diffuse reflection at once (a
    learned or user-supplied BRDF): enabled where the context asks for either."""

    def enabled(self, ctx: Any, active: Any) -> Any:
        """``active`` where the context asks for glossy or diffuse reflection."""
        mi = self.mi
        on = ctx.is_enabled(mi.BSDFFlags.GlossyReflection, 0) or ctx.is_enabled(
            mi.BSDFFlags.DiffuseReflection, 0
        )
        return active & on


def mixture_reflector_base(mi: types.ModuleType) -> type:
    """:class:`MixtureReflector` for Mitsuba's current variant (:func:`class_for_variant`),
    for a subclass defined once Mitsuba is loaded (e.g. a benchmark's)."""
    return class_for_variant(mi, MixtureReflector)
