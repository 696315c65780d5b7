"""The ``score`` job kind: score candidate artifacts against a reference.

The reference's *artifact kind* picks the scorer, through :data:`ARTIFACT_KINDS`:

=============  ===================  ====================================  =================
kind           files                metrics                               values compared
=============  ===================  ====================================  =================
``image-hdr``  OpenEXR (``.exr``)   ``flip`` (HDR-FLIP), ``psnr``,         linear RGB
                                    ``ssim``, ``mae``, ``mse``
``image-ldr``  PNG (``.png``)       ``flip`` (LDR-FLIP), ``psnr``,         sRGB-encoded
                                    ``ssim``, ``mae``, ``mse``             values in [0, 1]
``merl``       MERL table            ``smape`` (Eq. 6 of the hybrid-BRDF   plain RGB BRDF in
               (``.binary``)         paper), ``mae``                       1/sr at 10^6 pairs
=============  ===================  ====================================  =================

Other artifact kinds plug in with :func:`register_artifact_kind` (a loader, a scorer, the
metrics it supports) from modules in :data:`ARTIFACT_KIND_MODULES`: images in
:mod:`evaluators.score_images`, ``merl`` and ``brdf-model`` in :mod:`evaluators.score_brdf`.
``metrics`` left out means all that the reference's kind supports; one it does not support
fails the job, listing those it does.

Candidates are of the reference's kind, or of a kind it lists in ``candidate_kinds``. A
*model* kind (one with ``bind``) is a file holding several materials, scored one material
at a time: such a candidate is given as ``{"model": REF, "material": NAME}``. The model kind
``brdf-model`` (a ``train.brdf`` ``model.json``, recognised by its ``format`` field) is
scored against ``merl`` references, evaluated for that material with the portable
evaluator at the same pairs as tables; a model cannot be the reference. A whole model,
``{"model": REF}``, is scored against a *set* of tables given as the reference
(``job:<generate.merl id>`` or ``{material name: table ref}``), each material against the
table of the same name (:mod:`evaluators.score_sets`); the two forms are checked against
the reference's form at spec time.

Choices for images, recorded in ``metrics.json`` under ``settings``:

- ``data_range`` of PSNR and SSIM: 1 for PNG; for EXR the reference's largest pixel value
  (over all channels), so that PSNR is the error relative to the brightest reference value;
- HDR-FLIP's exposure range is computed once from the reference (unless given in
  ``exposure``) and used for every candidate, so their FLIP values are comparable;
- PSNR of an identical candidate is infinite and is written as ``null``.
"""

from __future__ import annotations

import importlib
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal

from pydantic import AfterValidator, Field, StringConstraints, field_validator, model_validator

from service.errors import FormatError, JobFailed
from service.registry import Kind, register
from service.specs import Ref, StrictModel

if TYPE_CHECKING:
    from service.context import JobContext

MetricName = Literal["flip", "psnr", "ssim", "mae", "mse", "smape"]
IMAGE_METRICS: tuple[MetricName, ...] = ("flip", "psnr", "ssim", "mae", "mse")
Label = Annotated[str, StringConstraints(pattern=r"^[A-Za-z0-9_.-]{1,64}$")]


class ExposureSettings(StrictModel):
    """HDR-FLIP exposures; unset fields are derived from the reference (HDR-FLIP rule)."""

    start: float | None = Field(
        default=None,
        ge=-64.0,
        le=64.0,
        allow_inf_nan=False,
        description="First exposure, in stops.",
    )
    stop: float | None = Field(
        default=None,
        ge=-64.0,
        le=64.0,
        allow_inf_nan=False,
        description="Last exposure, in stops (>= start).",
    )
    count: int | None = Field(
        default=None, ge=2, le=64, description="Number of exposures from start to stop."
    )
    tonemapper: Literal["aces", "hable", "reinhard"] = Field(
        default="aces", description="Tone curve HDR-FLIP assumes."
    )

    @model_validator(mode="after")
    def _check_order(self) -> ExposureSettings:
        if self.start is not None and self.stop is not None and self.start > self.stop:
            raise ValueError(f"start ({self.start}) must not be above stop ({self.stop})")
        return self


MaterialName = Annotated[str, StringConstraints(min_length=1, max_length=256)]


class ModelCandidate(StrictModel):
    """A trained model as a candidate: ``{"model": REF, "material": NAME}`` scores one of its
    materials against a table reference; ``{"model": REF}`` scores every material named in a
    set-of-tables reference (``job:<generate.merl id>`` or ``{name: table REF}``)."""

    model: Ref = Field(
        description="The trained model: a train.brdf model.json (job:<id>/model.json or "
        "sha256: ref)."
    )
    material: MaterialName | None = Field(
        default=None,
        description="Name of the model's material to score (one of its materials[].name); "
        "left out: the whole model, against a set of tables (reference job:<id> or a "
        "mapping), each material against the table of the same name.",
    )


TABLE_SET_JOB = re.compile(r"^job:[0-9a-f]{32}$")


def _check_table_set_job(value: str) -> str:
    if not TABLE_SET_JOB.match(value):
        raise ValueError("must be 'job:<job-id>' (every table of a generate.merl job)")
    return value


#: ``job:<id>``: every table of a ``generate.merl`` job, by material name.
TableSetJob = Annotated[str, AfterValidator(_check_table_set_job)]
#: ``{material name: MERL table ref}``.
TableMapping = Annotated[dict[MaterialName, Ref], Field(min_length=1, max_length=500)]


class ScoreParams(StrictModel):
    """Parameters of ``score``.

    Example::

        {"kind": "score", "params": {"reference": "job:<id>/image.exr",
         "candidates": {"fit": "job:<id2>/image.exr", "baseline": "sha256:<hex>"},
         "metrics": ["flip", "psnr"]}}

    Against a MERL table, a trained model's material::

        {"kind": "score", "params": {"reference": "sha256:<table>",
         "candidates": {"hybrid": {"model": "job:<train>/model.json", "material": "gold"}}}}

    Every material of trained models against the tables of a generate.merl job
    (:mod:`evaluators.score_sets`)::

        {"kind": "score", "params": {"reference": "job:<generate.merl>",
         "candidates": {"hybrid": {"model": "job:<train>/model.json"}}}}
    """

    reference: Ref | TableSetJob | TableMapping = Field(
        description="The reference artifact (job:<id>/<name> or sha256: ref); or, to score "
        "whole models ({model} candidates), a set of MERL tables: 'job:<id>' of a "
        "generate.merl job (its materials by name) or a mapping {material name: table ref}."
    )
    candidates: dict[Label, Ref | ModelCandidate] = Field(
        min_length=1,
        max_length=64,
        description="Candidates to score, by label (1-64 characters of A-Z a-z 0-9 _ . -): "
        "a ref, {model, material} for one material of a trained model (model.json; against "
        "a MERL table reference), or {model} for all of a model's materials against a set "
        "of tables.",
    )
    metrics: list[MetricName] | None = Field(
        default=None,
        min_length=1,
        description="Metrics to compute (default: all that apply to the reference's kind). "
        "Images: flip, psnr, ssim, mae, mse; BRDF tables: smape, mae.",
    )
    exposure: ExposureSettings | None = Field(
        default=None,
        description="HDR-FLIP exposure range {start, stop, count, tonemapper}; "
        "default: derived once from the reference.",
    )

    @property
    def table_set(self) -> bool:
        """Whether the reference is a set of tables (``job:<id>`` or a mapping)."""
        return not isinstance(self.reference, str) or bool(TABLE_SET_JOB.match(self.reference))

    @model_validator(mode="after")
    def _check_forms(self) -> ScoreParams:
        for label, cand in self.candidates.items():
            whole = isinstance(cand, ModelCandidate) and cand.material is None
            if self.table_set and not whole:
                raise ValueError(
                    f"candidates.{label}: against a set of tables (reference 'job:<id>' or "
                    'a mapping) every candidate is a whole model {"model": REF}'
                )
            if whole and not self.table_set:
                raise ValueError(
                    f'candidates.{label}: {{"model": REF}} without "material" scores every '
                    "material and needs a set of tables as reference: 'job:<generate.merl "
                    "job id>' or {material name: table ref}; or name one material"
                )
        return self

    @field_validator("metrics")
    @classmethod
    def _unique(cls, value: list[str] | None) -> list[str] | None:
        if value is None:
            return None
        dupes = sorted({m for m in value if value.count(m) > 1})
        if dupes:
            raise ValueError(f"metrics listed more than once: {', '.join(dupes)}")
        return value


# -- artifact kinds --------------------------------------------------------------------------


@dataclass(frozen=True)
class Loaded:
    """An input artifact: its ref, artifact kind and decoded data."""

    ref: str
    kind: str
    data: Any


@dataclass(frozen=True)
class ScoreResult:
    """What a scorer returns: ``{label: {metric: value}}`` and the settings it used."""

    metrics: dict[str, dict[str, float | None]]
    settings: dict[str, Any]


Scorer = Callable[[Loaded, dict[str, Loaded], ScoreParams, "JobContext"], ScoreResult]


@dataclass(frozen=True)
class ArtifactKind:
    """A kind of artifact ``score`` understands.

    ``media_types``, ``extensions`` and ``magic`` (leading bytes) identify it, in that
    order, then ``detect(path)`` where given; ``load(path, name)`` decodes it (raising
    ``FormatError``); ``scorer`` scores candidates of the same kind and of the kinds named in
    ``candidate_kinds``; ``metrics`` lists the metric names it supports. ``bind(data,
    material)`` marks a *model* kind: it returns the loaded data of one material (raising
    ``FormatError`` for an unknown one); model kinds are candidates only.
    """

    name: str
    description: str
    media_types: tuple[str, ...]
    extensions: tuple[str, ...]
    magic: bytes
    load: Callable[[Path, str], Any]
    scorer: Scorer
    metrics: tuple[str, ...]
    candidate_kinds: tuple[str, ...] = ()
    detect: Callable[[Path], bool] | None = None
    bind: Callable[[Any, str], Any] | None = None


ARTIFACT_KINDS: dict[str, ArtifactKind] = {}


def register_artifact_kind(kind: ArtifactKind) -> ArtifactKind:
    """Teach ``score`` a new kind of artifact (re-registering a name replaces it)."""
    ARTIFACT_KINDS[kind.name] = kind
    return kind


def identify(name: str, media_type: str, path: Path) -> ArtifactKind | None:
    """The artifact kind of a stored object, from its media type, name or first bytes."""
    for kind in ARTIFACT_KINDS.values():
        if media_type in kind.media_types:
            return kind
    suffix = Path(name).suffix.lower()
    for kind in ARTIFACT_KINDS.values():
        if suffix and suffix in kind.extensions:
            return kind
    with open(path, "rb") as fh:
        head = fh.read(16)
    for kind in ARTIFACT_KINDS.values():
        if kind.magic and head.startswith(kind.magic):
            return kind
    for kind in ARTIFACT_KINDS.values():
        if kind.detect is not None and kind.detect(path):
            return kind
    return None


def _load(ref: str, role: str, ctx: JobContext, material: str | None = None) -> Loaded:
    """Load ``ref``; ``material`` picks one material of a model kind (and requires one)."""
    record = ctx.ref_record(ref)
    path = ctx.resolve(ref)
    kind = identify(record.name, record.media_type, path)
    if kind is None:
        known = ", ".join(f"{k.description}" for k in ARTIFACT_KINDS.values())
        raise JobFailed(
            f"{role} {ref}: cannot score {record.name} ({record.media_type}); known kinds: {known}"
        )
    if kind.bind is None and material is not None:
        raise JobFailed(
            f"{role}: {{model, material}} needs a trained model, but {ref} is {kind.description}"
        )
    if kind.bind is not None and material is None:
        if role == "reference":
            raise JobFailed(
                f"reference {ref} is {kind.description}; a model can only be a candidate"
            )
        raise JobFailed(
            f"{role}: {ref} is {kind.description}; name one of its materials with "
            f'{{"model": "{ref}", "material": NAME}}'
        )
    try:
        data = kind.load(path, ref)
        if kind.bind is not None and material is not None:
            data = kind.bind(data, material)
    except FormatError as exc:
        raise JobFailed(f"{role}: {exc}") from None
    shown = ref if material is None else f"{ref}#{material}"
    return Loaded(ref=shown, kind=kind.name, data=data)


#: Modules that register further artifact kinds, imported once this module is complete.
ARTIFACT_KIND_MODULES: tuple[str, ...] = ("evaluators.score_images", "evaluators.score_brdf")
for _module in ARTIFACT_KIND_MODULES:
    importlib.import_module(_module)


# -- the runner ------------------------------------------------------------------------------


def run_score(params: ScoreParams, ctx: JobContext) -> None:
    """Load the reference and candidates, score them, and store ``metrics.json``."""
    ctx.progress(0.0, "loading inputs")
    if params.table_set:
        from evaluators.score_sets import score_table_set

        score_table_set(params, ctx)
        return
    assert isinstance(params.reference, str)
    reference = _load(params.reference, "reference", ctx)
    kind = ARTIFACT_KINDS[reference.kind]
    metrics = list(params.metrics or kind.metrics)
    unsupported = [m for m in metrics if m not in kind.metrics]
    if unsupported:
        names = ", ".join(repr(m) for m in unsupported)
        verb = "metric " + names + " does" if len(unsupported) == 1 else f"metrics {names} do"
        raise JobFailed(
            f"metrics: {verb} not apply to {kind.description}; use {', '.join(kind.metrics)}"
        )
    params = params.model_copy(update={"metrics": metrics})  # scorers see the concrete list
    candidates: dict[str, Loaded] = {}
    for label, spec in params.candidates.items():
        role = f"candidate {label!r}"
        if isinstance(spec, ModelCandidate):
            assert spec.material is not None  # whole models only with table sets
            cand = _load(spec.model, role, ctx, material=spec.material)
        else:
            cand = _load(spec, role, ctx)
        if cand.kind != reference.kind and cand.kind not in kind.candidate_kinds:
            raise JobFailed(
                f"candidate {label!r} is {ARTIFACT_KINDS[cand.kind].description} "
                f"but the reference is {kind.description}; score artifacts of "
                f"one kind against each other"
            )
        candidates[label] = cand
    ctx.progress(0.1, f"scoring {len(candidates)} candidates")
    result = kind.scorer(reference, candidates, params, ctx)
    ctx.put_json(
        "metrics.json",
        {"reference": params.reference, "metrics": result.metrics, "settings": result.settings},
    )
    ctx.progress(1.0, f"scored {len(candidates)} candidates with {', '.join(metrics)}")


register(
    Kind(
        name="score",
        params=ScoreParams,
        runner=run_score,
        summary="Scores candidate artifacts against a reference (images: FLIP, PSNR, "
        "SSIM, MAE, MSE; MERL BRDF tables, and trained models' materials against them: "
        "SMAPE, MAE in BRDF space).",
        artifacts=("metrics.json", "flip_<label>.png"),
        smoke={},
    )
)
