"""The params of the ``score`` kind (:mod:`evaluators.score.kind` documents the kind)."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, StringConstraints, field_validator, model_validator

from evaluators.render.sources.external import ExternalSpec
from jobapi.params import JOB_ID_REF, JobRef, Ref, StrictModel

MetricName = Literal["flip", "psnr", "ssim", "mae", "mse", "smape", "l1", "relative_l1"]
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


class ExternalCandidate(StrictModel):
    """A user's model as a candidate: ``{"external": {"model": REF, "kind": ...}}``."""

    external: ExternalSpec = Field(
        description="The model, exactly as the 'external' material: {model: REF, kind: brdf "
        "| btf, uv_scale?}."
    )


#: ``job:<id>``: every table of a ``generate.merl`` job, by material name.
TableSetJob = JobRef
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
    (:mod:`evaluators.score.sets`)::

        {"kind": "score", "params": {"reference": "job:<generate.merl>",
         "candidates": {"hybrid": {"model": "job:<train>/model.json"}}}}
    """

    reference: Ref | TableSetJob | TableMapping = Field(
        description="The reference artifact (job:<id>/<name> or sha256: ref); or, to score "
        "whole models ({model} candidates), a set of MERL tables: 'job:<id>' of a "
        "generate.merl job (its materials by name) or a mapping {material name: table ref}."
    )
    candidates: dict[Label, Ref | ModelCandidate | ExternalCandidate] = Field(
        min_length=1,
        max_length=64,
        description="Candidates to score, by label (1-64 characters of A-Z a-z 0-9 _ . -): "
        "a ref, {model, material} for one material of a trained model (model.json; against "
        "a MERL table reference), {model} for all of a model's materials against a set "
        "of tables, or {external: {model, kind}} for a user's model (kind brdf against a "
        "MERL table; kind btf against a BTF job 'job:<generate.btf id>').",
    )
    metrics: list[MetricName] | None = Field(
        default=None,
        min_length=1,
        description="Metrics to compute (default: all that apply to the reference's kind). "
        "Images: flip, psnr, ssim, mae, mse; BRDF tables: smape, mae; BTF slices: l1, "
        "relative_l1.",
    )
    exposure: ExposureSettings | None = Field(
        default=None,
        description="HDR-FLIP exposure range {start, stop, count, tonemapper}; "
        "default: derived once from the reference.",
    )

    @property
    def btf_set(self) -> bool:
        """Whether the reference is a BTF job's slices (every candidate an external BTF)."""
        return isinstance(self.reference, str) and any(
            isinstance(c, ExternalCandidate) and c.external.kind == "btf"
            for c in self.candidates.values()
        )

    @property
    def table_set(self) -> bool:
        """Whether the reference is a set of tables (``job:<id>`` or a mapping)."""
        if self.btf_set:
            return False
        return not isinstance(self.reference, str) or bool(JOB_ID_REF.match(self.reference))

    @model_validator(mode="after")
    def _check_forms(self) -> ScoreParams:
        btfs = [
            label
            for label, c in self.candidates.items()
            if isinstance(c, ExternalCandidate) and c.external.kind == "btf"
        ]
        if btfs:
            others = sorted(
                label
                for label, c in self.candidates.items()
                if label not in btfs and not (isinstance(c, ModelCandidate) and c.material is None)
            )
            if others:
                raise ValueError(
                    f"candidates.{others[0]}: against a BTF's slices every candidate is an "
                    '{"external": {"model": REF, "kind": "btf"}} or a train.btf model '
                    '{"model": "job:<train.btf id>/model.json"}'
                )
            if not isinstance(self.reference, str) or not JOB_ID_REF.match(self.reference):
                raise ValueError(
                    f"reference: an external BTF (candidates.{btfs[0]}) is scored against the "
                    "slices of a BTF job: give 'job:<generate.btf or import.btf job id>'"
                )
            return self
        for label, cand in self.candidates.items():
            if isinstance(cand, ExternalCandidate) and self.table_set:
                raise ValueError(
                    f"candidates.{label}: an external BRDF is one material, scored against one "
                    "MERL table: give that table as the reference (job:<id>/<name>.binary)"
                )
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
