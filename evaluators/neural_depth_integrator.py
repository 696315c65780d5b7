"""A path tracer that evaluates neural BRDFs only up to a given bounce (paper, Sec. 5.3).

De Oliveira et al., "A Hybrid Neural-Microfacet BRDF Model for Real-Time Rendering",
Sec. 5.3 and Table 5: "evaluating the network only when it meaningfully contributes to the
final appearance, and falling back to the analytical component otherwise", by bounce.

Why an integrator: a Mitsuba BSDF never sees the path depth, so the decision has to be made
by whoever tracks it. This integrator (registered as ``"neural_depth"`` by
:func:`register_neural_depth_integrator`) is Mitsuba's ``path`` integrator re-written in
Python (same estimator: emitter sampling and BSDF sampling combined by the power heuristic,
Russian roulette from ``rr_depth`` on, ``max_depth`` as in ``path``), with one change: at a
vertex of depth ``d`` (0 = the camera ray's hit) it calls the BSDF with the
:data:`materials.model_bsdf.ANALYTIC_ONLY` bit of ``BSDFContext.type_mask`` set when
``d >= neural_max_depth``. The ``brdf_model`` BSDF then traces ``f_a`` (Eq. 3) instead of
the hybrid ``f_c + f_g f_a``; sampling and pdf are the same in both cases (Sec. 5.2 needs
no network). Native plugins ignore the bit. So ``neural_max_depth = 1`` runs the network at
first hits only, as the paper's "Neural inference enabled until 1 bounce"; 0 renders the
analytic model; ``-1`` (the default) never falls back.

Cost: both variants of the BSDF are traced into one kernel, inside a symbolic ``if`` on
``depth < neural_max_depth``. Dr.Jit's LLVM backend branches over SIMD packets, and all
live lanes of a packet sit at the same depth, so the network's instructions are skipped,
not masked, past the threshold (``benchmarks/bench_neural_depth.py`` measures it). The
BSDF calls also sit inside an outer ``if`` on the lanes that shade the vertex: without it
the packets whose paths have all escaped still pay for the network, masked, at every later
iteration of the loop. Measured on ``sphere_env`` (256x256, 32 spp, 32x3 hybrid, kernel
time): 842 ms without the outer ``if``, 274 ms with it; Mitsuba's C++ ``path`` renders the
same image bit for bit in about twice the time of this integrator
(``benchmarks/bench_neural_depth.py``).
"""

from __future__ import annotations

import types
from typing import Any

from materials.mitsuba_backend import mis_weight, register_vectorised_integrator
from materials.model_bsdf import ANALYTIC_ONLY

#: The plugin name of the integrator.
NEURAL_DEPTH_INTEGRATOR = "neural_depth"


def integrator_for(mi: types.ModuleType, bsdf: Any, integrator: dict[str, Any]) -> dict[str, Any]:
    """The integrator dict to render ``bsdf`` with, given the scene's default ``integrator``.

    ``integrator`` is a ``{"type": "path", "max_depth": n}`` dict; when ``bsdf`` is a
    ``brdf_model`` BSDF loaded with ``neural_max_depth``, the ``neural_depth`` integrator
    (registered here for ``mi``'s variant) with the same ``max_depth`` replaces it.
    Otherwise ``integrator`` is returned unchanged.
    """
    depth = getattr(bsdf, "neural_max_depth", None)
    if depth is None:
        return integrator
    register_neural_depth_integrator(mi)
    return {
        "type": NEURAL_DEPTH_INTEGRATOR,
        "max_depth": int(integrator.get("max_depth", -1)),
        "neural_max_depth": int(depth),
    }


def register_neural_depth_integrator(mi: types.ModuleType) -> type:
    """Define and register the ``"neural_depth"`` integrator for Mitsuba's current variant.

    Idempotent per variant; returns the class. Needs a vectorised RGB variant (``llvm_ad_rgb``).
    """
    return register_vectorised_integrator(
        mi, NEURAL_DEPTH_INTEGRATOR, _define_class, "neural_depth integrator"
    )


def _define_class(mi: types.ModuleType) -> type:
    import drjit as dr

    def context(analytic: bool) -> Any:
        ctx = mi.BSDFContext()
        ctx.type_mask = ctx.type_mask | (ANALYTIC_ONLY if analytic else 0)
        return ctx

    class NeuralDepthIntegrator(mi.SamplingIntegrator):  # type: ignore[name-defined]
        """Path tracer with selective neural evaluation (plugin ``"neural_depth"``).

        ====================  =====  =======  ==============================================
        parameter             type   default  meaning
        ====================  =====  =======  ==============================================
        ``max_depth``         int    -1       longest path in segments, as ``path`` (-1: no
                                              limit; 1: emitters only; 2: direct light)
        ``rr_depth``          int    5        depth from which Russian roulette starts
        ``neural_max_depth``  int    -1       vertices of depth ``< neural_max_depth`` get
                                              the full model, deeper ones ``f_a`` (-1: all)
        ====================  =====  =======  ==============================================
        """

        def __init__(self, props: Any) -> None:
            mi.SamplingIntegrator.__init__(self, props)
            self.max_depth = int(props.get("max_depth", -1))
            self.rr_depth = int(props.get("rr_depth", 5))
            self.neural_max_depth = int(props.get("neural_max_depth", -1))
            if self.max_depth < -1 or self.max_depth == 0 or self.rr_depth < 1:
                raise ValueError("neural_depth: max_depth must be -1 or >= 1, rr_depth >= 1")
            if self.neural_max_depth < -1:
                raise ValueError("neural_depth: neural_max_depth must be -1 or >= 0")

        def _bsdf_calls(
            self,
            bsdf: Any,
            si: Any,
            wo: Any,
            s1: Any,
            s2: Any,
            active_em: Any,
            active: Any,
            depth: Any,
        ) -> Any:
            """``eval_pdf`` at the emitter sample and ``sample``, neural or analytic.

            Both are wrapped in symbolic ``if`` statements (see the module docstring): an
            outer one on ``active`` (the lanes that shade this vertex), so that packets
            whose paths have all escaped or ended skip the BSDF entirely, and an inner one
            on ``depth < neural_max_depth``.
            """
            n = self.neural_max_depth
            args = (si, wo, s1, s2, active_em, active, depth)

            def calls(ctx: Any) -> Any:
                def body(si: Any, wo: Any, s1: Any, s2: Any, em: Any, act: Any, d: Any) -> Any:
                    value, pdf = bsdf.eval_pdf(ctx, si, wo, em)
                    bs, weight = bsdf.sample(ctx, si, s1, s2, act)
                    return value, pdf, bs, weight

                return body

            def skip(*_: Any) -> Any:
                zero = dr.zeros(mi.Spectrum)
                return zero, dr.zeros(mi.Float), dr.zeros(mi.BSDFSample3f), zero

            def by_depth(*a: Any) -> Any:
                return dr.if_stmt(
                    args=a,
                    cond=a[5] & (a[6] < n),
                    true_fn=calls(context(False)),
                    false_fn=calls(context(True)),
                    label="neural_depth: network or f_a",
                )

            shade = calls(context(n == 0)) if n <= 0 else by_depth
            return dr.if_stmt(
                args=args, cond=active, true_fn=shade, false_fn=skip, label="neural_depth: shade"
            )

        def sample(
            self, scene: Any, sampler: Any, ray: Any, medium: Any = None, active: Any = True
        ) -> Any:
            """One path per lane; returns ``(radiance, valid, [])`` as ``path`` does."""
            max_depth = self.max_depth if self.max_depth > 0 else 0xFFFFFFFF
            state = (
                sampler,
                mi.Ray3f(ray),
                mi.Bool(active),
                mi.UInt32(0),  # depth of the current vertex
                mi.Spectrum(0.0),  # radiance
                mi.Spectrum(1.0),  # throughput
                mi.Float(1.0),  # relative IOR along the path
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
                eta: Any,
                valid_ray: Any,
                prev_si: Any,
                prev_bsdf_pdf: Any,
                prev_bsdf_delta: Any,
            ) -> tuple[Any, ...]:
                si = scene.ray_intersect(
                    ray, ray_flags=mi.RayFlags.All, coherent=(depth == 0), active=active
                )
                # Emission hit by the previous BSDF sample, MIS-weighted against emitter
                # sampling at the previous vertex.
                ds = mi.DirectionSample3f(scene, si=si, ref=prev_si)
                em_pdf = scene.pdf_emitter_direction(prev_si, ds, active & ~prev_bsdf_delta)
                emitted = ds.emitter.eval(si, active & (prev_bsdf_pdf > 0.0))
                result = dr.fma(throughput, emitted * mis_weight(prev_bsdf_pdf, em_pdf), result)

                active_next = active & (depth + 1 < max_depth) & si.is_valid()
                bsdf = si.bsdf(ray)
                active_em = active_next & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
                ds_em, em_weight = scene.sample_emitter_direction(
                    si, sampler.next_2d(active_next), True, active_em
                )
                active_em &= ds_em.pdf != 0.0
                wo_em = si.to_local(ds_em.d)
                s1, s2 = sampler.next_1d(active_next), sampler.next_2d(active_next)
                value_em, pdf_em, bs, bsdf_weight = self._bsdf_calls(
                    bsdf, si, wo_em, s1, s2, active_em, active_next, depth
                )
                mis_em = dr.select(ds_em.delta, 1.0, mis_weight(ds_em.pdf, pdf_em))
                result = dr.select(
                    active_em, dr.fma(throughput, value_em * em_weight * mis_em, result), result
                )

                ray = si.spawn_ray(si.to_world(bs.wo))
                throughput = throughput * bsdf_weight
                eta = eta * bs.eta
                valid_ray = valid_ray | (
                    active & si.is_valid() & ~mi.has_flag(bs.sampled_type, mi.BSDFFlags.Null)
                )
                prev_delta = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
                depth = dr.select(si.is_valid(), depth + 1, depth)

                # Russian roulette, as in Mitsuba's path integrator.
                throughput_max = dr.max(throughput)
                rr_prob = dr.minimum(throughput_max * dr.square(eta), 0.95)
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
                    eta,
                    valid_ray,
                    mi.SurfaceInteraction3f(si),
                    bs.pdf,
                    prev_delta,
                )

            out = dr.while_loop(state, lambda *s: s[2], body, label="neural_depth path")
            return out[4], out[7], []

        def aov_names(self) -> list[str]:
            return []

        def to_string(self) -> str:
            return (
                f"NeuralDepthIntegrator[max_depth={self.max_depth}, rr_depth={self.rr_depth}, "
                f"neural_max_depth={self.neural_max_depth}]"
            )

    return NeuralDepthIntegrator
