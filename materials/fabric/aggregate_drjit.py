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

import math
import types
from collections.abc import Callable, Sequence
from functools import lru_cache
from typing import TYPE_CHECKING, Any

import numpy as np

from materials.fabric import samplers
from materials.fabric.array_ops import Array
from materials.fabric.integrand import SamplePoint, footprint_positions, sample_terms_batch
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

    def march_many(
        self,
        counts: Sequence[Array],
        max_steps: int,
        lanes: Sequence[tuple[Array, ...]],
        body: Callable[[Array, tuple[Array, ...]], tuple[Array, Array]],
    ) -> list[Array]:
        # One symbolic loop: each lane runs its marches back to back, so a packet leaves when
        # its lanes' summed iterations are done. ``todo`` has a bit per march still to run
        # (those with steps), ``phase`` = its lowest bit (the march under way), ``hits`` a bit
        # per blocked march: O(1) bookkeeping per iteration, whatever the number of marches.
        dr, Float, n = self.dr, self.Float, len(counts)
        if n > 32:
            raise ValueError(f"at most 32 marches per element, got {n}")
        UInt32 = dr.uint32_array_t(Float)
        width = dr.width((*counts, *(a for lane in lanes for a in lane)))

        def pick(values: Sequence[Array], phase: Array) -> Array:
            # The marches' inputs repeat (a sample's start point is shared by its two rays,
            # a direction by every sample of a query): one select per change of value, and
            # a select on the phase's parity where the values alternate.
            distinct: list[Array] = []
            for v in values:
                if not any(v is d for d in distinct):
                    distinct.append(v)
            if len(distinct) == 1:
                return self._f(values[0])
            if len(distinct) == 2 and all(v is values[j % 2] for j, v in enumerate(values)):
                return dr.select((phase & 1) == 0, self._f(values[0]), self._f(values[1]))
            runs: list[tuple[int, Array]] = []
            for j, v in enumerate(values):
                if runs and runs[-1][1] is v:
                    runs[-1] = (j, v)
                else:
                    runs.append((j, v))
            out = self._f(runs[-1][1])
            for last, v in reversed(runs[:-1]):
                out = dr.select(phase <= last, self._f(v), out)
            return out

        todo0 = dr.zeros(UInt32, width)
        for j, c in enumerate(counts):
            todo0 |= dr.select(c > 0.0, UInt32(1 << j), UInt32(0))
        k0 = dr.zeros(Float, width)
        hits0 = dr.zeros(UInt32, width)

        def cond(todo: Array, k: Array, hits: Array) -> Array:
            return todo != 0

        def step(todo: Array, k: Array, hits: Array) -> tuple[Array, Array, Array]:
            phase = dr.tzcnt(todo)
            cur = tuple(pick([lane[i] for lane in lanes], phase) for i in range(len(lanes[0])))
            hit, k_next = body(k, cur)
            bit = UInt32(1) << phase
            done = hit | (k_next >= pick(counts, phase))
            return (
                dr.select(done, todo & ~bit, todo),
                dr.select(done, 0.0, k_next),
                dr.select(hit, hits | bit, hits),
            )

        _, _, hits = dr.while_loop((todo0, k0, hits0), cond, step)
        return [(hits & (1 << j)) != 0 for j in range(n)]


#: Samples per SIMD lane with the batched march: their 2 x LANE_SAMPLES rays are marched
#: back to back in one loop (a power of two, at most 16: 32 marches per lane). 1, 2, 4, 8
#: and 16 were measured (BENCHMARKS.md); the kernel grows with it (about 1.8 s to compile
#: per material at 8 on the loaded 2-core VM, 0.35 s at 1).
LANE_SAMPLES = 8


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
    # Samples per lane: with the batched march one lane integrates ``per_lane`` consecutive
    # samples of one replicate block, and marches all their rays in one loop.
    per_lane = math.gcd(block, LANE_SAMPLES) if settings.march == "batched" else 1
    width = count * samples // per_lane
    lane = dr.arange(UInt32, width)
    if settings.sampler == "sobol":
        nets = samplers.scrambled_nets(seed, replicates, block)
        net = [UInt32(np.ascontiguousarray(nets[:, :, d].ravel())) for d in range(3)]
        shifts = samplers.digital_shifts(seed, first, count, replicates)
        shift = [UInt32(np.ascontiguousarray(shifts[:, :, d].ravel())) for d in range(3)]
    else:
        pts = samplers.sample_points(
            "independent",
            seed=seed,
            first_query=first,
            n_queries=count,
            samples=samples,
            replicates=replicates,
        ).reshape(count * samples, 3)
        cols = [Float(np.ascontiguousarray(pts[:, d])) for d in range(3)]
    sl = slice(first, first + count)
    owner = (lane * per_lane) // samples
    centre_tab = [
        Float(np.ascontiguousarray(queries.centre[sl, d], dtype=np.float32)) for d in range(2)
    ]
    size_tab = Float(np.ascontiguousarray(queries.size[sl], dtype=np.float32))
    wi_tab = [Float(np.ascontiguousarray(queries.wi[sl, d], dtype=np.float32)) for d in range(3)]
    wo_tab = [Float(np.ascontiguousarray(queries.wo[sl, d], dtype=np.float32)) for d in range(3)]

    def per_query(a: Array) -> Array:
        return dr.gather(Float, a, owner)

    centre = (per_query(centre_tab[0]), per_query(centre_tab[1]))
    size = per_query(size_tab)
    wi = (per_query(wi_tab[0]), per_query(wi_tab[1]), per_query(wi_tab[2]))
    wo = (per_query(wo_tab[0]), per_query(wo_tab[1]), per_query(wo_tab[2]))
    points = []
    for r in range(per_lane):
        g = lane * per_lane + r  # the sample's global index: query owner, sample k
        if settings.sampler == "sobol":
            k = g - owner * samples  # = replicate * block + i
            slot = owner * replicates + k // block
            u = []
            for d in range(3):
                bits = dr.gather(UInt32, net[d], k) ^ dr.gather(UInt32, shift[d], slot)
                u.append((Float(bits >> 8) + 0.5) * (2.0**-24))  # = samplers.bits_to_unit
        else:
            u = [dr.gather(Float, c, g) for c in cols]
        s, t = footprint_positions(ops, centre, size, u[0], u[1], settings.kernel)
        points.append(SamplePoint(s, t, wi, wo, u[2]))
    batch = sample_terms_batch(
        ops,
        params,
        geo,
        tab,
        points,
        with_visibility=settings.with_visibility,
        march_step=settings.march_step,
        march_max_steps=settings.march_max_steps,
        march=settings.march,
    )
    products: list[Array] = [Float64(0.0)] * 15
    for terms in batch:
        comps = [Float64(x) for x in terms[:4]]
        area = Float64(terms.area)
        area_in = Float64(terms.area_in)
        one = (
            *comps,
            area,
            area_in,
            *(c * c for c in comps),
            *(c * area for c in comps),
            area * area,
        )
        products = [a + b for a, b in zip(products, one, strict=True)]
    # Symbolic block sums: the integrand and the reductions fuse into one kernel whose
    # lanes atomically add (in float64) into the per-replicate moments.
    outs = dr.block_sum(tuple(products), block // per_lane, mode="symbolic")
    dr.eval(outs)
    moments = np.stack([o.numpy() for o in outs], axis=1)
    return moments.reshape(count, replicates, len(outs))
