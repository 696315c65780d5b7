"""Public response models of the REST API, split by direction.

Requests: a job spec is validated by :func:`service.specs.validate_spec` (one strict model
per kind), so :data:`JobCreate` is the envelope model of :mod:`service.specs`; the OpenAPI
document adds one variant per registered kind (see :func:`service.api.build_openapi`).

Responses (``*Public``) document what the routes return. They allow extra fields, so a job
document that grows compatibly passes through unchanged.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from service.specs import JobSpec

#: The body of ``POST /api/jobs`` (documentation; validation is ``validate_spec``).
JobCreate = JobSpec

JobState = Literal["queued", "running", "succeeded", "failed", "cancelled"]


class PublicModel(BaseModel):
    """Base of the response models: extra fields pass through."""

    model_config = ConfigDict(extra="allow")


class HealthPublic(PublicModel):
    """``GET /api/health``."""

    status: Literal["ok"] = "ok"


class ArtifactPublic(PublicModel):
    """One artifact of a job."""

    name: str = Field(description="artifact name, e.g. `image.exr`")
    digest: str = Field(description="sha256 of the bytes, 64 lowercase hex")
    size: int = Field(description="size in bytes")
    media_type: str = Field(description="media type, e.g. `image/x-exr`")


class TimingsPublic(PublicModel):
    """Seconds spent queued and running (``run_seconds`` is null before the job starts)."""

    queued_seconds: float
    run_seconds: float | None = None


class JobPublic(PublicModel):
    """The job document (``GET /api/jobs/{id}``); times are ISO 8601 UTC strings."""

    id: str = Field(description="32 lowercase hex digits")
    kind: str
    name: str | None = None
    batch: str | None = Field(
        default=None, description="label of the batch run that submitted it (`matforge batch`)"
    )
    state: JobState
    progress: float = Field(description="0..1")
    message: str = Field(description="one line: what the job is doing")
    error: str | None = Field(default=None, description="one line, when the job failed")
    worker: str | None = Field(default=None, description='"<host>:<pid>" of its worker')
    attempts: int
    seed: int
    spec_hash: str = Field(description="sha256 of the canonical spec (the job's identity)")
    created_at: str | None = None
    started_at: str | None = None
    finished_at: str | None = None
    timings: TimingsPublic
    spec: dict[str, Any] = Field(description="the validated spec, defaults filled in")
    manifest: str | None = Field(default=None, description="`sha256:` ref of the manifest")
    artifacts: list[ArtifactPublic] = Field(description="empty until the job succeeded")
    tags: list[str] = Field(
        default_factory=list, description="labels added with `matforge tag` (sorted)"
    )


class JobListItem(JobPublic):
    """A job in ``GET /api/jobs``: the job document, plus ``columns`` when asked for."""

    columns: dict[str, Any] | None = Field(
        default=None,
        description="in `GET /api/jobs?columns=`: the job's value for each asked column "
        "(`params.<path>`, `metric.<name>`), null where it has none",
    )


class UploadPublic(PublicModel):
    """``POST /api/artifacts``: the stored upload."""

    digest: str = Field(description="sha256 of the bytes, 64 lowercase hex")
    ref: str = Field(description="`sha256:<digest>`, usable in job specs")
    size: int
    media_type: str
    name: str = Field(description="the file name it was uploaded under")


class KindPublic(PublicModel):
    """A registered job kind (``GET /api/kinds``)."""

    name: str
    summary: str
    artifacts: list[str] = Field(description="fixed artifact names (patterns allowed)")
    params_schema: dict[str, Any] = Field(description="JSON schema of the kind's params")
    plugin: str | None = Field(
        default=None,
        description="the installed package whose plugin (entry point matforge.kinds) adds "
        "this kind; null for a built-in kind",
    )


class PluginPublic(PublicModel):
    """An entry point of the group ``matforge.kinds`` (``GET /api/plugins``)."""

    name: str = Field(description="the entry point's name")
    value: str = Field(description="the module (or module:object) it names")
    distribution: str | None = Field(description="the installed package that declares it")
    kinds: list[str] = Field(description="the kinds it added (empty when it is broken)")
    error: str | None = Field(description="why it was not loaded; null when it loaded")


class StatsPublic(PublicModel):
    """``GET /api/stats``: how many jobs are in each state."""

    counts: dict[str, int]
    total: int


class ErrorPublic(PublicModel):
    """Every error: ``error`` is one line a user can act on (it names the field or file);
    ``detail`` is the structured form (a string, or ``[{"loc", "msg"}]`` for 422)."""

    error: str
    detail: Any = None


class ResultRowPublic(BaseModel):
    """One measured value (see ``jobapi.rows`` for the cost columns' meaning)."""

    job: str
    step: str | None = None
    kind: str
    dataset: str | None = None
    scene: str | None = None
    candidate: str | None = None
    material: str | None = None
    family: str | None = None
    split: Literal["train", "test"] | None = Field(
        None,
        description="`train`: over the data the model was fitted to; `test`: over held-out "
        "data (materials, betas, patterns) it never saw",
    )
    config: dict[str, Any] = Field(default_factory=dict)
    metric: str = Field(
        description="the metric; one measured in more than one space names it "
        "(`brdf.mae`, `image.mae`)"
    )
    value: float
    lower_is_better: bool | None = None
    seed: int | None = None
    ns_per_eval: float | None = Field(
        None, description="ns per evaluation on a fixed batch, in the row's runtime"
    )
    runtime: str | None = Field(
        None,
        description="what evaluated the model: drjit-fused, onnxruntime or mitsuba (costs of "
        "two runtimes are not alike)",
    )
    ms_per_frame: float | None = None
    bytes_per_material: float | None = None
    bytes_per_network: float | None = None
    train_seconds: float | None = Field(None, description="wall seconds of the training job")
    spp: int | None = None
    render_seconds: float | None = Field(None, description="wall seconds of the render job")
    macs_per_eval: float | None = Field(
        None,
        description="multiply-adds of the model's dense layers per evaluation (the same on "
        "every machine)",
    )
    bytes_per_eval: float | None = Field(
        None,
        description="bytes one evaluation reads: weights, analytic parameters, and what one "
        "lookup reads of a latent texture or a table",
    )
