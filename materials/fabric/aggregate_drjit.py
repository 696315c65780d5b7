"""Dr.Jit backend of the footprint estimator: the ``integrand`` code in one fused kernel.

There is no second copy of the physics here: :class:`DrJitOps` implements
:class:`~materials.fabric.array_ops.ArrayOps` over Dr.Jit arrays, and the very functions the
numpy estimator calls (``yarn.surface``, ``integrand.visibility``, ``shading.*``) are traced
once per chunk into a single kernel (LLVM or CUDA, the variant's backend): the visibility
march is a symbolic loop (compiled once, each SIMD packet leaving it when its lanes are
done) and the per-replicate moments are symbolic ``block_sum`` reductions (float64 atomic
adds) fused into the same kernel, so the per-sample terms never touch memory. The sample
points are those of ``samplers.py`` (Sobol points are rebuilt inside the kernel from the
same nets and shifts), so both backends integrate the same points and agree up to float32 round-off
(``tests/unit/materials/fabric/test_aggregate_drjit.py``).

Material scalars are baked into the kernel as literals, so each material compiles once
(about 0.1 s; Dr.Jit caches kernels in memory and on disk); chunk sizes and query values
do not. The sums are float64 atomic adds; reruns gave bit-identical results here, but the
additions' order is not guaranteed by Dr.Jit.

Dr.Jit starts through :func:`materials.backend.load_mitsuba`, which points it at a
working libLLVM (NOTES.md) or picks CUDA (``MATFORGE_VARIANT``); the array types are those of
the active variant's backend (:func:`materials.backend.jit_backend`). If only the scalar
fallback is available this module raises.
Timing note (NOTES.md): results are read back with ``.numpy()``, which waits for the kernel.
"""

from __future__ import annotations

import types
from collections.abc import Callable
from functools import lru_cache
from typing import TYPE_CHECKING, Any

import numpy as np

from materials.fabric import samplers
from materials.fabric.array_ops import Array
from materials.fabric.integrand import footprint_positions, sample_terms
from materials.fabric.params import FabricParams
from materials.fabric.yarn import YarnGeometry, tables

if TYPE_CHECKING:
    from materials.fabric.aggregate import EstimatorSettings, FootprintQueries


@lru_cache(maxsize=1)
def _drjit() -> types.SimpleNamespace:
    """Start Dr.Jit's backend of the active variant (once) and return its module and plain
    (non-AD) array types: ``drjit.llvm`` or ``drjit.cuda``."""
    from materials.backend import active_variant, jit_backend, load_mitsuba

    mi = load_mitsuba()
    import drjit as dr

    variant = active_variant() or ""
    if not variant.startswith(("llvm", "cuda")):
        raise RuntimeError(
            f"the Dr.Jit JIT backend is unavailable (Mitsuba variant {variant!r}); "
            f"use backend='numpy' or install libLLVM 19 (`make setup`)"
        )
    jit = jit_backend(mi)
    return types.SimpleNamespace(
        dr=dr, Bool=jit.Bool, Float=jit.Float, Float64=jit.Float64, UInt32=jit.UInt32
    )


class DrJitOps:
    """:class:`~materials.fabric.array_ops.ArrayOps` over Dr.Jit arrays.

    ``float_type`` and ``uint_type`` default to the active backend's ``Float`` / ``UInt32``
    (``drjit.llvm`` or ``drjit.cuda``); a Mitsuba
    plugin can pass its variant's types (e.g. ``mi.Float``, ``mi.UInt32``).
    """

    name = "drjit"

    def __init__(self, float_type: Any = None, uint_type: Any = None) -> None:
        jit = _drjit()
        self.dr = jit.dr
        self.Float = float_type or jit.Float
        self.UInt32 = uint_type or jit.UInt32

    def _f(self, x: Array | float) -> Array:
        return self.Float(x) if isinstance(x, int | float) else x

    def sqrt(self, x: Array) -> Array:
        return self.dr.sqrt(self.dr.maximum(x, 0.0))

    def sin(self, x: Array) -> Array:
        return self.dr.sin(x)

    def cos(self, x: Array) -> Array:
        return self.dr.cos(x)

    def exp(self, x: Array) -> Array:
        return self.dr.exp(x)

    def log(self, x: Array) -> Array:
        return self.dr.log(x)

    def abs(self, x: Array) -> Array:
        return self.dr.abs(x)

    def floor(self, x: Array) -> Array:
        return self.dr.floor(x)

    def erfinv(self, x: Array) -> Array:
        return self.dr.erfinv(x)

    def minimum(self, a: Array | float, b: Array | float) -> Array:
        return self.dr.minimum(self._f(a), self._f(b))

    def maximum(self, a: Array | float, b: Array | float) -> Array:
        return self.dr.maximum(self._f(a), self._f(b))

    def where(self, cond: Array, a: Array | float, b: Array | float) -> Array:
        return self.dr.select(cond, self._f(a), self._f(b))

    def index(self, x: Array) -> Array:
        return self.UInt32(x)

    def gather(self, table: Array, idx: Array) -> Array:
        return self.dr.gather(self.Float, table, idx)

    def table(self, values: np.ndarray) -> Array:
        return self.Float(np.ascontiguousarray(values, dtype=np.float32))

    def march(
        self,
        count: Array,
        max_steps: int,
        lanes: tuple[Array, ...],
        flag: Array,
        body: Callable[[Array, tuple[Array, ...]], tuple[Array, Array]],
    ) -> Array:
        # A symbolic loop: compiled once (not unrolled); each SIMD packet leaves it as soon
        # as all its lanes are done.
        dr, Float = self.dr, self.Float
        k0 = dr.zeros(Float, dr.width((count, flag, *lanes)))

        def cond(k: Array, done: Array) -> Array:
            return (k < count) & ~done

        def step(k: Array, done: Array) -> tuple[Array, Array]:
            hit, k_next = body(k, lanes)
            return k_next, done | hit

        # (An evaluated loop with lane compaction, ``compress=True``, ran 2.5x slower here.)
        _, out = dr.while_loop((k0, flag), cond, step)
        return out


def drjit_chunk_moments(
    params: FabricParams,
    geo: YarnGeometry,
    queries: FootprintQueries,
    first: int,
    count: int,
    settings: EstimatorSettings,
) -> np.ndarray:
    """``(count, replicates, 15)`` moments, as ``aggregate.numpy_chunk_moments`` computes.

    ``settings.threads`` is ignored (Dr.Jit uses its own pool, ``drjit.thread_count()``).
    Sobol points are built inside the kernel from the uploaded nets and per-query shifts
    (bit-identical to ``samplers.sample_points``); independent points are uploaded.
    """
    jit = _drjit()
    dr, Float, Float64, UInt32 = jit.dr, jit.Float, jit.Float64, jit.UInt32
    ops = DrJitOps()
    tab = tables(ops, geo)
    samples, replicates, seed = settings.samples, settings.replicates, settings.seed
    block = samples // replicates
    owner = dr.arange(UInt32, count * samples) // samples
    if settings.sampler == "sobol":
        nets = samplers.scrambled_nets(seed, replicates, block)
        shifts = samplers.digital_shifts(seed, first, count, replicates)
        k = dr.arange(UInt32, count * samples) - owner * samples  # = replicate * block + i
        slot = owner * replicates + k // block
        u = []
        for d in range(3):
            net = UInt32(np.ascontiguousarray(nets[:, :, d].ravel()))
            shift = UInt32(np.ascontiguousarray(shifts[:, :, d].ravel()))
            bits = dr.gather(UInt32, net, k) ^ dr.gather(UInt32, shift, slot)
            u.append((Float(bits >> 8) + 0.5) * (2.0**-24))  # = samplers.bits_to_unit
    else:
        pts = samplers.sample_points(
            "independent",
            seed=seed,
            first_query=first,
            n_queries=count,
            samples=samples,
            replicates=replicates,
        ).reshape(count * samples, 3)
        u = [Float(np.ascontiguousarray(pts[:, d])) for d in range(3)]
    sl = slice(first, first + count)

    def per_sample(a: np.ndarray) -> Array:
        return dr.gather(Float, Float(np.ascontiguousarray(a[sl], dtype=np.float32)), owner)

    centre = (per_sample(queries.centre[:, 0]), per_sample(queries.centre[:, 1]))
    s, t = footprint_positions(ops, centre, per_sample(queries.size), u[0], u[1], settings.kernel)
    wi = tuple(per_sample(queries.wi[:, k]) for k in range(3))
    wo = tuple(per_sample(queries.wo[:, k]) for k in range(3))
    terms = sample_terms(
        ops,
        params,
        geo,
        tab,
        s,
        t,
        (wi[0], wi[1], wi[2]),
        (wo[0], wo[1], wo[2]),
        u[2],
        with_visibility=settings.with_visibility,
        march_step=settings.march_step,
        march_max_steps=settings.march_max_steps,
        march=settings.march,
    )
    comps = [Float64(x) for x in terms[:4]]
    area = Float64(terms.area)
    area_in = Float64(terms.area_in)
    products = (
        *comps,
        area,
        area_in,
        *(c * c for c in comps),
        *(c * area for c in comps),
        area * area,
    )
    # Symbolic block sums: the integrand and the reductions fuse into one kernel whose
    # lanes atomically add (in float64) into the per-replicate moments.
    outs = dr.block_sum(products, block, mode="symbolic")
    dr.eval(outs)
    moments = np.stack([o.numpy() for o in outs], axis=1)
    return moments.reshape(count, replicates, len(outs))
