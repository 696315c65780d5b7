"""The ``train.brdf`` job kind: fit BRDF models to MERL tables (the hybrid-BRDF paper).

De Oliveira et al., "A Hybrid Neural-Microfacet BRDF Model for Real-Time Rendering":
``hybrid`` (Eq. 1-3), the ``neural`` baseline (Sec. 4.1) and ``analytic`` GGX + Lambert,
all fitted with the loss of Eq. 4-5 by AdamW with cosine decay and clipping (Sec. 3.3). See
:mod:`models.brdf.networks` for the models and the per-material parameter accounting.

Artifacts:

- ``model.pt``: torch checkpoint (:func:`models.brdf.portable.checkpoint_bytes`);
- ``model.json``: the portable model, format ``matforge.brdf-model/1``
  (:mod:`models.brdf.portable`, with a numpy reference evaluator);
- ``materials.json``: per material ``name``, ``family``, ``split``, ``kd``, ``eta``,
  ``alpha``, ``z``;
- ``curves.json``, ``curves.png``: loss against step (training phase, and the held-out
  phase if any, its steps counted on; ``phases`` says which is which), in the one schema of
  ``docs/artifacts.md``; published live while the job runs;
- ``metrics.json``: per-material ``smape`` (Eq. 6), ``smape_floor`` (stable at exact table
  zeros) and ``mae`` against the source tables at the
  fixed-seed scoring pairs, with means overall, per family and per split
  (:mod:`models.brdf.report`);
Not an artifact: the speed document (unless ``speed: off``), kept in the job's manifest as
``timings.measured.speed`` (timings vary between runs, and artifacts are the same bytes for
the same spec): ns per evaluation of the fused Dr.Jit kernel (wall
  and, steadier on a shared machine, CPU time on 2 dedicated cores), its FLOP per evaluation
  and GFLOP/s per core, and of torch eager, bytes per network and per material, measured in
  this job by
  :func:`models.speed.speed_report` (format ``matforge.speed/1``). ``speed: trained``
  (default) times the trained model at its own size, with its weights and its first
  material, beside the analytic GGX + Lambert; ``speed: full`` adds the bare MLP, hybrid
  and neural at the paper's Table 4 sizes 16x2 ... 64x3 (fresh weights); ``speed_batch``
  pairs per measurement, median of :data:`SPEED_REPEATS` runs, 2 threads.

Same spec, same bytes. All randomness
comes from the job's seed (``ctx.sub_seed``), training runs with
:func:`models.brdf.train.deterministic_torch`, and no other artifact holds a timing (the last
progress message and the log line of :mod:`models.brdf.runner` do; the job's manifest has
its run time). Byte identity holds on CPU; ``device: cuda`` is not guaranteed deterministic
(``scripts/gpu_check.sh`` trains it on CUDA on a GPU machine; the manifest records the
device).

Held-out families (Table 3 of the paper): materials of ``holdout_families`` are left out
of the first phase (network and training materials' ``(z, p)``); a second phase then fits
only their ``(z, p)`` against the frozen network, for ``holdout_steps`` steps. With
``init`` and ``freeze_network`` the whole dataset is fitted that way against a previous
job's network.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from typing import TYPE_CHECKING, Annotated, Any, Literal

from pydantic import Field, model_validator

from jobapi.documents import CurvesDocument, read_typed
from jobapi.errors import JobFailed
from jobapi.kinds import Figure, Kind, register
from jobapi.params import Device, JobRef, Ref, StrictModel, device_field
from jobapi.presets import preset_note, resolve_preset
from jobapi.reports import ReportFacts, phase_loss
from jobapi.results import ArtifactReader, ResultTable, per_material_table
from models.brdf.claims import brdf_claims
from models.brdf.document import BrdfModelDocument, TrainBrdfMaterials, TrainBrdfMetrics
from models.brdf.rows import ROW_METRICS, train_brdf_rows

if TYPE_CHECKING:
    from jobapi.context import JobContext
    from models.brdf.networks import Architecture, BrdfModel

#: Most tables one job may train on.
MAX_TABLES = 500
#: Runs per median of each speed measurement (after one warm-up run).
SPEED_REPEATS = 5


#: ``job:<id>`` without an artifact name: every table of a ``generate.merl`` job.
DatasetJob = JobRef


@dataclass(frozen=True)
class TrainPreset:
    """Defaults of every tunable field; explicit params override them one by one."""

    summary: str
    width: int
    depth: int
    latent_dim: int
    steps: int
    batch_pairs: int
    lr: float
    weight_decay: float
    clip: float
    eval_pairs: int


#: Named presets (``preset``). ``paper`` is Sec. 3.3: hours on 2 CPU cores, minutes on a GPU.
PRESETS: dict[str, TrainPreset] = {
    "small": TrainPreset(
        "about two minutes on 2 cores for the 12-material small collection",
        width=32,
        depth=3,
        latent_dim=4,
        steps=5000,
        batch_pairs=1024,
        lr=0.005,
        weight_decay=0.01,
        clip=0.01,
        eval_pairs=1 << 18,
    ),  # fmt: skip
    "paper": TrainPreset(
        "Sec. 3.3 of the paper: 200k steps, 1024 pairs, lr 0.005, clip 0.01, 10^6 pairs",
        width=32,
        depth=3,
        latent_dim=4,
        steps=200_000,
        batch_pairs=1024,
        lr=0.005,
        weight_decay=0.01,
        clip=0.01,
        eval_pairs=1_000_000,
    ),  # fmt: skip
}


def _preset(name: str) -> str:
    return preset_note(PRESETS, name)


class TrainBrdfParams(StrictModel):
    """Parameters of ``train.brdf``.

    Precedence: a field given explicitly wins; a field left out (``null``) takes the
    ``preset``'s value; with ``init``, the architecture (``width``, ``depth``, latent sizes)
    is the init model's and explicit values must agree with it.

    ======================  ===================  =========  =================================
    name                    type                 default    meaning
    ======================  ===================  =========  =================================
    ``model``               hybrid|neural|       hybrid     which model (Eq. 1 / Sec. 4.1 /
                            analytic                        GGX + Lambert)
    ``dataset``             ``job:<id>`` | refs  required   tables to fit
    ``preset``              small | paper        small      defaults of the fields below
    ``width``, ``depth``    int                  preset     MLP hidden width 16..64, 2..3
    ``latent_dim``          4 | 8                preset     hybrid latent ``l``
    ``neural_latent_dim``   int                  ``l + 7``  neural code size
    ``steps``               int                  preset     optimiser steps
    ``batch_pairs``         int                  preset     pairs per material per step
    ``lr``, ``weight_decay``, ``clip``           preset     AdamW, cosine decay, clipping
    ``eval_pairs``          int                  preset     scoring pairs of metrics.json
    ``holdout_families``    list of str          []         families fitted in phase 2 only
    ``holdout_steps``       int                  steps      steps of phase 2
    ``init``                ref                  none       model.json / model.pt to start
    ``freeze_network``      bool                 false      fit only ``(z, p)`` (needs init)
    ``device``              auto | cpu | cuda    cpu        where to train
    ``speed``               full | trained |     trained    what the speed timing covers
                            off
    ``speed_batch``         int                  2^18       pairs per speed measurement
    ======================  ===================  =========  =================================

    Example::

        {"kind": "train.brdf", "seed": 0, "params": {"model": "hybrid",
         "dataset": "job:<generate.merl job id>", "preset": "small", "width": 16}}
    """

    model: Literal["hybrid", "neural", "analytic"] = Field(
        default="hybrid",
        description="'hybrid' (Eq. 1-3: GGX + Lambert gated and corrected by a shared MLP), "
        "'neural' (the fully neural baseline with learned shading frames) or 'analytic' "
        "(GGX + Lambert alone).",
    )
    dataset: DatasetJob | Annotated[list[Ref], Field(min_length=1, max_length=MAX_TABLES)] = Field(
        description="'job:<id>': every table of a generate.merl job (names and families "
        "from its materials.json); or a list of MERL table refs."
    )
    preset: Literal["small", "paper"] = Field(
        default="small",
        description="Defaults of the unset fields: 'small' (~2 min on 2 cores for 12 "
        "materials) or 'paper' (Sec. 3.3: 200k steps; for a GPU).",
    )
    width: int | None = Field(
        default=None, ge=16, le=64, description="MLP hidden width, 16..64" + _preset("width")
    )
    depth: int | None = Field(
        default=None, ge=2, le=3, description="MLP hidden layers, 2..3" + _preset("depth")
    )
    latent_dim: Literal[4, 8] | None = Field(
        default=None,
        description="Latent size l of the hybrid; the neural baseline gets l + 7 (the same "
        "per-material float count) unless neural_latent_dim is set" + _preset("latent_dim"),
    )
    neural_latent_dim: int | None = Field(
        default=None,
        ge=1,
        le=64,
        description="Neural model only: its code size (the paper's convention is l + 8).",
    )
    steps: int | None = Field(
        default=None, ge=1, le=2_000_000, description="Optimiser steps" + _preset("steps")
    )
    batch_pairs: int | None = Field(
        default=None,
        ge=16,
        le=65536,
        description="Cosine-weighted pairs per material per step" + _preset("batch_pairs"),
    )
    lr: float | None = Field(
        default=None,
        gt=0.0,
        le=1e4,
        description="Initial AdamW learning rate, cosine decay to 0" + _preset("lr"),
    )
    weight_decay: float | None = Field(
        default=None,
        ge=0.0,
        le=1.0,
        description="AdamW decoupled weight decay of the network weights (not of z, p)"
        + _preset("weight_decay"),
    )
    clip: float | None = Field(
        default=None,
        gt=0.0,
        le=1e6,
        description="Gradient-norm clipping threshold" + _preset("clip"),
    )
    eval_pairs: int | None = Field(
        default=None,
        ge=1024,
        le=4_000_000,
        description="Fixed-seed scoring pairs per material in metrics.json" + _preset("eval_pairs"),
    )
    holdout_families: list[Annotated[str, Field(min_length=1, max_length=80)]] = Field(
        default_factory=list,
        max_length=32,
        description="Families left out of training; their (z, p) are fitted afterwards "
        "against the frozen network (Table 3).",
    )
    holdout_steps: int | None = Field(
        default=None, ge=1, le=2_000_000, description="Held-out phase steps (default: steps)."
    )
    init: Ref | None = Field(
        default=None,
        description="model.json or model.pt of a previous train.brdf job: its network (and "
        "the (z, p) of materials with the same names) start this fit.",
    )
    freeze_network: bool = Field(
        default=False, description="With init: keep the network fixed, fit only (z, p)."
    )
    # cpu by default (as before the shared type): the identity and the bytes of every
    # train.brdf spec written without a device stay what they were.
    device: Device = device_field("cpu")
    speed: Literal["full", "trained", "off"] = Field(
        default="trained",
        description="Time the model, ns per evaluation (fused Dr.Jit kernel and torch eager), "
        "kept in the manifest (timings.measured.speed, not an artifact: timings vary "
        "between runs): 'trained' the trained size and the analytic model (seconds), 'full' "
        "also the bare MLP, hybrid and neural at 16x2..64x3 (a few minutes), 'off' nothing.",
    )
    speed_batch: int = Field(
        default=1 << 18,
        ge=1024,
        le=1 << 22,
        description="Cosine-weighted pairs per speed measurement (median of 5 runs).",
    )

    @model_validator(mode="after")
    def _check(self) -> TrainBrdfParams:
        if self.freeze_network and self.init is None:
            raise ValueError("freeze_network needs init (a trained model to freeze)")
        if self.freeze_network and self.holdout_families:
            raise ValueError("holdout_families does not apply with freeze_network")
        if self.holdout_steps is not None and not self.holdout_families:
            raise ValueError("holdout_steps needs holdout_families")
        if self.model == "analytic":
            given = [n for n in ("width", "depth", "latent_dim") if getattr(self, n) is not None]
            if given or self.neural_latent_dim is not None:
                raise ValueError("the analytic model has no network or latent code")
        if self.neural_latent_dim is not None and self.model != "neural":
            raise ValueError("neural_latent_dim applies to model 'neural' only")
        return self

    def effective(self) -> TrainPreset:
        """The preset with the set fields in its place."""
        return resolve_preset(self, PRESETS)


def architecture(params: TrainBrdfParams, init: Architecture | None) -> Architecture:
    """The model's architecture: from the params and preset, or the init model's."""
    from models.brdf.networks import Architecture, equal_neural_latent

    if params.model == "analytic":
        wanted = Architecture("analytic", 0, 0, 0)
    else:
        eff = params.effective()
        lat = eff.latent_dim
        if params.model == "neural":
            lat = params.neural_latent_dim or equal_neural_latent(lat)
        wanted = Architecture(params.model, eff.width, eff.depth, lat)
    if init is None:
        return wanted
    if init.model != params.model:
        raise JobFailed(f"init: that model is '{init.model}', not '{params.model}'")
    explicit = {
        "width": params.width,
        "depth": params.depth,
        "latent_dim": params.neural_latent_dim
        if params.neural_latent_dim is not None
        else (None if params.latent_dim is None else wanted.latent_dim),
    }
    for name, v in explicit.items():
        if v is not None and v != getattr(init, name):
            raise JobFailed(f"init: {name} {v} differs from the init model's {getattr(init, name)}")
    return init


def load_init(ref: str, ctx: JobContext) -> tuple[BrdfModel, list[str], list[str]]:
    """The model of a ``model.json`` or ``model.pt`` ref: ``(model, names, families)``."""
    from models.brdf.portable import from_portable, load_checkpoint

    data = ctx.read_ref(ref)
    try:
        if data[:1] == b"{":
            return from_portable(json.loads(data))
        return load_checkpoint(data)
    except (ValueError, KeyError, TypeError, RuntimeError, OSError) as exc:
        raise JobFailed(f"init {ref}: not a train.brdf model.json or model.pt: {exc}") from None


def run_train_brdf(params: TrainBrdfParams, ctx: JobContext) -> None:
    """Fit, score and store the model (see the module docstring)."""
    from models.brdf.runner import train_and_report

    train_and_report(params, ctx)


#: Columns of ``metrics.json``'s per-material rows, in the result table.
MATERIAL_COLUMNS = ("family", "split", "smape", "smape_floor", "mae", "smape_analytic",
                    "smape_floor_analytic", "mae_analytic")  # fmt: skip


def training_loss(curves: Any) -> list[float | None]:
    """The training loss of a ``curves.json`` for ``report.stability``: its ``train``
    phase (the held-out phase fits other materials); a document of before the one schema
    kept the training curves under ``train``."""
    if isinstance(curves, dict) and isinstance(curves.get("train"), dict):
        curves = curves["train"]
    return phase_loss(curves)


def model_checks(ctx: JobContext, job_id: str) -> dict[str, Any]:
    """NaN/Inf at extreme inputs, albedo and reciprocity of a finished job's model, for
    ``report.stability`` (:func:`models.brdf.stability.trained_checks`; imported here
    only when asked, as it loads torch)."""
    from models.brdf.stability import trained_checks

    return trained_checks(ctx, job_id)


def summarize(read: ArtifactReader) -> ResultTable | None:
    """The result table: ``metrics.json`` (read typed), one row per material (its split
    beside it) then the mean; with held-out materials, the mean over them first
    (``mean test``, the headline) and over the training materials (``mean train``) instead
    of one mean over both."""
    doc = read_typed(read("metrics.json"), TrainBrdfMetrics)
    table = per_material_table(doc, MATERIAL_COLUMNS)
    if table is None or doc is None or "heldout" not in doc["splits"]:
        return table
    rows = {k: v for k, v in table.rows.items() if k != "mean"}
    for label, split in (("mean test", "heldout"), ("mean train", "train")):
        if split in doc["splits"]:
            means: dict[str, Any] = dict(doc["splits"][split])
            rows[label] = {c: means.get(c) for c in table.columns}
            rows[label]["split"] = split
    return dataclasses.replace(table, rows=rows)


register(
    Kind(
        name="train.brdf",
        params=TrainBrdfParams,
        runner=run_train_brdf,
        description="Fit the hybrid neural-microfacet BRDF (or the neural / GGX baselines) to "
        "MERL tables; portable model, per-material parameters, curves and SMAPE.",
        artifacts=(
            "model.pt",
            "model.json",
            "materials.json",
            "curves.json",
            "curves.png",
            "metrics.json",
        ),
        smoke={
            "dataset": "step:generate.merl",
            "steps": 20,
            "width": 16,
            "depth": 2,
            "batch_pairs": 64,
            "eval_pairs": 4096,
            "speed_batch": 1024,
        },
        figures=(
            Figure(
                "curves.png",
                caption="Training curves (the Charts section draws them interactively).",
                lead=True,
            ),
        ),
        documents={
            "curves.json": CurvesDocument,
            "metrics.json": TrainBrdfMetrics,
            "model.json": BrdfModelDocument,
            "materials.json": TrainBrdfMaterials,
        },
        summary=summarize,
        rows=train_brdf_rows,
        metrics=ROW_METRICS,
        report=ReportFacts(
            metric="brdf.smape", loss=training_loss, checks=model_checks, claims=brdf_claims
        ),
    )
)
