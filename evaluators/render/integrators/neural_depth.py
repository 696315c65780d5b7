"""A path tracer that evaluates neural BRDFs only up to a given bounce (paper, Sec. 5.3).

De Oliveira et al., "A Hybrid Neural-Microfacet BRDF Model for Real-Time Rendering",
Sec. 5.3 and Table 5: "evaluating the network only when it meaningfully contributes to the
final appearance, and falling back to the analytical component otherwise", by bounce.

Why an integrator: a Mitsuba BSDF never sees the path depth, so the decision has to be made
by whoever tracks it. This integrator (registered as ``"neural_depth"`` by
:func:`register_neural_depth_integrator`) is the shared path loop of
:mod:`evaluators.render.integrators.common` (Mitsuba's ``path`` estimator) with one hook,
``shade``: at a
vertex of depth ``d`` (0 = the camera ray's hit) it calls the BSDF with the
:data:`evaluators.render.bsdfs.brdf_model.ANALYTIC_ONLY` bit of ``BSDFContext.type_mask`` set when
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
same image (to float rounding) in about twice the time of this integrator
(``benchmarks/bench_neural_depth.py``).
"""

from __future__ import annotations

import types
from typing import Any

from evaluators.render.bsdfs.brdf_model import ANALYTIC_ONLY
from evaluators.render.integrators.common import read_depths, trace_paths
from evaluators.render.plugins import VariantPlugin, register_vectorised_integrator

#: The plugin name of the integrator.
NEURAL_DEPTH_INTEGRATOR = "neural_depth"


def wants(bsdf: Any) -> bool:
    """Whether ``bsdf`` asks for this integrator: a ``brdf_model`` BSDF loaded with a
    ``neural_max_depth`` hint."""
    return getattr(bsdf, "neural_max_depth", None) is not None


def integrator_dict(mi: types.ModuleType, bsdf: Any, integrator: dict[str, Any]) -> dict[str, Any]:
    """``neural_depth`` (registered here for ``mi``'s variant) with ``integrator``'s
    ``max_depth`` and ``bsdf``'s ``neural_max_depth``."""
    register_neural_depth_integrator(mi)
    return {
        "type": NEURAL_DEPTH_INTEGRATOR,
        "max_depth": int(integrator.get("max_depth", -1)),
        "neural_max_depth": int(bsdf.neural_max_depth),
    }


def register_neural_depth_integrator(mi: types.ModuleType) -> type:
    """Define and register the ``"neural_depth"`` integrator for Mitsuba's current variant.

    Idempotent per variant; returns the class. Needs a vectorised RGB variant
    (``llvm_ad_rgb`` or ``cuda_ad_rgb``).
    """
    return register_vectorised_integrator(
        mi, NEURAL_DEPTH_INTEGRATOR, NeuralDepthIntegrator, "neural_depth integrator"
    )


class NeuralDepthIntegrator(VariantPlugin):
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

    @classmethod
    def mitsuba_base(cls, mi: types.ModuleType) -> type:
        """``mi.SamplingIntegrator`` of the current variant."""
        base: type = mi.SamplingIntegrator
        return base

    def __init__(self, props: Any) -> None:
        VariantPlugin.__init__(self, props)
        self.max_depth, self.rr_depth = read_depths(props, NEURAL_DEPTH_INTEGRATOR)
        self.neural_max_depth = int(props.get("neural_max_depth", -1))
        if self.neural_max_depth < -1:
            raise ValueError("neural_depth: neural_max_depth must be -1 or >= 0")

    def _shade(
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
        """The ``shade`` hook: ``eval_pdf`` at the emitter sample and ``sample``, neural
        or analytic.

        Both are wrapped in symbolic ``if`` statements (see the module docstring): an
        outer one on ``active`` (the lanes that shade this vertex), so that packets
        whose paths have all escaped or ended skip the BSDF entirely, and an inner one
        on ``depth < neural_max_depth``.
        """
        mi, dr = self.mi, self.dr
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
                true_fn=calls(self._context(False)),
                false_fn=calls(self._context(True)),
                label="neural_depth: network or f_a",
            )

        shade = calls(self._context(n == 0)) if n <= 0 else by_depth
        return dr.if_stmt(
            args=args, cond=active, true_fn=shade, false_fn=skip, label="neural_depth: shade"
        )

    def _context(self, analytic: bool) -> Any:
        """A ``mi.BSDFContext`` asking for ``f_a`` alone if ``analytic``
        (:data:`~evaluators.render.bsdfs.brdf_model.ANALYTIC_ONLY`), else the full model."""
        ctx = self.mi.BSDFContext()
        ctx.type_mask = ctx.type_mask | (ANALYTIC_ONLY if analytic else 0)
        return ctx

    def sample(
        self, scene: Any, sampler: Any, ray: Any, medium: Any = None, active: Any = True
    ) -> Any:
        """One path per lane; returns ``(radiance, valid, [])`` as ``path`` does."""
        mi = self.mi
        radiance, valid = trace_paths(
            mi,
            scene,
            sampler,
            ray,
            active,
            max_depth=self.max_depth,
            rr_depth=self.rr_depth,
            shade=self._shade,
            label="neural_depth path",
        )
        return radiance, valid, []

    def aov_names(self) -> list[str]:
        return []

    def to_string(self) -> str:
        return (
            f"NeuralDepthIntegrator[max_depth={self.max_depth}, rr_depth={self.rr_depth}, "
            f"neural_max_depth={self.neural_max_depth}]"
        )
