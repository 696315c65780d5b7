"""The shared half of the fabric Mitsuba BSDFs: footprints, sides, sampling, Eq. 8.

Two plugins shade a pixel footprint with the aggregated fabric BSDF ``f_P`` of Chen, Wang &
Wang 2024: ``fabric_aggregate`` (:mod:`evaluators.render.bsdfs.fabric_aggregate`, the Monte Carlo
reference)
and ``fabric_model`` (:mod:`evaluators.render.sources.fabric_model`, the trained network). Both
derive
from :class:`FabricFootprintBSDF`, which owns everything but the estimate itself:

- **Footprint** (tile units): tile ``(s, t)`` = ``uv * tiles_per_uv``, ``t`` scaled by the
  tile's aspect so a square uv patch keeps the weave's physical proportions. The pixel's
  footprint is the parallelogram spanned by ``si.duv_dx`` and ``si.duv_dy`` around
  ``si.uv`` (filled by the ``fabric_path`` integrator at camera hits,
  :mod:`evaluators.render.integrators.fabric_path`); where they are zero (secondary vertices, other
  integrators) it is a :data:`FALLBACK_FOOTPRINT` = 1 tile square, the tile average.
- **Sides**: the viewer is above the fabric (``wo_z > 0`` in Eq. 3); when ``si.wi`` is below
  the shading frame both directions are mirrored in the surface plane: a thin two-sided
  sheet whose back is a mirror image of its front. Light from the far side is transmission.
- **Sampling**: a cosine-weighted direction on the viewer's side with probability
  :data:`P_REFLECT`, on the far side otherwise; ``pdf`` is that density, and ``sample``'s
  weight is ``eval / pdf`` at the drawn direction.
- **Eq. 8**: the components ``C_warp, C_weft, S_warp, S_weft`` (unit albedos, incident
  cosine included) times the material's RGB albedos.
"""

from __future__ import annotations

import json
import math
from typing import Any

from evaluators.render.plugins import VariantPlugin
from materials.fabric.params import FabricParams
from materials.fabric.yarn import YarnGeometry

#: Footprint side (tiles) where no uv partials were given.
FALLBACK_FOOTPRINT = 1.0
#: Probability that ``sample`` draws on the viewer's side (reflection).
P_REFLECT = 0.75


class FabricFootprintBSDF(VariantPlugin):
    """Base of the fabric footprint BSDFs; subclasses define :meth:`estimate`.

    Properties read here: ``params`` (JSON of the ``FabricParams`` fields) and
    ``tiles_per_uv`` (float, default 16).
    """

    #: Read by :func:`evaluators.render.integrators.fabric_path.integrator_for`.
    needs_footprint = True

    def __init__(self, props: Any) -> None:
        VariantPlugin.__init__(self, props)
        mi = self.mi
        flags = (
            mi.BSDFFlags.GlossyReflection
            | mi.BSDFFlags.GlossyTransmission
            | mi.BSDFFlags.FrontSide
            | mi.BSDFFlags.BackSide
        )
        self.params = FabricParams(**json.loads(str(props.get("params"))))
        self.tiles_per_uv = float(props.get("tiles_per_uv", 16.0))
        if not (math.isfinite(self.tiles_per_uv) and self.tiles_per_uv > 0):
            raise ValueError("tiles_per_uv must be > 0")
        tw, th = YarnGeometry.from_params(self.params).tile
        self.scale = (self.tiles_per_uv, self.tiles_per_uv * tw / th)
        self.albedos = self.params.albedos()  # (4, 3): kd_warp, kd_weft, ks_warp, ks_weft
        self.m_flags = flags
        self.m_components = [flags]

    def directions(self, si: Any, light: Any, active: Any) -> tuple[Any, Any, Any]:
        """``(view, light, active)``: 3-tuples mirrored so the view is above (``z > 0``)."""
        mi, dr = self.mi, self.dr
        sign = dr.select(si.wi.z < 0.0, -1.0, 1.0)
        view = (si.wi.x, si.wi.y, si.wi.z * sign)
        lit = (light.x, light.y, light.z * sign)
        active = mi.Bool(active) & (view[2] > 1e-5) & (dr.abs(lit[2]) > 1e-6)
        return view, lit, active

    def footprint(self, si: Any) -> tuple[Any, Any, Any, Any, Any, Any]:
        """``(s, t, ax, ay, bx, by)``: centre and the two edge vectors, tile units."""
        dr = self.dr
        ks, kt = self.scale
        ax, ay = si.duv_dx.x * ks, si.duv_dx.y * kt
        bx, by = si.duv_dy.x * ks, si.duv_dy.y * kt
        none = (ax == 0.0) & (ay == 0.0) & (bx == 0.0) & (by == 0.0)
        ax = dr.select(none, FALLBACK_FOOTPRINT, ax)
        by = dr.select(none, FALLBACK_FOOTPRINT, by)
        return si.uv.x * ks, si.uv.y * kt, ax, ay, bx, by

    def recombine(self, comps: tuple[Any, Any, Any, Any]) -> Any:
        """Eq. 8: ``mi.Color3f`` from the four unit-albedo components."""
        rgb = [sum(float(self.albedos[k, ch]) * comps[k] for k in range(4)) for ch in range(3)]
        return self.mi.Color3f(rgb[0], rgb[1], rgb[2])

    def estimate(self, si: Any, light: Any, active: Any = True) -> Any:
        """``f_P`` (Eq. 8, incident cosine included) for view ``si.wi``; ``mi.Color3f``."""
        raise NotImplementedError

    def _pdf(self, si: Any, wo: Any, active: Any) -> Any:
        dr = self.dr
        same = wo.z * si.wi.z > 0.0
        side = dr.select(same, P_REFLECT, 1.0 - P_REFLECT)
        return dr.select(active, side * dr.abs(wo.z) * (1.0 / math.pi), 0.0)

    def eval(self, ctx: Any, si: Any, wo: Any, active: Any = True) -> Any:
        """``f_P`` with the cosine included (Mitsuba's ``eval``), ``mi.Spectrum``."""
        return self.estimate(si, wo, active)

    def pdf(self, ctx: Any, si: Any, wo: Any, active: Any = True) -> Any:
        """Solid-angle density of :meth:`sample` at ``wo``."""
        return self._pdf(si, wo, active)

    def eval_pdf(self, ctx: Any, si: Any, wo: Any, active: Any = True) -> Any:
        """``(eval, pdf)`` in one call."""
        return self.estimate(si, wo, active), self._pdf(si, wo, active)

    def sample(self, ctx: Any, si: Any, sample1: Any, sample2: Any, active: Any = True) -> Any:
        """Cosine-weighted direction, viewer's side with probability ``P_REFLECT``."""
        mi, dr = self.mi, self.dr
        d = mi.warp.square_to_cosine_hemisphere(sample2)
        reflect = sample1 < P_REFLECT
        side = dr.select(si.wi.z < 0.0, -1.0, 1.0) * dr.select(reflect, 1.0, -1.0)
        wo = mi.Vector3f(d.x, d.y, d.z * side)
        pdf = self._pdf(si, wo, active)
        active = mi.Bool(active) & (pdf > 0.0)
        value = self.estimate(si, wo, active)
        bs = dr.zeros(mi.BSDFSample3f)
        bs.wo = wo
        bs.pdf = pdf
        bs.eta = 1.0
        bs.sampled_type = dr.select(
            reflect,
            mi.UInt32(+mi.BSDFFlags.GlossyReflection),
            mi.UInt32(+mi.BSDFFlags.GlossyTransmission),
        )
        bs.sampled_component = mi.UInt32(0)
        weight = dr.select(active, value / dr.maximum(pdf, 1e-30), 0.0)
        return bs, weight
