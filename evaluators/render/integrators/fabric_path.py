"""``fabric_path``: a path tracer that hands each pixel's footprint to the fabric BSDF.

Chen, Wang & Wang 2024, Sec. 6: the reference image shades each pixel with the aggregated
BSDF ``f_P`` of the pixel's footprint P (Eq. 3). A Mitsuba BSDF sees one hit point, not a
pixel, so this integrator supplies the footprint:

- **Camera rays through pixel centres.** Each of a pixel's samples traces the ray through
  the pixel's *centre* (no position jitter), with ray differentials one pixel apart (not
  scaled by ``1 / sqrt(spp)``); at its hit, ``si.compute_uv_partials`` gives the pixel's
  uv parallelogram ``si.duv_dx``, ``si.duv_dy``, which the ``fabric_aggregate`` BSDF samples
  as its box kernel k_P. So every sample of a pixel estimates the aggregate over the same,
  whole pixel footprint, and the pixel's mean over spp converges to the aggregate (at
  256 spp: the paper's ground truth; at 1: its baseline), as in the paper's renderer, which
  shades a G-buffer at pixel centres. Jittering the ray as well would blur the kernel into a
  two-pixel tent. The price: silhouettes of the shape are not antialiased.
- **Secondary vertices** get no partials (zeros), and the BSDF falls back to a one-tile
  footprint (the tile-averaged aggregate): their footprints, after a rough bounce, are
  much larger than a pixel's.
- **Randomness for ``eval``.** Before shading a vertex the integrator stores a fresh
  uniform number in ``si.time`` (the scenes have no motion blur); the BSDF hashes it into
  its footprint sample's seed (``evaluators/render/bsdfs/fabric_aggregate.py``).

Otherwise the estimator is the shared path loop of
:mod:`evaluators.render.integrators.common` (Mitsuba's ``path``: emitter sampling and BSDF
sampling combined by the power heuristic, Russian roulette from ``rr_depth``), with the
footprint and the seed set by its ``prepare`` hook. It subclasses Mitsuba's Python
``ADIntegrator`` only to own ``sample_rays``; rendering runs in primal mode (``mi.render``).
"""

from __future__ import annotations

import types
from typing import Any

from evaluators.render.integrators.common import read_depths, trace_paths
from evaluators.render.plugins import VariantPlugin, register_vectorised_integrator

#: The plugin name of the integrator.
FABRIC_INTEGRATOR = "fabric_path"


def wants(bsdf: Any) -> bool:
    """Whether ``bsdf`` needs pixel footprints: a true ``needs_footprint`` attribute (the
    fabric BSDFs have one)."""
    return bool(getattr(bsdf, "needs_footprint", False))


def integrator_dict(mi: types.ModuleType, bsdf: Any, integrator: dict[str, Any]) -> dict[str, Any]:
    """``fabric_path`` (registered here for ``mi``'s variant) with ``integrator``'s
    ``max_depth``."""
    register_fabric_integrator(mi)
    return {"type": FABRIC_INTEGRATOR, "max_depth": int(integrator.get("max_depth", -1))}


def register_fabric_integrator(mi: types.ModuleType) -> type:
    """Define and register ``fabric_path`` for Mitsuba's variant, once; returns the class."""
    return register_vectorised_integrator(
        mi, FABRIC_INTEGRATOR, FabricPathIntegrator, "fabric_path integrator"
    )


class FabricPathIntegrator(VariantPlugin):
    """Path tracer with pixel-footprint uv partials (plugin ``"fabric_path"``).

    =============  =====  =======  ===================================================
    parameter      type   default  meaning
    =============  =====  =======  ===================================================
    ``max_depth``  int    -1       longest path in segments, as ``path`` (-1: no limit)
    ``rr_depth``   int    5        depth from which Russian roulette starts
    =============  =====  =======  ===================================================
    """

    @classmethod
    def mitsuba_base(cls, mi: types.ModuleType) -> type:
        """Mitsuba's Python ``ADIntegrator`` of the current variant (it owns ``sample_rays``)."""
        from mitsuba.ad.integrators.common import ADIntegrator

        base: type = ADIntegrator
        return base

    def __init__(self, props: Any) -> None:
        VariantPlugin.__init__(self, props)
        # ADIntegrator keeps its own (unsigned) copies with other defaults; ours win.
        self.max_depth, self.rr_depth = read_depths(props, FABRIC_INTEGRATOR)

    def sample_rays(self, scene: Any, sensor: Any, sampler: Any) -> Any:
        """Rays through the pixel centres, with one-pixel differentials (module docstring)."""
        mi, dr = self.mi, self.dr
        film = sensor.film()
        if not film.rfilter().is_box_filter() or film.sample_border():
            raise ValueError("fabric_path needs a box reconstruction filter, no border")
        size = film.crop_size()
        spp = sampler.sample_count()
        idx = dr.arange(mi.UInt32, dr.prod(size) * spp) // dr.opaque(mi.UInt32, spp)
        pos = mi.Vector2i()
        pos.y = idx // size[0]
        pos.x = dr.fma(mi.UInt32(mi.Int32(-size[0])), pos.y, idx)
        pos += mi.Vector2i(film.crop_offset())
        scale = dr.rcp(mi.ScalarVector2f(size))
        offset = -mi.ScalarVector2f(film.crop_offset()) * scale
        centre = dr.fma(mi.Vector2f(pos) + 0.5, scale, offset)
        aperture = sampler.next_2d() if sensor.needs_aperture_sample() else mi.Vector2f(0.0)
        ray, weight = sensor.sample_ray_differential(
            time=sensor.shutter_open(), sample1=0.0, sample2=centre, sample3=aperture
        )
        return ray, weight, mi.Vector2f(pos)

    def sample(
        self,
        mode: Any,
        scene: Any,
        sampler: Any,
        ray: Any,
        δL: Any = None,  # noqa: PLC2401 (Mitsuba's keyword names)
        δaovs: Any = None,  # noqa: PLC2401
        state_in: Any = None,
        active: Any = True,
        **kwargs: Any,
    ) -> Any:
        """One path per lane; returns ``(radiance, valid, [], None)`` (primal only)."""
        mi, dr = self.mi, self.dr
        if mode != dr.ADMode.Primal:
            raise RuntimeError("fabric_path renders in primal mode only")
        primary = ray  # (a copy constructor would drop has_differentials)
        if not primary.has_differentials:
            raise ValueError("fabric_path: the camera rays carry no differentials")

        def prepare(si: Any, depth: Any, sampler: Any, active: Any) -> Any:
            # The pixel footprint at the camera ray's hit; none further down the path.
            first = depth == 0
            si.compute_uv_partials(primary)
            si.duv_dx = dr.select(first, si.duv_dx, 0.0)
            si.duv_dy = dr.select(first, si.duv_dy, 0.0)
            si.time = sampler.next_1d(active)  # the BSDF's seed (module docstring)
            return si

        radiance, valid = trace_paths(
            mi,
            scene,
            sampler,
            ray,
            active,
            max_depth=self.max_depth,
            rr_depth=self.rr_depth,
            prepare=prepare,
            label="fabric_path",
        )
        return radiance, valid, [], None

    def aov_names(self) -> list[str]:
        return []

    def to_string(self) -> str:
        return f"FabricPathIntegrator[max_depth={self.max_depth}, rr_depth={self.rr_depth}]"
