"""The timing pass of a comparison: ``report.pareto`` and ``select`` re-time every model they
rank by ``ns_per_eval`` in one pass of their own (:func:`models.timing.timing_pass`), with
the reference kernel (Mitsuba's ``roughconductor`` on the same batch) interleaved.

A cost measured while training (``train.brdf``'s ``speed``) or while scoring (a ``score``
job's ``cost``) stays a diagnostic of that job: taken at another moment, under another
load, it is not comparable with the next job's. Here every candidate's model is found from
its result rows (:func:`target_of`), loaded once, and timed with the others:

- a training row's ``config.model_file`` (``train.brdf``: its job's ``model.json``; first
  material, since the cost of a material does not depend on its weights' values);
- a score row of a model candidate (``config.model``, ``config.material``): that model
  (a BRDF model, or a BTF model with its ``textures.npz``, by the document's format); of a
  user's model (``config.external``): the uploaded file, in its own runtime;
- a ``select`` scene-mode row: its rung's material, when it is one of these.

A candidate with an ``ns_per_eval`` of its own that cannot be re-timed here (a model kind
this pass does not know) is refused (:class:`jobapi.errors.JobFailed`, naming it): a chart
never mixes costs from two passes. The candidates of one name that differ in model (seeds)
are timed by their first run's model.
"""

from __future__ import annotations

import json
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, cast

from pydantic import Field

from jobapi.errors import JobFailed
from jobapi.params import StrictModel

if TYPE_CHECKING:
    from jobapi.context import JobContext
    from jobapi.documents import TimingDocument
    from jobapi.rows import ResultRow

#: The costs a pass re-measures.
PASS_COSTS = ("ns_per_eval",)
#: The machine-independent counts a row may carry beside its time.
COUNTS = ("macs_per_eval", "bytes_per_eval")
#: The trained models' document formats a pass times.
BRDF_MODEL, BTF_MODEL = "matforge.brdf-model/1", "matforge.btf-model/1"
#: Timed costs taken by the jobs themselves (not re-measured): ranked only within one job.
JOB_TIMED_COSTS = ("render_seconds", "train_seconds", "ms_per_frame")


class TimingParams(StrictModel):
    """How a comparison's timing pass runs (``timing`` of ``report.pareto`` and ``select``).

    =================  =====  =======  ================================================
    name               type   default  meaning
    =================  =====  =======  ================================================
    ``repeats``        int    5        recorded rounds per kernel, 5..200
    ``warmup``         int    2        unrecorded rounds first, 0..10
    ``batch``          int    2^20     direction pairs per evaluation call, 2^10..2^22
    ``threads``        int    2        CPU threads of Dr.Jit and torch, 1..256
    ``min_sample_ms``  float  50       a sample repeats the kernel's call (each
                                       synchronised) until it takes this long by the
                                       warm-up's time, 0..5000
    =================  =====  =======  ================================================
    """

    repeats: int = Field(default=5, ge=5, le=200, description="Recorded rounds per kernel.")
    warmup: int = Field(default=2, ge=0, le=10, description="Unrecorded rounds before them.")
    batch: int = Field(
        default=1 << 20, ge=1 << 10, le=1 << 22, description="Direction pairs per call."
    )
    threads: int = Field(default=2, ge=1, le=256, description="Dr.Jit and torch threads.")
    min_sample_ms: float = Field(
        default=50.0,
        ge=0.0,
        le=5000.0,
        allow_inf_nan=False,
        description="Each sample repeats a kernel's call until it takes this long (by the "
        "warm-up's time); 0: one call.",
    )


@dataclass(frozen=True)
class Target:
    """A model to time: ``what`` is ``model`` (``ref`` a trained model's ``model.json``,
    ``matforge.brdf-model/1`` or ``matforge.btf-model/1`` by its ``format``; ``material``
    one of a BRDF model's materials, ``None`` for the first) or ``external`` (``ref`` a
    user's file, ``kind`` ``brdf`` or ``btf``)."""

    what: str
    ref: str
    material: str | None = None
    kind: str = "brdf"
    counts: tuple[tuple[str, float], ...] = ()
    """The rows' machine-independent counts (``macs_per_eval``, ``bytes_per_eval``), carried
    into the pass's cost record beside the time."""


def material_target(value: Any) -> Target | None:
    """The target of a material value (``{"model", "material"}`` or ``{"external"}``)."""
    if not isinstance(value, Mapping):
        return None
    ext = value.get("external")
    if isinstance(ext, Mapping) and isinstance(ext.get("model"), str):
        return Target("external", str(ext["model"]), kind=str(ext.get("kind") or "brdf"))
    ref = value.get("model_file", value.get("model"))
    if not isinstance(ref, str) or not ref.startswith(("job:", "sha256:")):
        return None  # e.g. a training row's model type ("hybrid"), not a file
    material = value.get("material")
    return Target("model", ref, material if isinstance(material, str) else None)


def target_of(row: ResultRow) -> Target | None:
    """The model behind ``row``'s candidate (see the module docstring), or ``None``: its
    ``config``'s ``model_file`` (a training job's own model), ``external`` (a user's
    file), ``model`` and ``material`` (a score's model candidate), or a select rung's
    ``material`` holding one of these."""
    cfg = row.config or {}
    return material_target(cfg) or material_target(cfg.get("material"))


def pass_targets(rows: Sequence[ResultRow], cost: str) -> dict[str, Target]:
    """Per candidate of ``rows`` with a model to time (:func:`target_of`, its first row's),
    that model, whether or not its own job timed it; :class:`JobFailed` naming the
    candidates that carry a ``cost`` but have no model to re-time."""
    targets: dict[str, Target] = {}
    untimed: list[str] = []
    for r in rows:
        if r.candidate is None or r.candidate in targets:
            continue
        t = target_of(r)
        if t is not None:
            counts = tuple((k, float(v)) for k in COUNTS if (v := getattr(r, k, None)) is not None)
            targets[r.candidate] = replace(t, counts=counts)
        elif getattr(r, cost) is not None and r.candidate not in untimed:
            untimed.append(r.candidate)
    untimed = [c for c in untimed if c not in targets]
    if untimed:
        raise JobFailed(
            f"costs: {cost} of {', '.join(sorted(untimed))} cannot be re-timed in this job's "
            "timing pass (no model to evaluate), and costs from different passes are not "
            f"compared: leave {cost} out of costs, or compare models only"
        )
    return targets


def _kernel(name: str, target: Target, q: Any, ctx: JobContext) -> Any:
    from models import timing_kernels as tk

    try:
        if target.what == "model":
            doc = json.loads(ctx.read_ref(target.ref))
            fmt = doc.get("format") if isinstance(doc, dict) else None
            if fmt == BRDF_MODEL:
                material = target.material or str(doc["materials"][0]["name"])
                return tk.builtin_brdf_kernel(name, q, doc, material)
            if fmt == BTF_MODEL:
                from models.btf.portable import read_model, read_textures

                textures_ref = target.ref.rsplit("/", 1)[0] + "/textures.npz"
                model = read_model(doc, read_textures(ctx.read_ref(textures_ref)))
                return tk.builtin_btf_kernel(name, q, model)
            raise ValueError(f"not a {BRDF_MODEL} or {BTF_MODEL} document: {fmt!r}")
        from models.external import load_external

        return tk.external_kernel(name, q, load_external(ctx.resolve(target.ref), target.kind))
    except (ValueError, KeyError, OSError) as exc:
        raise JobFailed(f"timing pass: candidate {name!r} ({target.ref}): {exc}") from None


def comparison_pass(
    targets: Mapping[str, Target], timing: TimingParams, ctx: JobContext
) -> dict[str, Any]:
    """The ``matforge.timing/1`` record of ``targets`` (candidate -> model) and the
    reference kernel, timed in one interleaved pass with ``timing``'s settings."""
    from materials.backend import load_mitsuba, runs_on_cpu_jit
    from models import timing_kernels as tk
    from models.timing import fixed_threads, timing_pass

    mi = load_mitsuba()
    if tk.REFERENCE in targets:
        raise JobFailed(f"timing pass: {tk.REFERENCE!r} is the reference kernel's name")
    try:
        with fixed_threads(timing.threads):
            q = tk.query_batch(mi, timing.batch)
            kernels = [tk.reference_kernel(q)]
            kernels += [
                replace(_kernel(n, t, q, ctx), counts=dict(t.counts)) for n, t in targets.items()
            ]
            ctx.check_cancelled()
            on_cpu = runs_on_cpu_jit(mi)
            record = timing_pass(
                kernels,
                reference=tk.REFERENCE,
                repeats=timing.repeats,
                warmup=timing.warmup,
                threads=timing.threads,
                clock=time.process_time if on_cpu else time.perf_counter,
                clock_name="cpu" if on_cpu else "wall",
                per=timing.threads if on_cpu else 1,
                min_sample_s=timing.min_sample_ms / 1000.0,
                runtimes=tk.runtime_versions(mi),
                settings={
                    "batch": timing.batch,
                    "seed": 0,
                    "queries": "cosine-weighted (wi, wo) pairs, uniform uv",
                    "reference_bsdf": tk.REFERENCE_BSDF,
                },
            )
    except ValueError as exc:
        raise JobFailed(f"timing pass: {exc}") from None
    record["targets"] = {
        n: {"what": t.what, "ref": t.ref, "material": t.material} for n, t in targets.items()
    }
    return record


def pass_cost(record: Mapping[str, Any], candidate: str) -> dict[str, Any] | None:
    """A point's cost fields from the pass ``record``: ``cost`` (median ns per
    evaluation), ``cost_min``, ``cost_max``, ``cost_iqr``, ``cost_n``, ``relative`` (the
    ratio to the reference: ``{"median", "min", "max", "iqr", "n"}``), ``runtime``."""
    entry = (record.get("costs") or {}).get(candidate)
    if entry is None:
        return None
    d = entry["distribution"]
    rel = entry.get("relative")
    return {
        "cost": d["median"],
        "cost_min": d["min"],
        "cost_max": d["max"],
        "cost_iqr": d["iqr"],
        "cost_n": d["n"],
        "relative": None
        if rel is None
        else {k: rel[k] for k in ("median", "min", "max", "iqr", "n")},
        "runtime": entry["runtime"],
        "macs_per_eval": entry.get("macs_per_eval"),
        "bytes_per_eval": entry.get("bytes_per_eval"),
    }


def timing_summary(record: Mapping[str, Any]) -> TimingDocument:
    """The pass as a document records it: everything but the per-round order and the
    targets' details (kept: machine, settings, repeats, costs with their distributions)."""
    keep = ("format", "reference", "repeats", "warmup", "clock", "machine", "settings", "method")
    out = {k: record[k] for k in keep if k in record}
    out["costs"] = dict(record.get("costs") or {})
    out["order"] = list(record.get("order") or [])
    return cast("TimingDocument", out)
