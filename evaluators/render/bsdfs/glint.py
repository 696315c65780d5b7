"""Mitsuba BSDF ``glint``: glinty microstructure over the pixel footprint (Xing et al. 2024,
Sec. 3.1 and 6.4; the Yan et al. 2016 reference).

The BRDF of a footprint P is the microfacet model with the footprint's P-NDF (Sec. 3.1):

    f_P(wi, wo) = D_P(h) G(wi, wo) F(wi . h) / (4 cos_i cos_o),

``h`` the half vector and ``D_P`` the density of projected normals ``s = (h_x, h_y)`` over
the footprint (which is the NDF per solid angle with ``int D cos_h dw = 1``), ``s`` taken in the
example's axes (x along dp/du, y along dp/dv: :func:`example_slopes`). ``D_P`` comes
from one of two evaluators of the same microstructure (:mod:`materials.glints.pndf_drjit`):

- ``tiny_example`` (tiled or stochastic distributions): the example's NDF maps at the
  footprint's level, or its lobes below the
  finest tile (``lookup="flat"``); or the paper's descent over covered and partly covered
  tiles (``lookup="paper"``);
- ``yan``: Eq. 1 over the lobes of the microstructure exported as an explicit normal map,
  by brute force (every lobe of the footprint's support) or, when the layer has
  ``bounds``, by Yan et al. 2016's hierarchy (:mod:`materials.glints.pndf_yan_hier`: the
  same sum, skipping blocks of texels that cannot reach the half vector);
- ``smooth_ggx``: no microstructure: a smooth anisotropic GGX NDF whose roughness
  ``(alpha_u, alpha_v)`` matches the microstructure's slopes (the cheapest rung of the glint
  ladder of ``select``: what a scene gets without glints).

``G`` is the separable Smith term of a GGX lobe whose roughness matches the microstructure's
slopes (``alpha``), ``F`` a conductor's (complex IOR) or a dielectric's Fresnel term. A
clearcoat (Sec. 6.4, Eq. 3) is a second layer with its own microstructure and a dielectric
Fresnel ``F_c``: ``f_s = f_b (1 - F_c(wi . h)) + f_c``.

**Footprint**: the pixel's uv parallelogram from the ``fabric_path`` integrator's ray
differentials (``si.duv_dx``, ``si.duv_dy``; the BSDF sets ``needs_footprint``), scaled to
texels by ``texels_per_uv`` and turned into Heckbert's Gaussian; secondary vertices (no
partials) use a footprint of one example (the example's average NDF).

**Sampling**: the NDF is not sampled exactly; a one-sample mixture of the matching GGX lobe
(probability 0.9) and the cosine lobe (:class:`~evaluators.render.bsdfs.common.MixtureSampling`,
the same MIS the MERL and model BSDFs use). ``pdf`` is that mixture's exact density.

**Layers** are prepared by the material source (:mod:`evaluators.render.sources.glint`) and
handed to the plugin through :func:`put_layers`, which returns the key the ``layers``
property names: the arrays are Dr.Jit arrays, which Mitsuba properties cannot carry.
One-sided: 0 when ``wi.z <= 0`` or ``wo.z <= 0``.
"""

from __future__ import annotations

import math
import types
import weakref
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any

import numpy as np

from evaluators.render.bsdfs.common import MixtureReflector, MixtureSampling
from evaluators.render.plugins import register_vectorised_bsdf
from materials.glints.footprint import PIXEL_SIGMA
from materials.glints.pndf_drjit import (
    JitLobes,
    JitMaps,
    JitMapSampler,
    JitPlacement,
    Sym2,
    lobes_pndf,
    lobes_sample,
    stochastic_pndf,
    tiny_pndf,
    tiny_sample,
)
from materials.glints.pndf_yan_hier import JitBounds, hier_pndf

#: The plugin name.
GLINT_BSDF_NAME = "glint"
#: Probability that ``sample`` draws from the GGX lobe.
GGX_WEIGHT = 0.9
#: Most texels (``yan``, brute force), leaf blocks of 2 x 2 texels (``yan``, hierarchical) or
#: tiles (``tiny_example``) one evaluation visits.
MAX_ITEMS = 1 << 16
#: ``sampling="pndf"``: probability that ``sample`` draws from the P-NDF itself (the rest
#: goes to the GGX/cosine mixture, which keeps the density positive where the P-NDF is 0).
PNDF_WEIGHT = 0.9
#: The sampling strategies.
SAMPLINGS = ("ggx_mix", "pndf")


@dataclass(frozen=True)
class GlintLayer:
    """One microstructure layer, ready to trace.

    ``method`` ``"tiny_example"`` (needs ``maps``), ``"yan"`` or ``"smooth_ggx"`` (needs
    ``alphas``); ``lobes`` the example's (tiny) or the exported map's (yan) lobes, ``None``
    for smooth_ggx; ``transform`` ``(A, o)`` of a tiled example
    (tiny only); ``texel_scale`` map texels per global texel (yan: the export's
    oversampling; tiny: 1); ``fresnel`` ``("conductor", eta, k)`` with RGB tuples or
    ``("dielectric", eta)``; ``alpha`` the matching GGX roughness (Smith G, sampling);
    ``fallback_texels`` the standard deviation (global texels) of the footprint used
    without ray differentials; ``alphas`` the smooth NDF's GGX ``(alpha_u, alpha_v)``
    (smooth_ggx only); ``lookup`` the tiny example's lookup rule (``"flat"`` or
    ``"paper"``, :data:`materials.glints.footprint.LOOKUPS`); ``sampling`` ``"ggx_mix"``
    or ``"pndf"`` (module docstring; read from the base layer), ``sampler`` the maps' patch
    CDFs (``tiny_example`` with ``"pndf"`` only); ``placement`` a stochastic
    distribution's table (``tiny_example`` on a stochastic surface; ``transform`` unused);
    ``bounds`` (``yan`` only) the hierarchy over the lobes: evaluation walks it (sampling
    still visits every lobe).
    """

    method: str
    lobes: JitLobes | None
    maps: JitMaps | None
    transform: tuple[np.ndarray, np.ndarray]
    texel_scale: float
    fresnel: tuple[Any, ...]
    alpha: float
    fallback_texels: float
    alphas: tuple[float, float] | None = None
    lookup: str = "flat"
    sampling: str = "ggx_mix"
    sampler: JitMapSampler | None = None
    placement: JitPlacement | None = None
    bounds: JitBounds | None = None


@dataclass(frozen=True, eq=False)
class _Prepared:
    """A base layer and its clearcoat, as :func:`put_layers` registered them."""

    base: GlintLayer
    coat: GlintLayer | None


#: How many registered layer pairs :func:`put_layers` keeps alive that no ``glint`` BSDF
#: holds (the latest ones): a Yan export's lobes are hundreds of MiB, so the registry must
#: not keep every render's layers for the life of the process.
KEPT_LAYERS = 2
#: The last :data:`KEPT_LAYERS` registrations, oldest first.
_RECENT: OrderedDict[str, _Prepared] = OrderedDict()
#: Every registration still alive: kept by :data:`_RECENT` or by a ``glint`` BSDF (which
#: holds its pair), so that a key stays valid while a scene uses it.
_LAYERS: weakref.WeakValueDictionary[str, _Prepared] = weakref.WeakValueDictionary()


def put_layers(key: str, base: GlintLayer, coat: GlintLayer | None = None) -> str:
    """Register a base layer (and optional clearcoat) under ``key`` for the ``layers``
    property; returns ``key``.

    The registry holds the pair while a ``glint`` BSDF made from it is alive, and holds the
    last :data:`KEPT_LAYERS` pairs registered; older ones are released with the last BSDF
    (and so the scene) that uses them, and their key is then unknown.
    """
    prepared = _Prepared(base, coat)
    _LAYERS[key] = prepared
    _RECENT[key] = prepared
    _RECENT.move_to_end(key)
    while len(_RECENT) > KEPT_LAYERS:
        _RECENT.popitem(last=False)
    return key


def register_glint_bsdf(mi: types.ModuleType) -> type:
    """Register ``glint`` for Mitsuba's (vectorised RGB) variant; returns the class."""
    return register_vectorised_bsdf(mi, GLINT_BSDF_NAME, GlintBSDF, "glint BSDF")


def layer_pndf(
    mi: types.ModuleType,
    layer: GlintLayer,
    c: tuple[Any, Any],
    cov: Sym2,
    q: tuple[Any, Any],
    active: Any,
) -> Any:
    """``D_P(q)`` of ``layer`` for a footprint ``N(c, cov)`` in global texels."""
    assert layer.lobes is not None, "smooth_ggx has no lobes; see GlintBSDF._lobe"
    k = layer.texel_scale
    if layer.method == "yan":
        cs = (c[0] * k, c[1] * k)
        covs = Sym2(cov.a * (k * k), cov.b * (k * k), cov.d * (k * k))
        if layer.bounds is not None:
            return hier_pndf(
                mi, layer.lobes, layer.bounds, cs, covs, q, active, max_items=MAX_ITEMS
            )  # fmt: skip
        return lobes_pndf(mi, layer.lobes, cs, covs, q, active, max_items=MAX_ITEMS)
    assert layer.maps is not None
    if layer.placement is not None:
        return stochastic_pndf(
            mi, layer.maps, layer.lobes, layer.placement, c, cov, q, active, max_items=MAX_ITEMS
        )  # fmt: skip
    return tiny_pndf(
        mi, layer.maps, layer.lobes, layer.transform, c, cov, q, active, max_items=MAX_ITEMS,
        lookup=layer.lookup,
    )  # fmt: skip


def layer_sample(
    mi: types.ModuleType,
    layer: GlintLayer,
    c: tuple[Any, Any],
    cov: Sym2,
    u1: Any,
    u2: tuple[Any, Any],
    active: Any,
    *,
    total_only: bool = False,
) -> tuple[Any, Any, Any]:
    """A projected normal drawn from ``layer``'s P-NDF for a footprint ``N(c, cov)`` in
    global texels, and the P-NDF's integral (:func:`~materials.glints.pndf_drjit.lobes_sample`,
    :func:`~materials.glints.pndf_drjit.tiny_sample`)."""
    assert layer.lobes is not None
    k = layer.texel_scale
    if layer.method == "yan":
        cs = (c[0] * k, c[1] * k)
        covs = Sym2(cov.a * (k * k), cov.b * (k * k), cov.d * (k * k))
        return lobes_sample(
            mi, layer.lobes, cs, covs, u1, u2, active, max_items=MAX_ITEMS, total_only=total_only
        )  # fmt: skip
    assert layer.maps is not None and layer.sampler is not None
    return tiny_sample(
        mi, layer.maps, layer.sampler, layer.lobes, layer.transform, c, cov, u1, u2, active,
        max_items=MAX_ITEMS, total_only=total_only,
    )  # fmt: skip


def local_of_slopes(mi: types.ModuleType, si: Any, sx: Any, sy: Any) -> Any:
    """The local unit half vector whose :func:`example_slopes` are ``(sx, sy)`` (its
    inverse; ``z = sqrt(1 - |s|^2)``, 0 outside the unit disc)."""
    import drjit as dr

    du = si.to_local(si.dp_du)
    dv = si.to_local(si.dp_dv)
    norm = dr.sqrt(du.x * du.x + du.y * du.y)
    ok = norm > 1e-12
    inv = dr.select(ok, 1.0 / dr.maximum(norm, 1e-30), 0.0)
    tx, ty = du.x * inv, du.y * inv
    side = dr.select(tx * dv.y - ty * dv.x < 0.0, -1.0, 1.0)
    hx = dr.select(ok, tx * sx - side * ty * sy, sx)
    hy = dr.select(ok, ty * sx + side * tx * sy, sy)
    hz = dr.sqrt(dr.maximum(1.0 - hx * hx - hy * hy, 0.0))
    return mi.Vector3f(hx, hy, hz)


def example_slopes(mi: types.ModuleType, si: Any, h: Any) -> tuple[Any, Any]:
    """The projected normal ``(s_x, s_y)`` of the local half vector ``h`` in the example's
    axes: x along dp/du, y along dp/dv (both projected into the shading plane).

    Mitsuba's shading frame need not follow the uv directions (on its ``sphere`` the frame's
    t axis is opposite to dp/dv), while the example's normals are written in (u, v, n), so
    ``h`` is re-expressed in the orthonormal tangent frame ``(t_u, b)`` with ``t_u`` the unit
    projection of dp/du and ``b = n x t_u`` flipped to the side of dp/dv. Where dp/du
    vanishes (a sphere's poles) the shading frame's ``(h.x, h.y)`` is used.
    """
    import drjit as dr

    du = si.to_local(si.dp_du)
    dv = si.to_local(si.dp_dv)
    norm = dr.sqrt(du.x * du.x + du.y * du.y)
    ok = norm > 1e-12
    inv = dr.select(ok, 1.0 / dr.maximum(norm, 1e-30), 0.0)
    tx, ty = du.x * inv, du.y * inv
    side = dr.select(tx * dv.y - ty * dv.x < 0.0, -1.0, 1.0)  # b = (-ty, tx) . dv
    sx = tx * h.x + ty * h.y
    sy = side * (tx * h.y - ty * h.x)
    return dr.select(ok, sx, h.x), dr.select(ok, sy, h.y)


def _fresnel(mi: types.ModuleType, fresnel: tuple[Any, ...], cos_d: Any) -> Any:
    if fresnel[0] == "conductor":
        eta, k = fresnel[1], fresnel[2]
        ch = [
            mi.fresnel_conductor(cos_d, mi.Complex2f(float(eta[i]), float(k[i]))) for i in range(3)
        ]
        return mi.Color3f(ch[0], ch[1], ch[2])
    f = mi.fresnel(cos_d, float(fresnel[1]))[0]
    return mi.Color3f(f, f, f)


class GlintBSDF(MixtureReflector):
    """Glinty microstructure (plugin ``"glint"``).

    ================  ======  ========  ==============================================
    parameter         type    default   meaning
    ================  ======  ========  ==============================================
    ``layers``        string  --        key of :func:`put_layers` (base, clearcoat)
    ``texels_per_uv`` float   256       global texels across the uv range [0, 1]
    ================  ======  ========  ==============================================
    """

    #: Read by :func:`evaluators.render.integrators.fabric_path.wants`.
    needs_footprint = True

    def __init__(self, props: Any) -> None:
        MixtureReflector.__init__(self, props)
        mi = self.mi
        flags = mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.FrontSide
        key = str(props.get("layers"))
        prepared = _LAYERS.get(key)
        if prepared is None:
            raise ValueError(f"glint: no prepared layers {key!r} (see put_layers)")
        self._prepared = prepared  # keeps the key registered while this BSDF lives
        self.base, self.coat = prepared.base, prepared.coat
        self.texels_per_uv = float(props.get("texels_per_uv", 256.0))
        if not (math.isfinite(self.texels_per_uv) and self.texels_per_uv > 0):
            raise ValueError("glint: texels_per_uv must be > 0")
        self.sampling = MixtureSampling(self.base.alpha, GGX_WEIGHT)
        if self.base.sampling not in SAMPLINGS:
            raise ValueError(f"glint: sampling must be one of {SAMPLINGS}")
        self.pndf_sampling = self.base.sampling == "pndf" and self.base.method != "smooth_ggx"
        if self.pndf_sampling and self.base.method == "tiny_example":
            if self.base.placement is not None:
                raise ValueError("glint: sampling 'pndf' draws from tiled surfaces only")
            if self.base.lookup != "flat" or self.base.sampler is None:
                raise ValueError(
                    "glint: sampling 'pndf' draws from the 'flat' lookup's P-NDF and "
                    "needs the maps' sampler (jit_map_sampler)"
                )
        self.m_flags = flags
        self.m_components = [flags]

    def _footprint(self, si: Any, fallback: float) -> tuple[tuple[Any, Any], Sym2]:
        dr = self.dr
        t = self.texels_per_uv
        cx, cy = si.uv.x * t, si.uv.y * t
        ax, ay = si.duv_dx.x * t, si.duv_dx.y * t
        bx, by = si.duv_dy.x * t, si.duv_dy.y * t
        s2 = PIXEL_SIGMA * PIXEL_SIGMA
        a = s2 * (ax * ax + bx * bx) + 1e-6
        b = s2 * (ax * ay + bx * by)
        d = s2 * (ay * ay + by * by) + 1e-6
        none = (ax == 0.0) & (ay == 0.0) & (bx == 0.0) & (by == 0.0)
        f2 = fallback * fallback
        cov = Sym2(dr.select(none, f2, a), dr.select(none, 0.0, b), dr.select(none, f2, d))
        return (cx, cy), cov

    def _lobe(
        self, layer: GlintLayer, si: Any, wi: Any, wo: Any, h: Any, active: Any
    ) -> tuple[Any, Any]:
        """``(f, D)``: the layer's BRDF and its NDF value at ``h``."""
        mi, dr = self.mi, self.dr
        ggx = mi.MicrofacetDistribution(mi.MicrofacetType.GGX, layer.alpha, False)
        if layer.alphas is not None:  # smooth_ggx: the NDF alone differs, not G or F
            smooth = mi.MicrofacetDistribution(
                mi.MicrofacetType.GGX, layer.alphas[0], layer.alphas[1], False
            )
            d = smooth.eval(h)
        else:
            c, cov = self._footprint(si, layer.fallback_texels)
            d = layer_pndf(mi, layer, c, cov, example_slopes(mi, si, h), active)
        g = ggx.G(wi, wo, h)
        cos_d = dr.clip(dr.dot(wi, h), 0.0, 1.0)
        f = _fresnel(mi, layer.fresnel, cos_d)
        return f * (d * g / (4.0 * wi.z * wo.z)), d

    def brdf(self, ctx: Any, wi: Any, wo: Any, active: Any) -> Any:
        raise NotImplementedError  # glints need the interaction (footprint): see eval

    def _value_d(self, si: Any, wo: Any, active: Any) -> tuple[Any, Any]:
        """The BRDF at ``wo`` and the base layer's NDF at the half vector."""
        mi, dr = self.mi, self.dr
        wi = si.wi
        active = active & (wi.z > 0.0) & (wo.z > 0.0)
        h = dr.normalize(wi + wo)
        value, d = self._lobe(self.base, si, wi, wo, h, active)
        if self.coat is not None:
            cos_d = dr.clip(dr.dot(wi, h), 0.0, 1.0)
            f_c = mi.fresnel(cos_d, float(self.coat.fresnel[1]))[0]
            value = value * (1.0 - f_c) + self._lobe(self.coat, si, wi, wo, h, active)[0]
        return dr.select(active, value, 0.0), d

    def _value(self, si: Any, wo: Any, active: Any) -> Any:
        return self._value_d(si, wo, active)[0]

    def _pdf_of(self, si: Any, wo: Any, d: Any, total: Any, active: Any) -> Any:
        """``sampling="pndf"``: the mixture's density at ``wo``, given the base NDF
        ``d`` at the half vector and the P-NDF's integral ``total``: ``D cos_h / total``
        per solid angle of ``h``, times the reflection Jacobian ``1 / (4 wo.h)``."""
        mi, dr = self.mi, self.dr
        wi = si.wi
        h = dr.normalize(wi + wo)
        dot_oh = dr.dot(wo, h)
        ok = active & (wi.z > 0.0) & (wo.z > 0.0) & (dot_oh > 0.0) & (total > 0.0)
        p_d = dr.select(
            ok, d * h.z / (dr.maximum(total, 1e-30) * 4.0 * dr.maximum(dot_oh, 1e-30)), 0.0
        )
        p_mix = self.sampling.pdf(mi, wi, wo, active)
        return PNDF_WEIGHT * dr.maximum(p_d, 0.0) + (1.0 - PNDF_WEIGHT) * p_mix

    def _total(self, si: Any, active: Any) -> Any:
        mi, dr = self.mi, self.dr
        c, cov = self._footprint(si, self.base.fallback_texels)
        zero = dr.zeros(mi.Float)
        return layer_sample(
            mi, self.base, c, cov, zero, (zero, zero), active, total_only=True
        )[2]  # fmt: skip

    def pdf(self, ctx: Any, si: Any, wo: Any, active: Any = True) -> Any:
        active = self.enabled(ctx, active)
        if not self.pndf_sampling:
            return self._pdf(si.wi, wo, active)
        _, d = self._value_d(si, wo, active)
        return self._pdf_of(si, wo, d, self._total(si, active), active)

    # The footprint lives in ``si``, so eval / eval_pdf / sample are written here
    # rather than through the base class's ``brdf(ctx, wi, wo)``.
    def eval(self, ctx: Any, si: Any, wo: Any, active: Any = True) -> Any:
        dr = self.dr
        active = self.enabled(ctx, active)
        return self._value(si, wo, active) * dr.maximum(wo.z, 0.0)

    def eval_pdf(self, ctx: Any, si: Any, wo: Any, active: Any = True) -> Any:
        dr = self.dr
        active = self.enabled(ctx, active)
        if not self.pndf_sampling:
            value = self._value(si, wo, active) * dr.maximum(wo.z, 0.0)
            return value, self._pdf(si.wi, wo, active)
        value, d = self._value_d(si, wo, active)
        pdf = self._pdf_of(si, wo, d, self._total(si, active), active)
        return value * dr.maximum(wo.z, 0.0), pdf

    def sample(self, ctx: Any, si: Any, sample1: Any, sample2: Any, active: Any = True) -> Any:
        mi, dr = self.mi, self.dr
        from evaluators.render.bsdfs.common import sample_record

        active = self.enabled(ctx, active) & (si.wi.z > 0.0)
        if self.pndf_sampling:
            return self._sample_pndf(si, sample1, sample2, active, sample_record)
        wo = self.sampling.sample(mi, si.wi, sample1, sample2)
        pdf = self._pdf(si.wi, wo, active)
        active &= pdf > 0.0
        value = self._value(si, wo, active) * dr.maximum(wo.z, 0.0)
        bs = sample_record(mi, wo, pdf)
        return bs, dr.select(active, value / dr.maximum(pdf, 1e-30), 0.0)

    def _sample_pndf(self, si: Any, sample1: Any, sample2: Any, active: Any, record: Any) -> Any:
        """``sampling="pndf"``: with probability :data:`PNDF_WEIGHT` a half vector from
        the base layer's P-NDF (its lobes or tiles, then the Gaussian or the bilinear
        patch), reflected; otherwise the GGX/cosine mixture (``sample1`` rescaled)."""
        mi, dr = self.mi, self.dr
        wi = si.wi
        from_d = sample1 < PNDF_WEIGHT
        u1 = dr.select(from_d, sample1 / PNDF_WEIGHT, (sample1 - PNDF_WEIGHT) / (1.0 - PNDF_WEIGHT))
        c, cov = self._footprint(si, self.base.fallback_texels)
        sx, sy, total = layer_sample(
            mi, self.base, c, cov, u1, (sample2.x, sample2.y), active & from_d
        )
        inside = sx * sx + sy * sy < 1.0
        h = local_of_slopes(mi, si, sx, sy)
        wo_d = mi.reflect(wi, h)
        wo_m = self.sampling.sample(mi, wi, u1, sample2)
        wo = dr.select(from_d, wo_d, wo_m)
        drawn = active & (~from_d | (inside & (total > 0.0) & (dr.dot(wi, h) > 0.0)))
        value, d = self._value_d(si, wo, drawn)
        # The P-NDF's integral at this footprint, also for mixture draws.
        total = dr.select(from_d, total, self._total(si, drawn & ~from_d))
        pdf = self._pdf_of(si, wo, d, total, drawn)
        drawn &= pdf > 0.0
        value = value * dr.maximum(wo.z, 0.0)
        bs = record(mi, wo, pdf)
        return bs, dr.select(drawn, value / dr.maximum(pdf, 1e-30), 0.0)

    def to_string(self) -> str:
        coat = "" if self.coat is None else f", clearcoat {self.coat.method}"
        return (
            f"GlintBSDF[{self.base.method}, alpha={self.base.alpha:.3g}, "
            f"texels_per_uv={self.texels_per_uv:g}{coat}]"
        )
