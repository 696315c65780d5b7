"""The one path loop of our Python integrators, and what they share with it.

Our integrators (``neural_depth``, ``fabric_path``) are Mitsuba's ``path`` integrator
re-written in Python, each with one change; this module holds the estimator itself, once,
so the copies cannot drift:

- emitter sampling and BSDF sampling combined by the power heuristic (:func:`mis_weight`,
  Veach 1997), emission hit by a BSDF sample weighted against emitter sampling at the
  previous vertex;
- Russian roulette from ``rr_depth`` on, with the survival probability
  ``min(max(throughput) eta^2, 0.95)`` (``eta``: the product of the relative IORs crossed,
  as in ``path``);
- ``max_depth`` as in ``path`` (the longest path in segments; -1: no limit; 1: emitters
  only; 2: direct light).

An integrator changes the loop through two hooks of :func:`trace_paths`:

``prepare(si, depth, sampler, active)``
    called at every vertex after emitter sampling and before the BSDF's random numbers are
    drawn; may fill fields of ``si`` (``fabric_path``: the pixel footprint's uv partials and
    a seed in ``si.time``) and returns it.
``shade(bsdf, si, wo_em, s1, s2, active_em, active, depth)``
    the BSDF calls at a vertex: ``(eval, pdf)`` at the emitter sample's direction and
    ``sample``; returns ``(value_em, pdf_em, bs, weight)``. The default calls the BSDF with
    a plain context (``neural_depth`` picks the network or ``f_a`` by depth here).

All arrays are Dr.Jit arrays of the current (vectorised RGB) Mitsuba variant.
"""

from __future__ import annotations

import types
from collections.abc import Callable
from typing import Any

#: ``max_depth`` when a plugin's properties do not give one (as Mitsuba's ``path``).
DEFAULT_MAX_DEPTH = -1
#: ``rr_depth`` when a plugin's properties do not give one (as Mitsuba's ``path``).
DEFAULT_RR_DEPTH = 5

Shade = Callable[[Any, Any, Any, Any, Any, Any, Any, Any], tuple[Any, Any, Any, Any]]
Prepare = Callable[[Any, Any, Any, Any], Any]


def mis_weight(pdf_a: Any, pdf_b: Any) -> Any:
    """Power heuristic (Veach 1997) as Mitsuba's ``path`` integrator: ``a^2 / (a^2 + b^2)``,
    0 where it is not finite. Dr.Jit arrays of the current variant."""
    import drjit as dr

    a2, b2 = dr.square(pdf_a), dr.square(pdf_b)
    w = a2 / (a2 + b2)
    return dr.select(dr.isfinite(w), w, 0.0)


def read_depths(props: Any, plugin: str) -> tuple[int, int]:
    """``(max_depth, rr_depth)`` from a plugin's properties, with ``path``'s defaults and
    checks: ``max_depth`` is -1 or >= 1, ``rr_depth`` >= 1 (``ValueError`` naming
    ``plugin`` otherwise)."""
    max_depth = int(props.get("max_depth", DEFAULT_MAX_DEPTH))
    rr_depth = int(props.get("rr_depth", DEFAULT_RR_DEPTH))
    if max_depth < -1 or max_depth == 0 or rr_depth < 1:
        raise ValueError(f"{plugin}: max_depth must be -1 or >= 1, rr_depth >= 1")
    return max_depth, rr_depth


def plain_shade(mi: types.ModuleType) -> Shade:
    """The default ``shade`` hook: ``eval_pdf`` and ``sample`` with a plain context."""

    def shade(
        bsdf: Any, si: Any, wo: Any, s1: Any, s2: Any, active_em: Any, active: Any, depth: Any
    ) -> tuple[Any, Any, Any, Any]:
        ctx = mi.BSDFContext()
        value, pdf = bsdf.eval_pdf(ctx, si, wo, active_em)
        bs, weight = bsdf.sample(ctx, si, s1, s2, active)
        return value, pdf, bs, weight

    return shade


def _initial_state(mi: types.ModuleType, sampler: Any, ray: Any, active: Any) -> tuple[Any, ...]:
    """The loop state of :func:`trace_paths` before the first vertex."""
    import drjit as dr

    return (
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


def _emission_hit(
    mi: types.ModuleType,
    scene: Any,
    si: Any,
    active: Any,
    throughput: Any,
    result: Any,
    prev_si: Any,
    prev_bsdf_pdf: Any,
    prev_bsdf_delta: Any,
) -> Any:
    """``result`` plus the emission that the previous BSDF sample hit at ``si``,
    MIS-weighted against emitter sampling at the previous vertex."""
    import drjit as dr

    ds = mi.DirectionSample3f(scene, si=si, ref=prev_si)
    em_pdf = scene.pdf_emitter_direction(prev_si, ds, active & ~prev_bsdf_delta)
    emitted = ds.emitter.eval(si, active & (prev_bsdf_pdf > 0.0))
    return dr.fma(throughput, emitted * mis_weight(prev_bsdf_pdf, em_pdf), result)


def _shade_vertex(
    mi: types.ModuleType,
    scene: Any,
    sampler: Any,
    ray: Any,
    si: Any,
    depth: Any,
    active_next: Any,
    throughput: Any,
    result: Any,
    shade: Shade,
    prepare: Prepare | None,
) -> tuple[Any, Any, Any, Any]:
    """Emitter sampling at ``si``, then the ``prepare`` and ``shade`` hooks: the BSDF at the
    emitter sample's direction (MIS-weighted against BSDF sampling) and its own sample.
    Returns ``(si, result, bs, bsdf_weight)``: ``si`` as ``prepare`` left it, ``result``
    plus the emitter sample's contribution, and the BSDF sample with its weight."""
    import drjit as dr

    bsdf = si.bsdf(ray)
    active_em = active_next & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
    ds_em, em_weight = scene.sample_emitter_direction(
        si, sampler.next_2d(active_next), True, active_em
    )
    active_em &= ds_em.pdf != 0.0
    wo_em = si.to_local(ds_em.d)
    if prepare is not None:
        si = prepare(si, depth, sampler, active_next)
    s1, s2 = sampler.next_1d(active_next), sampler.next_2d(active_next)
    value_em, pdf_em, bs, bsdf_weight = shade(
        bsdf, si, wo_em, s1, s2, active_em, active_next, depth
    )
    mis_em = dr.select(ds_em.delta, 1.0, mis_weight(ds_em.pdf, pdf_em))
    result = dr.select(active_em, dr.fma(throughput, value_em * em_weight * mis_em, result), result)
    return si, result, bs, bsdf_weight


def _russian_roulette(
    sampler: Any, depth: Any, throughput: Any, eta: Any, active_next: Any, rr_depth: int
) -> tuple[Any, Any]:
    """Russian roulette, as in Mitsuba's path integrator: ``(throughput, active)`` after
    it (the throughput divided by the survival probability from ``rr_depth`` on)."""
    import drjit as dr

    throughput_max = dr.max(throughput)
    rr_prob = dr.minimum(throughput_max * dr.square(eta), 0.95)
    rr_active = depth >= rr_depth
    rr_continue = sampler.next_1d(active_next) < rr_prob
    throughput = dr.select(rr_active, throughput * dr.rcp(rr_prob), throughput)
    active = active_next & (~rr_active | rr_continue) & (throughput_max != 0.0)
    return throughput, active


def trace_paths(
    mi: types.ModuleType,
    scene: Any,
    sampler: Any,
    ray: Any,
    active: Any,
    *,
    max_depth: int,
    rr_depth: int,
    shade: Shade | None = None,
    prepare: Prepare | None = None,
    label: str = "path",
) -> tuple[Any, Any]:
    """One path per lane from ``ray``; returns ``(radiance, valid)`` as ``path`` does.

    ``max_depth`` (-1: no limit) and ``rr_depth`` as in Mitsuba's ``path``; ``shade`` and
    ``prepare`` are the hooks of the module docstring. The loop is a symbolic
    ``dr.while_loop``, traced once into the render kernel.
    """
    import drjit as dr

    shade = shade or plain_shade(mi)
    depth_limit = max_depth if max_depth > 0 else 0xFFFFFFFF

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
        result = _emission_hit(
            mi, scene, si, active, throughput, result, prev_si, prev_bsdf_pdf, prev_bsdf_delta
        )

        active_next = active & (depth + 1 < depth_limit) & si.is_valid()
        si, result, bs, bsdf_weight = _shade_vertex(
            mi, scene, sampler, ray, si, depth, active_next, throughput, result, shade, prepare
        )

        # The next segment.
        ray = si.spawn_ray(si.to_world(bs.wo))
        throughput = throughput * bsdf_weight
        eta = eta * bs.eta
        valid_ray = valid_ray | (
            active & si.is_valid() & ~mi.has_flag(bs.sampled_type, mi.BSDFFlags.Null)
        )
        prev_delta = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
        depth = dr.select(si.is_valid(), depth + 1, depth)
        throughput, active = _russian_roulette(
            sampler, depth, throughput, eta, active_next, rr_depth
        )
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

    state = _initial_state(mi, sampler, ray, active)
    out = dr.while_loop(state, lambda *s: s[2], body, label=label)
    return out[4], out[7]
