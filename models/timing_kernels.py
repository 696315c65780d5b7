"""The kernels of a timing pass (:mod:`models.timing`) for models queried at direction
pairs: built-in BRDF models (``matforge.brdf-model/1``), built-in BTF models, users' models
(MLP files through the fused kernel, ONNX through onnxruntime) and the reference kernel,
Mitsuba's native ``roughconductor`` evaluated at the same pairs.

The batch (:func:`query_batch`) is :func:`models.external.cost.cost_batch`'s: cosine
weighted pairs ``(wi, wo)`` from a fixed seed, and uniform ``uv`` in the unit square for a
BTF. It is made once per pass, as numpy arrays and as Dr.Jit arrays of the Mitsuba variant,
and every kernel evaluates all of it per call. Dr.Jit kernels are traced, launched and
waited for in the timed call (:func:`drjit_sync`), what a renderer pays per evaluation of
the batch; an onnxruntime model's call returns finished results. The same code runs under a
CUDA variant (``dr.sync_thread`` waits for the device there).

Every Dr.Jit kernel is frozen (``dr.freeze``): the first call (a warm-up round) traces and
compiles it, later calls replay the recorded kernel on the batch without tracing the Python
code again. So a timed call is the kernel's launch and execution, what a renderer pays per
evaluation once the frame's kernel is traced: tracing a network with its weights as
literals costs milliseconds of single-threaded Python that a frame pays once, and under
load it would dominate a call and swing with the load. A frozen function sees only its
inputs, so the Dr.Jit arrays a model object holds (latent textures) are passed in as one
more input (:func:`frozen`'s ``state``).
"""

from __future__ import annotations

import types
from dataclasses import dataclass
from typing import Any

import numpy as np

from models.timing import Kernel

#: The reference kernel's BSDF: Mitsuba's rough conductor (GGX, aluminium by default).
REFERENCE_BSDF: dict[str, Any] = {"type": "roughconductor", "distribution": "ggx", "alpha": 0.2}
#: The reference kernel's name in a pass.
REFERENCE = "reference"


@dataclass(frozen=True)
class QueryBatch:
    """One pass's queries: ``(N, 3)`` float32 ``wi``, ``wo`` (local frame, z up) and ``(N,
    2)`` ``uv`` (for BTFs), as numpy arrays and as the variant's Dr.Jit arrays."""

    mi: types.ModuleType
    wi: np.ndarray
    wo: np.ndarray
    uv: np.ndarray
    wi_d: Any
    wo_d: Any
    uv_d: Any

    @property
    def size(self) -> int:
        return len(self.wi)


def query_batch(mi: types.ModuleType, batch: int, seed: int = 0) -> QueryBatch:
    """The pass's batch of ``batch`` pairs (see the module docstring). ``ValueError`` for a
    scalar Mitsuba variant (a fused kernel needs LLVM or CUDA)."""
    import drjit as dr

    from models.external.cost import COST_SEED, cost_batch

    if not mi.variant().startswith(("llvm_", "cuda_")):
        raise ValueError(
            f"a timing pass needs a vectorised Mitsuba variant (LLVM or CUDA), not {mi.variant()}"
        )
    wi, wo, _ = cost_batch("brdf", batch)
    if seed != COST_SEED:
        from models.speed import cosine_pairs

        wi, wo = cosine_pairs(batch, seed)
    uv = np.random.default_rng(seed).random((batch, 2)).astype(np.float32)
    wi_d, wo_d, uv_d = mi.Vector3f(*wi.T), mi.Vector3f(*wo.T), mi.Point2f(*uv.T)
    dr.eval(wi_d, wo_d, uv_d)
    dr.sync_thread()
    return QueryBatch(mi, wi, wo, uv, wi_d, wo_d, uv_d)


def drjit_sync(out: Any) -> None:
    """Evaluate ``out`` (when given) and wait for every queued Dr.Jit kernel."""
    import drjit as dr

    if out is not None:
        dr.eval(out)
    dr.sync_thread()


def _holds_arrays(value: Any) -> bool:
    """Whether ``value`` is or holds (in lists, tuples, dicts, dataclasses: what
    ``dr.freeze`` traverses) a Dr.Jit array."""
    import dataclasses

    import drjit as dr

    if isinstance(value, (list, tuple)):
        return any(_holds_arrays(v) for v in value)
    if isinstance(value, dict):
        return any(_holds_arrays(v) for v in value.values())
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return any(_holds_arrays(getattr(value, f.name)) for f in dataclasses.fields(value))
    return bool(dr.is_array_v(value))


def frozen(fn: Any, *args: Any, state: Any = None) -> Any:
    """``fn(*args)`` as a call of no arguments that replays a frozen Dr.Jit kernel
    (``dr.freeze``, see the module docstring); ``args`` are the batch's arrays.

    ``state``: an object whose attributes hold Dr.Jit arrays that ``fn`` reads (a model's
    textures): a frozen function sees only its inputs, so those attributes are passed in
    as one more input and set back on the object inside the recorded call."""
    import drjit as dr

    if state is None:
        replay = dr.freeze(fn)
        return lambda: replay(*args)
    held = {k: v for k, v in vars(state).items() if _holds_arrays(v)}

    def with_state(inputs: dict[str, Any], *xs: Any) -> Any:
        for k, v in inputs.items():
            setattr(state, k, v)
        return fn(*xs)

    replay_state = dr.freeze(with_state)
    return lambda: replay_state(held, *args)


def reference_kernel(q: QueryBatch, bsdf: dict[str, Any] | None = None) -> Kernel:
    """Mitsuba's native ``roughconductor`` (``bsdf``: default :data:`REFERENCE_BSDF`)
    evaluated (``BSDF.eval``, value times cosine) at every pair of the batch."""
    import drjit as dr

    mi = q.mi
    plugin = mi.load_dict(dict(bsdf or REFERENCE_BSDF))
    ctx = mi.BSDFContext()

    def run(wi: Any, wo: Any) -> Any:
        si = dr.zeros(mi.SurfaceInteraction3f, dr.width(wi))
        si.n = mi.Normal3f(0, 0, 1)
        si.sh_frame = mi.Frame3f(si.n)
        si.wi = wi
        return plugin.eval(ctx, si, wo)

    return Kernel(REFERENCE, frozen(run, q.wi_d, q.wo_d), q.size, "mitsuba", drjit_sync)


def builtin_brdf_kernel(name: str, q: QueryBatch, doc: dict[str, Any], material: str) -> Kernel:
    """A ``matforge.brdf-model/1`` document's ``material`` through the fused kernel the
    renderer runs (:func:`models.brdf.fused.model_brdf`, weights baked as literals)."""
    from models.brdf.fused import bake_material, model_brdf

    baked = bake_material(doc, material)
    run = frozen(lambda wi, wo: model_brdf(q.mi, baked, wi, wo), q.wi_d, q.wo_d)
    return Kernel(name, run, q.size, "drjit-fused", drjit_sync)


def builtin_btf_kernel(name: str, q: QueryBatch, model: Any) -> Kernel:
    """A ``train.btf`` model (:class:`models.btf.portable.PortableBtf`) through its fused
    kernel (:meth:`models.btf.fused.FusedBtf.eval`)."""
    from models.btf.fused import FusedBtf

    fused = FusedBtf(model, q.mi)
    run = frozen(fused.eval, q.uv_d, q.wi_d, q.wo_d, state=fused)
    return Kernel(name, run, q.size, "drjit-fused", drjit_sync)


def external_kernel(name: str, q: QueryBatch, model: Any) -> Kernel:
    """A user's model (:class:`models.external.ExternalModel`) in its own runtime: an MLP
    material through its fused kernel (:class:`models.external.fused.FusedMlp`), anything
    else through its ``eval`` on the numpy batch."""
    runtime = str(model.runtime)
    uv = q.uv if model.kind == "btf" else None
    if runtime == "drjit-fused":
        from models.external.fused import FusedMlp

        fused = FusedMlp(model, q.mi)
        if model.kind == "btf":
            run = frozen(fused.eval, q.wi_d, q.wo_d, q.uv_d, state=fused)
        else:
            run = frozen(fused.eval, q.wi_d, q.wo_d, state=fused)
        return Kernel(name, run, q.size, runtime, drjit_sync)
    return Kernel(name, lambda: model.eval(q.wi, q.wo, uv), q.size, runtime)


def runtime_versions(mi: types.ModuleType) -> dict[str, str]:
    """Versions of the runtimes a pass may use, and the Mitsuba variant."""
    import drjit as dr

    out = {
        "mitsuba": str(getattr(mi, "__version__", "unknown")),
        "mitsuba_variant": str(mi.variant()),
        "drjit": str(getattr(dr, "__version__", "unknown")),
    }
    try:
        import onnxruntime

        out["onnxruntime"] = str(onnxruntime.__version__)
    except ImportError:
        pass
    return out
