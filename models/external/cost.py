"""The cost of a user's model, measured by matforge the same way as the built-in models'.

An external model (:class:`ExternalModel`: an exported MLP or an ONNX graph that is an MLP,
evaluated by a fused Dr.Jit kernel, or any other ONNX file, evaluated by onnxruntime) is
timed on the same fixed batch as a
``train.brdf`` model's ``speed.json``: :data:`COST_BATCH` cosine-weighted direction pairs
from :func:`models.speed.cosine_pairs` (seed 0; a BTF also gets uniform ``uv`` in the unit
square from the same seed), the median of :data:`COST_REPEATS` runs after one warm-up run.

- ``drjit-fused`` models (MLP materials and recognised ONNX graphs, traced by
  :func:`models.external.fused.fused_of`, the kernel the renderer runs):
  :func:`models.speed.time_fused`, the kernel's own execution time from Dr.Jit's kernel
  history -- exactly the ``fused_kernel_ns`` that is a ``train.brdf`` row's ``ns_per_eval``;
- any other runtime (``onnxruntime``): the wall time of ``eval`` on the numpy batch, which
  is what the renderer pays per bounce for that runtime (:func:`models.speed.time_call`).

``ns_per_eval`` = that time / batch. Bytes, float32 counted as 4, by one rule for every
model, a user's or a built-in one (:func:`model_bytes`): ``bytes_total`` is everything needed
to render it (networks, latent textures, analytic parameters); a BTF's ``bytes_per_material``
is its latent textures (the per-material part) and ``bytes_per_network`` the rest (the
networks' weights and biases), as ``train.btf``'s ``storage`` counts them; a BRDF's
``bytes_per_network`` is all of its parameters (one file is one material and its network).
An ONNX graph does not say which initialisers are textures, so an ONNX model's
``bytes_per_network`` is all of its floating-point initialisers (= ``bytes_total``) and its
``bytes_per_material`` is not given.
Beside the time, the counts that do not depend on the machine (:mod:`models.counts`):
``macs_per_eval`` (multiply-adds of the dense layers per evaluation) and ``bytes_per_eval``
(bytes one evaluation reads), from the JSON document's layers and textures, or from an ONNX
graph's nodes and inferred shapes (:func:`models.external.onnx_mlp.graph_counts`); a
built-in BTF's from its ``model.json`` (:func:`models.btf.counts.btf_counts`).
The document (the measurement ``cost`` in a ``score`` job's manifest, :data:`COST_FORMAT`:
not an artifact, since timings vary; typed, :class:`CostDocument` of :class:`CostRecord`,
and checked when the score records it) names the ``runtime``
and the ``method``, so a chart never mixes two runtimes' costs unawares. Timings vary from
run to run.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from typing_extensions import TypedDict

from jobapi.documents import document

#: Pairs per measurement: ``train.brdf``'s default ``speed_batch`` (2^18).
COST_BATCH = 1 << 18
#: Runs per median (``train.brdf``'s ``SPEED_REPEATS``).
COST_REPEATS = 5
#: The seed of the batch (:func:`models.speed.cosine_pairs`).
COST_SEED = 0
if TYPE_CHECKING:
    from models.external import ExternalModel

#: The version tag of a cost document.
COST_FORMAT = "matforge.cost/1"


@document
class CostRecord(TypedDict):
    """One model's cost (:func:`measure_cost`, :func:`measure_builtin_btf`)."""

    format: str
    """``matforge.cost/1``."""
    ns_per_eval: float
    """ns per evaluation on the fixed batch, in ``runtime``."""
    runtime: str
    """What evaluated it: ``drjit-fused`` or ``onnxruntime``."""
    bytes_total: int | None
    """float32 bytes of everything needed to render it."""
    bytes_per_network: int | None
    """float32 bytes of the networks' weights and biases."""
    bytes_per_material: int | None
    """float32 bytes of the latent textures (``null``: not split)."""
    macs_per_eval: int | None
    """Multiply-adds of the dense layers per evaluation (:mod:`models.counts`)."""
    bytes_per_eval: int | None
    """Bytes one evaluation reads (:mod:`models.counts`)."""
    method: str
    """How the time was measured."""
    batch: int
    """Pairs in the batch."""
    repeats: int
    """Runs per median."""


@document
class CostDocument(TypedDict):
    """The ``cost`` measurement of a ``score`` job: every timed candidate's record."""

    format: str
    """``matforge.cost/1``."""
    candidates: dict[str, CostRecord]
    """``{label: record}``."""


#: The runtime whose time is the fused kernel's.
FUSED = "drjit-fused"


def cost_batch(
    kind: str, batch: int = COST_BATCH
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """The fixed batch ``(wi, wo, uv)``: float32, ``uv`` ``None`` for a BRDF."""
    from models.speed import cosine_pairs

    wi, wo = cosine_pairs(batch, COST_SEED)
    uv = None
    if kind == "btf":
        uv = np.random.default_rng(COST_SEED).random((batch, 2)).astype(np.float32)
    return wi, wo, uv


def measure_cost(
    model: ExternalModel, *, batch: int = COST_BATCH, repeats: int = COST_REPEATS
) -> dict[str, Any]:
    """``{"ns_per_eval", "runtime", "bytes_per_network", "macs_per_eval", "bytes_per_eval",
    "method", "batch", "repeats"}`` of ``model`` (see the module docstring). ``ValueError``
    for a ``drjit-fused`` model without a fused kernel, or for no Mitsuba LLVM variant to
    run it in."""
    from models.speed import time_call

    wi, wo, uv = cost_batch(model.kind, batch)
    runtime = str(model.runtime)
    if runtime == FUSED:
        from models.external.fused import fused_of

        seconds = fused_seconds(
            lambda mi: fused_of(model, mi).eval, model.kind, batch, repeats, uv_first=False
        )
        method = FUSED_METHOD
    else:
        seconds = time_call(lambda: model.eval(wi, wo, uv), repeats)
        method = f"wall time of one {runtime} evaluation of the batch, median"
    return {
        "format": COST_FORMAT,
        "ns_per_eval": round(seconds / batch * 1e9, 3),
        "runtime": runtime,
        **model_bytes(model),
        "macs_per_eval": getattr(model, "macs_per_eval", None),
        "bytes_per_eval": getattr(model, "bytes_per_eval", None),
        "method": method,
        "batch": batch,
        "repeats": repeats,
    }


def model_bytes(model: ExternalModel) -> dict[str, int | None]:
    """``{"bytes_total", "bytes_per_network", "bytes_per_material"}`` of a user's model by
    the rule of the module docstring."""
    total = int(model.param_bytes)
    textures = getattr(model, "texture_bytes", None)
    if model.kind != "btf" or textures is None:  # a BRDF, or ONNX: no split
        return {"bytes_total": total, "bytes_per_network": total, "bytes_per_material": None}
    return {"bytes_total": total, "bytes_per_network": total - int(textures),
            "bytes_per_material": int(textures)}  # fmt: skip


#: How a fused kernel is timed.
FUSED_METHOD = "fused Dr.Jit kernel execution (kernel history), median"


def fused_seconds(make: Any, kind: str, batch: int, repeats: int, *, uv_first: bool) -> float:
    """Median kernel seconds of ``make(mi)(...)`` on the fixed batch: ``(wi, wo[, uv])``, or
    ``(uv, wi, wo)`` with ``uv_first`` (the built-in BTF's :meth:`FusedBtf.eval`)."""
    from materials.backend import load_mitsuba
    from models.speed import time_fused

    mi = load_mitsuba()
    if not mi.variant().startswith(("llvm_", "cuda_")):
        raise ValueError(
            f"timing the fused kernel needs a vectorised Mitsuba variant (LLVM or CUDA), "
            f"not {mi.variant()}"
        )
    import drjit as dr

    wi, wo, uv = cost_batch(kind, batch)
    wi_d, wo_d = mi.Vector3f(*wi.T), mi.Vector3f(*wo.T)
    uv_d = None if uv is None else mi.Point2f(*uv.T)
    dr.eval(wi_d, wo_d, uv_d)
    fn = make(mi)
    if uv_first:
        timed = time_fused(lambda: [fn(uv_d, wi_d, wo_d)], repeats)
    else:
        timed = time_fused(lambda: [fn(wi_d, wo_d, uv_d)], repeats)
    return float(timed["kernel_s"])


def measure_builtin_btf(
    model: Any, *, batch: int = COST_BATCH, repeats: int = COST_REPEATS
) -> dict[str, Any]:
    """The cost document of a ``train.btf`` model (:class:`models.btf.portable.PortableBtf`)
    on the same batch as :func:`measure_cost`: its fused kernel
    (:meth:`models.btf.fused.FusedBtf.eval`, what ``btf_model`` renders with); bytes by the
    rule of the module docstring, from ``storage`` of its model.json: per material its
    textures', per network every network's weights and biases, in all both."""
    from models.btf.fused import FusedBtf

    seconds = fused_seconds(lambda mi: FusedBtf(model, mi).eval, "btf", batch, repeats,
                            uv_first=True)  # fmt: skip
    from models.btf.counts import btf_counts

    storage = model.doc.get("storage") or {}
    return {
        "format": COST_FORMAT,
        "ns_per_eval": round(seconds / batch * 1e9, 3),
        "runtime": FUSED,
        "bytes_total": storage.get("total_bytes"),
        "bytes_per_material": storage.get("texture_bytes"),
        "bytes_per_network": storage.get("network_bytes"),
        **btf_counts(model.doc),
        "method": FUSED_METHOD,
        "batch": batch,
        "repeats": repeats,
    }
