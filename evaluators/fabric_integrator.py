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
  its footprint sample's seed (``materials/fabric/bsdf.py``).

Otherwise the estimator is Mitsuba's ``path`` (emitter sampling and BSDF sampling combined
by the power heuristic, Russian roulette from ``rr_depth``), written after
:mod:`evaluators.neural_depth_integrator`. It subclasses Mitsuba's Python ``ADIntegrator``
only to own ``sample_rays``; rendering runs in primal mode (``mi.render``).
"""

from __future__ import annotations

import types
from typing import Any

from materials.mitsuba_backend import mis_weight, register_vectorised_integrator

#: The plugin name of the integrator.
FABRIC_INTEGRATOR = "fabric_path"


def integrator_for(mi: types.ModuleType, bsdf: Any, integrator: dict[str, Any]) -> dict[str, Any]:
    """``fabric_path`` (same ``max_depth``) if ``bsdf`` needs pixel footprints, else ``integrator``.

    A BSDF asks for footprints with a true ``needs_footprint`` attribute (the
    ``fabric_aggregate`` plugin does).
    """
    if not getattr(bsdf, "needs_footprint", False):
        return integrator
    register_fabric_integrator(mi)
    return {"type": FABRIC_INTEGRATOR, "max_depth": int(integrator.get("max_depth", -1))}


def register_fabric_integrator(mi: types.ModuleType) -> type:
    """Define and register ``fabric_path`` for Mitsuba's variant, once; returns the class."""
    return register_vectorised_integrator(
        mi, FABRIC_INTEGRATOR, _define_class, "fabric_path integrator"
    )


def _define_class(mi: types.ModuleType) -> type:
    import drjit as dr
    from mitsuba.ad.integrators.common import ADIntegrator

    class FabricPathIntegrator(ADIntegrator):  # type: ignore[misc,valid-type]
        """Path tracer with pixel-footprint uv partials (plugin ``"fabric_path"``).

        =============  =====  =======  ===================================================
        parameter      type   default  meaning
        =============  =====  =======  ===================================================
        ``max_depth``  int    6        longest path in segments, as ``path`` (-1: no limit)
        ``rr_depth``   int    5        depth from which Russian roulette starts
        =============  =====  =======  ===================================================
        """

        def __init__(self, props: Any) -> None:
            super().__init__(props)
            if self.max_depth == 0:
                raise ValueError("fabric_path: max_depth must be -1 or >= 1")

        def sample_rays(self, scene: Any, sensor: Any, sampler: Any) -> Any:
            """Rays through the pixel centres, with one-pixel differentials (module docstring)."""
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
            if mode != dr.ADMode.Primal:
                raise RuntimeError("fabric_path renders in primal mode only")
            primary = ray  # (a copy constructor would drop has_differentials)
            if not primary.has_differentials:
                raise ValueError("fabric_path: the camera rays carry no differentials")
            state = (
                sampler,
                mi.Ray3f(ray),
                mi.Bool(active),
                mi.UInt32(0),  # depth of the current vertex
                mi.Spectrum(0.0),  # radiance
                mi.Spectrum(1.0),  # throughput
                mi.Bool(False),  # valid_ray
                dr.zeros(mi.SurfaceInteraction3f),  # previous vertex
                mi.Float(1.0),  # previous BSDF sample's pdf
                mi.Bool(True),  # previous BSDF sample was a delta
            )

            def body(
                sampler: Any,
                ray: Any,
                active: Any,
                depth: Any,
                result: Any,
                throughput: Any,
                valid_ray: Any,
                prev_si: Any,
                prev_bsdf_pdf: Any,
                prev_bsdf_delta: Any,
            ) -> tuple[Any, ...]:
                si = scene.ray_intersect(
                    ray, ray_flags=mi.RayFlags.All, coherent=(depth == 0), active=active
                )
                ds = mi.DirectionSample3f(scene, si=si, ref=prev_si)
                em_pdf = scene.pdf_emitter_direction(prev_si, ds, active & ~prev_bsdf_delta)
                emitted = ds.emitter.eval(si, active & (prev_bsdf_pdf > 0.0))
                result = dr.fma(throughput, emitted * mis_weight(prev_bsdf_pdf, em_pdf), result)

                # The pixel footprint at the camera ray's hit; none further down the path.
                first = depth == 0
                si.compute_uv_partials(primary)
                si.duv_dx = dr.select(first, si.duv_dx, 0.0)
                si.duv_dy = dr.select(first, si.duv_dy, 0.0)

                active_next = active & (depth + 1 < self.max_depth) & si.is_valid()
                bsdf = si.bsdf(ray)
                active_em = active_next & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
                ds_em, em_weight = scene.sample_emitter_direction(
                    si, sampler.next_2d(active_next), True, active_em
                )
                active_em &= ds_em.pdf != 0.0
                wo_em = si.to_local(ds_em.d)
                si.time = sampler.next_1d(active_next)  # the BSDF's seed (module docstring)
                s1, s2 = sampler.next_1d(active_next), sampler.next_2d(active_next)
                ctx = mi.BSDFContext()
                value_em, pdf_em = bsdf.eval_pdf(ctx, si, wo_em, active_em)
                bs, bsdf_weight = bsdf.sample(ctx, si, s1, s2, active_next)
                mis_em = dr.select(ds_em.delta, 1.0, mis_weight(ds_em.pdf, pdf_em))
                result = dr.select(
                    active_em, dr.fma(throughput, value_em * em_weight * mis_em, result), result
                )

                ray = si.spawn_ray(si.to_world(bs.wo))
                throughput = throughput * bsdf_weight
                valid_ray = valid_ray | (
                    active & si.is_valid() & ~mi.has_flag(bs.sampled_type, mi.BSDFFlags.Null)
                )
                prev_delta = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
                depth = dr.select(si.is_valid(), depth + 1, depth)

                # Russian roulette, as in Mitsuba's path integrator (no refraction: eta = 1).
                throughput_max = dr.max(throughput)
                rr_prob = dr.minimum(throughput_max, 0.95)
                rr_active = depth >= self.rr_depth
                rr_continue = sampler.next_1d(active_next) < rr_prob
                throughput = dr.select(rr_active, throughput * dr.rcp(rr_prob), throughput)
                active = active_next & (~rr_active | rr_continue) & (throughput_max != 0.0)
                return (
                    sampler,
                    ray,
                    active,
                    depth,
                    result,
                    throughput,
                    valid_ray,
                    mi.SurfaceInteraction3f(si),
                    bs.pdf,
                    prev_delta,
                )

            out = dr.while_loop(state, lambda *s: s[2], body, label="fabric_path")
            return out[4], out[6], [], None

        def aov_names(self) -> list[str]:
            return []

        def to_string(self) -> str:
            return f"FabricPathIntegrator[max_depth={self.max_depth}, rr_depth={self.rr_depth}]"

    return FabricPathIntegrator
