"""Result rows: every value a job measured, one row each, in long ("tidy") format.

A kind's *rows hook* (:attr:`jobapi.kinds.Kind.rows`) turns its finished job's artifacts
into :class:`ResultRow` records; ``GET /api/results`` and ``matforge results`` serve them
as JSON or CSV without knowing any kind's fields. One row holds one value of one metric,
with what it measured (dataset, scene, candidate, material), how (``config``), whether
lower is better, the seed, and what it cost.

A metric's name says its space where it is measured in more than one (``brdf.mae``,
``image.mae``: :mod:`jobapi.metric_names`), so that a column holds one unit. ``split``
says whether a value is over the data the model was fitted to (``train``) or over data it
never saw (``test``: held-out materials, betas or patterns); ``None`` for a value that is
neither (a render, a score of images). Tables and charts label the two, and headline the
test error where there is one.

Costs: one name per meaning, the same name wherever it is shown or drawn.

==========================  ==================================================================
column                      meaning
==========================  ==================================================================
``ns_per_eval``             ns per evaluation of the model on a fixed batch, in its runtime:
                            fused Dr.Jit kernel execution for built-in and exported MLP
                            models (``speed.json``'s ``fused_kernel_ns``: what a renderer
                            pays once the kernel is traced; tracing and launch overhead is
                            the separate metric ``fused_ns``, eager torch ``torch_ns``),
                            onnxruntime's session run for ONNX models
                            (:mod:`models.external_cost`)
``runtime``                 what evaluates the model, so that costs from two runtimes are
                            never compared unawares: ``drjit-fused`` (a fused Dr.Jit kernel:
                            train.brdf, train.btf, exported MLPs), ``onnxruntime`` (an
                            uploaded ONNX model), ``mitsuba`` (a table or a Mitsuba plugin)
``ms_per_frame``            milliseconds per displayed frame (``evaluate.tss``: shading
                            kernel / (N + 1) + lookup kernel)
``bytes_per_material``      float32 bytes of one material's own parameters or textures
                            (a glint material: the tiny example's NDF maps and lobes, the
                            Yan et al. export's lobes, or a smooth GGX's two roughnesses)
``bytes_per_network``       float32 bytes of the shared network weights
``train_seconds``           wall seconds of the training job (fit, evaluation and timing)
``spp``                     samples per pixel of the render that was scored
``render_seconds``          seconds of that render's passes, without JIT compilation (its own
                            measurement; older renders: the job's wall time)
``macs_per_eval``           multiply-adds of the model's dense layers per evaluation, as its
                            kernel runs them (:mod:`models.counts`): the same on every
                            machine; 0 for a model without a network (analytic, a table)
``bytes_per_eval``          bytes one evaluation reads (:mod:`models.counts`): every weight
                            and bias, analytic parameters, and of a latent texture or a
                            table what one lookup reads
==========================  ==================================================================
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import asdict, dataclass, field, replace
from typing import Any, Protocol

from jobapi.metric_names import SPACED

#: The identity and what-was-measured columns, in order.
KEY_COLUMNS = (
    "job",
    "step",
    "kind",
    "dataset",
    "scene",
    "candidate",
    "material",
    "family",
    "split",
    "config",
    "metric",
    "value",
    "lower_is_better",
    "seed",
)
#: The cost columns (see the module docstring), in order.
COST_COLUMNS = (
    "ns_per_eval",
    "runtime",
    "ms_per_frame",
    "bytes_per_material",
    "bytes_per_network",
    "train_seconds",
    "spp",
    "render_seconds",
    "macs_per_eval",
    "bytes_per_eval",
)
#: The columns that are timings (costs or metrics): each is measured by the job that
#: reports it, at its own moment and load, so values from different jobs are shown but
#: never ranked against each other (a comparison's own timing pass ranks ``ns_per_eval``:
#: ``report.pareto``, ``select``).
TIMED_COLUMNS = frozenset({
    "ns_per_eval", "ms_per_frame", "train_seconds", "render_seconds", "fused_kernel_ns",
    "fused_ns", "torch_ns", "seconds_per_frame", "seconds", "samples_per_second",
    "precompute_seconds",
})  # fmt: skip

#: The ``split`` names (see the module docstring).
SPLITS = ("train", "test")
#: The ``runtime`` names (see the module docstring).
RUNTIMES = ("drjit-fused", "onnxruntime", "mitsuba")
#: Every column of a row, in the order of a CSV file.
COLUMNS = KEY_COLUMNS + COST_COLUMNS

#: Whether lower values are better, per metric name (``None`` for a metric not listed:
#: a measured quantity without a better direction, e.g. an image's mean).
LOWER_IS_BETTER: dict[str, bool] = {
    "flip": True,
    "flip_mean": True,
    "flip_max": True,
    "psnr": False,
    "psnr_mean": False,
    "psnr_min": False,
    "ssim": False,
    "mae": True,
    "mse": True,
    "smape": True,
    "smape_analytic": True,
    "smape_floor": True,
    "smape_floor_analytic": True,
    "mae_analytic": True,
    "l1": True,
    "l1_train": True,
    "l1_heldout": True,
    "relative_l1": True,
    "loss": True,
    "rgb.rel": True,
    "rgb.mse": True,
    "fused_kernel_ns": True,
    "fused_ns": True,
    "torch_ns": True,
    "relative_cost": True,
    "seconds_per_frame": True,
    "render_seconds": True,
    "seconds": True,
    "samples_per_second": False,
    "bytes": True,
    "memory_ratio": True,
    "precompute_seconds": True,
    "stderr_mean": True,
    "stderr_relative": True,
}


def lower_is_better(metric: str) -> bool | None:
    """Whether a lower ``metric`` is better (suffixes ``.rel``/``.mse``/``_rel`` count as
    errors; a space's name, ``image.psnr``, as its bare one); ``None`` when it has no
    better direction."""
    if metric in LOWER_IS_BETTER:
        return LOWER_IS_BETTER[metric]
    space, _, bare = metric.partition(".")
    if space in SPACED and bare in SPACED[space]:
        return LOWER_IS_BETTER.get(bare)
    if metric.endswith((".rel", ".mse", ".loss", "_rel", "_mse", "_error")):
        return True
    return None


@dataclass(frozen=True)
class ResultRow:
    """One measured value (see the module docstring for the cost columns)."""

    job: str
    kind: str
    metric: str
    value: float
    lower_is_better: bool | None = None
    step: str | None = None
    dataset: str | None = None
    scene: str | None = None
    candidate: str | None = None
    material: str | None = None
    family: str | None = None
    split: str | None = None
    config: Mapping[str, Any] = field(default_factory=dict)
    seed: int | None = None
    ns_per_eval: float | None = None
    runtime: str | None = None
    ms_per_frame: float | None = None
    bytes_per_material: float | None = None
    bytes_per_network: float | None = None
    train_seconds: float | None = None
    spp: int | None = None
    render_seconds: float | None = None
    macs_per_eval: float | None = None
    bytes_per_eval: float | None = None

    def document(self) -> dict[str, Any]:
        """The JSON form: every column of :data:`COLUMNS`, in order."""
        doc = asdict(self)
        doc["config"] = dict(self.config)
        return {c: doc[c] for c in COLUMNS}

    def csv_cells(self) -> dict[str, str]:
        """The CSV form: ``config`` as compact JSON, missing values as empty cells."""
        out: dict[str, str] = {}
        for col, value in self.document().items():
            if value is None:
                out[col] = ""
            elif col == "config":
                out[col] = json.dumps(value, sort_keys=True, separators=(",", ":"))
            else:
                out[col] = str(value)
        return out

    def with_(self, **changes: Any) -> ResultRow:
        """A copy with ``changes`` applied."""
        return replace(self, **changes)


def number(value: Any) -> float | None:
    """``value`` as a finite float, or ``None`` (bools, text, NaN and infinities are not
    measurements)."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    v = float(value)
    return v if math.isfinite(v) else None


@dataclass(frozen=True)
class JobFacts:
    """What a rows hook knows of a job besides its artifacts.

    Attributes:
        id: the job id (32 hex digits).
        kind: its kind.
        seed: the spec's seed.
        params: the spec's params as stored (defaults filled in).
        name: the spec's label, if any.
        run_seconds: wall seconds the job ran (``None`` if unknown).
        measured: the timings the kind measured itself (``JobContext.measure``), from the
            job's manifest: seconds (``render_seconds``) or documents (a score's ``cost``);
            empty for jobs made before they were recorded.
    """

    id: str
    kind: str
    seed: int
    params: Mapping[str, Any]
    name: str | None = None
    run_seconds: float | None = None
    measured: Mapping[str, Any] = field(default_factory=dict)


class RowSource(Protocol):
    """A finished job as a rows hook sees it."""

    @property
    def job(self) -> JobFacts: ...

    def read(self, name: str) -> Any:
        """The job's JSON artifact ``name``, parsed, or ``None``."""
        ...

    def source(self, ref: str) -> RowSource | None:
        """The succeeded job a ``job:<id>[/<name>]`` ref names, or ``None`` (another ref,
        or no such job)."""
        ...


#: ``rows(src)``: every value the job measured, as :class:`ResultRow` records.
RowsHook = Callable[[RowSource], list[ResultRow]]


def base_row(src: RowSource, metric: str, value: float, **fields: Any) -> ResultRow:
    """A row of ``src``'s job: job, kind and seed filled in, ``lower_is_better`` from the
    metric's name unless given."""
    fields.setdefault("lower_is_better", lower_is_better(metric))
    fields.setdefault("seed", src.job.seed)
    return ResultRow(job=src.job.id, kind=src.job.kind, metric=metric, value=value, **fields)


def whole_set(row: ResultRow) -> bool:
    """A row about a job's whole set (no material, or the mean over materials)."""
    return row.material in (None, "mean")


def headline_rows(rows: Iterable[ResultRow]) -> list[ResultRow]:
    """The whole-set rows (:func:`whole_set`) that stand for their jobs' errors: a job
    with ``test`` whole-set rows of a metric is represented by those (its test error), not
    by its ``train`` ones; other jobs by all their whole-set rows. Order kept."""
    rows = [r for r in rows if whole_set(r)]
    tested = {(r.job, r.metric) for r in rows if r.split == "test"}
    return [r for r in rows if r.split == "test" or (r.job, r.metric) not in tested]


def dataset_of(params: Mapping[str, Any], *keys: str) -> str | None:
    """The first of ``keys`` in ``params`` that is a ref string, as the row's dataset."""
    for key in keys:
        value = params.get(key)
        if isinstance(value, str):
            return value
    return None
