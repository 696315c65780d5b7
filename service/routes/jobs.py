"""``/api/jobs``: submit, list, show, cancel, and a job's artifacts, manifest and log."""

from __future__ import annotations

import json
import logging
import re
from typing import Annotated, Any

from fastapi import APIRouter, HTTPException, Query, Request, Response
from fastapi.responses import PlainTextResponse
from pydantic import BaseModel, ConfigDict, Field, WithJsonSchema
from starlette.concurrency import run_in_threadpool

from jobapi.context import LIVE_PREFIX
from jobapi.errors import SpecError
from service.deps import AuthDep, JobId, JobsDep, SettingsDep, StoreDep
from service.job_columns import job_values, metric_means
from service.job_list import JobListDep
from service.parse_threads import SMALL_BYTES, off_loop
from service.results import job_rows
from service.schemas import ArtifactPublic, ErrorPublic, JobListItem, JobPublic
from service.spec_text import parse_json_text, parse_spec_text
from service.submission import prepare_submission, queue_spec
from service.summaries import job_summary
from service.workers.backend import identity_variant
from storage.artifacts import ArtifactStore
from storage.errors import TooLargeError
from storage.job_logs import JobLog, log_dir
from storage.jobs import Job, JobStore

log = logging.getLogger("matforge.api")

router = APIRouter(prefix="/api/jobs", tags=["jobs"], dependencies=[AuthDep])

#: The request body of ``POST /api/jobs`` in the OpenAPI document; the schema is filled in
#: with one variant per registered kind by :func:`service.api.build_openapi`.
SPEC_BODY_DOC: dict[str, Any] = {
    "requestBody": {
        "required": True,
        "description": (
            "A job spec `{kind, name, seed, params, force}`; `params` are the kind's "
            "parameters (one schema per kind under `components/schemas/params.<kind>`). "
            "JSON, or YAML with `Content-Type: application/yaml`."
        ),
        "content": {
            "application/json": {"schema": {"$ref": "#/components/schemas/JobCreate"}},
            "application/yaml": {"schema": {"$ref": "#/components/schemas/JobCreate"}},
        },
    }
}


#: The content types of a spec body (YAML under its registered and customary names).
SPEC_TYPES = frozenset(
    {"application/json", "application/yaml", "application/x-yaml", "text/yaml", "text/x-yaml"}
)


#: Bytes a spec sent over HTTP may have, checked before it is read or parsed (413 beyond):
#: far above any real spec (a score of a thousand candidates is about 100 KB), far below the
#: 1 MiB of other JSON bodies (``MATFORGE_MAX_BODY_KB``), which a batch of many steps needs.
#: Parsing and validating a 1 MB spec holds the GIL in single C calls (decode, encode,
#: pydantic) of 40-50 ms each, and the event loop waits for them (issue 21, item 5).
MAX_SPEC_BYTES = 256 * 1024
#: YAML values a spec sent over HTTP may hold (counted before it is built; libyaml's events
#: are cheap, PyYAML's objects are not: a 1 MB flat YAML list took seconds to build). JSON,
#: parsed in C, is bounded by the body limit alone.
MAX_YAML_VALUES = 50_000


def parse_spec_body(raw: bytes, content_type: str) -> Any:
    """The parsed and checked spec in a request body (JSON, or YAML when ``content_type``
    says so); :class:`SpecError` (422) when it does not parse or is hostile."""
    if not raw.strip():
        raise SpecError([("body", "empty request body: send a job spec as JSON")])
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise SpecError([("body", "the request body is not UTF-8 text")]) from None
    if "yaml" in content_type:
        return parse_spec_text(text, "request body", aliases=False, max_values=MAX_YAML_VALUES)
    return parse_json_text(text, "body")


async def spec_bytes(request: Request) -> tuple[bytes, str]:
    """The request body of a spec, unparsed, and its content type: 415 for a type that is
    not a spec's, 413 beyond :data:`MAX_SPEC_BYTES` (from the declared length before the
    body is read)."""
    content_type = request.headers.get("content-type", "").split(";")[0].strip().lower()
    if content_type not in SPEC_TYPES:
        # A cross-site form can POST text/plain without a CORS preflight: never a spec.
        shown = repr(content_type) if content_type else "none"
        raise HTTPException(
            415,
            f"Content-Type {shown} is not a job spec's: send application/json "
            "(or application/yaml)",
        )
    declared = request.headers.get("content-length", "")
    if declared.isdigit() and int(declared) > MAX_SPEC_BYTES:
        raise TooLargeError(_too_large(int(declared)))
    raw = await request.body()
    if len(raw) > MAX_SPEC_BYTES:
        raise TooLargeError(_too_large(len(raw)))
    return raw, content_type


def _too_large(size: int) -> str:
    return (
        f"a job spec of {size} bytes exceeds the limit of {MAX_SPEC_BYTES} bytes; "
        "large inputs belong in an upload (POST /api/artifacts), referenced by its sha256: ref"
    )


_ERRORS: dict[int | str, dict[str, Any]] = {
    404: {"model": ErrorPublic, "description": "no such job"},
    422: {
        "model": ErrorPublic,
        "description": "invalid input; `error` names the field: a malformed job id, or a "
        "prefix that several jobs share (ambiguous; `error` lists the matches)",
    },
}
#: What ``POST /api/jobs`` refuses with 422, some of it beyond what a JSON schema can say.
_SPEC_422: dict[str, Any] = {
    "model": ErrorPublic,
    "description": "invalid spec; `error` names the field. Besides what the schema states: "
    "an unknown kind; a kind's rules across fields (e.g. `select`: either `runs`, or "
    "`scene`, `reference` and `ladder`, with distinct rung names); a `job:` or `sha256:` "
    "ref that names no succeeded job's artifact or no stored object; an ambiguous job id "
    "prefix; a body that is not JSON or YAML, nested too deep, or with YAML aliases",
}


@router.post(
    "",
    status_code=201,
    response_model=JobPublic,
    summary="Submit a job",
    openapi_extra=SPEC_BODY_DOC,
    responses={
        200: {
            "model": JobPublic,
            "description": (
                "The identical spec (same canonical kind, seed and params) is already "
                "succeeded, queued or running, and `force` is not set: that job is returned "
                "instead of a new one."
            ),
        },
        201: {"description": "A new job was queued."},
        413: {
            "model": ErrorPublic,
            "description": f"a spec over {MAX_SPEC_BYTES // 1024} KiB (or a body over the "
            "JSON size limit)",
        },
        415: {"model": ErrorPublic, "description": "not application/json or YAML"},
        422: _SPEC_422,
    },
)
async def create_job(
    request: Request,
    response: Response,
    jobs: JobsDep,
    store: StoreDep,
    settings: SettingsDep,
) -> Any:
    """Validate a spec and queue it (201). Every `job:`/`sha256:` reference in the params
    must exist. Resubmitting an identical spec returns the existing job (200) unless
    `"force": true`."""
    raw, content_type = await spec_bytes(request)
    # The workers' Mitsuba variant, part of the identity of the kinds whose bytes depend on
    # it (resolved by `matforge serve` at start-up; else probed once per process).
    variant = settings.variant
    if variant == "auto":
        variant = await run_in_threadpool(identity_variant, settings)
    if len(raw) <= SMALL_BYTES:
        # Every real spec: parsed, validated and queued in one trip to the thread pool.
        # Each trip is a hand-over of the GIL and a wake-up that the scheduler may give
        # to another process first; three of them were a third of the web process's CPU
        # per submission, and more of its latency on a busy machine.
        job, created = await run_in_threadpool(submit_body, raw, content_type, jobs, store, variant)
    else:
        # A large spec costs CPU in C calls that hold the GIL: parsed and validated in
        # the parse thread, so that one at most competes with the event loop; queued in
        # the (larger) thread pool, where submissions overlap their waits on SQLite.
        parsed = await off_loop(parse_spec_body, raw, content_type, size=len(raw))
        spec = await off_loop(prepare_submission, parsed, jobs, store, variant, size=len(raw))
        job, created = await run_in_threadpool(queue_spec, spec, jobs, store)
    response.status_code = 201 if created else 200
    response.headers["Location"] = f"/api/jobs/{job.id}"
    return job.document()


def submit_body(
    raw: bytes, content_type: str, jobs: JobStore, store: ArtifactStore, variant: str | None
) -> tuple[Job, bool]:
    """Parse, validate and queue a spec body (in a worker thread); ``(job, created)``.
    Raises :class:`SpecError`."""
    parsed = parse_spec_body(raw, content_type)
    return queue_spec(prepare_submission(parsed, jobs, store, variant), jobs, store)


@router.get("", response_model=list[JobListItem], summary="List jobs, newest first")
def list_jobs(jobs: JobsDep, store: StoreDep, query: JobListDep, response: Response) -> Any:
    """Jobs, newest first unless `sort` says otherwise (without their artifact lists; see
    `GET /api/jobs/{id}`). The `X-Total-Count` header holds how many jobs match the
    filters, for paging with `limit` and `offset`. An unknown `kind` or `sort` is a 422
    that names the parameter. `columns` adds each job's value of params or metrics as
    `columns`; `filter` keeps the jobs whose values pass (both: `service.job_columns`)."""
    q = query
    base = {"name": q.name, "batch": q.batch, "tag": q.tag}
    if not q.filters:
        total = jobs.count_jobs(q.state, q.kind, **base)
        found = jobs.list_jobs(q.state, q.kind, q.limit, q.offset, sort=q.sort, **base)
        values = [job_values_of(j, q.columns, jobs, store) for j in found] if q.columns else []
    else:
        keys = list(dict.fromkeys([*q.columns, *(f.key for f in q.filters)]))
        matched, values = [], []
        for j in jobs.list_jobs(q.state, q.kind, MAX_FILTERED, 0, sort=q.sort, **base):
            v = job_values_of(j, keys, jobs, store)
            if all(f.passes(v[f.key]) for f in q.filters):
                matched.append(j)
                values.append(v)
        total = len(matched)
        found = matched[q.offset : q.offset + q.limit]
        values = values[q.offset : q.offset + q.limit]
    response.headers["X-Total-Count"] = str(total)
    docs = [j.document() for j in found]
    if q.columns:
        for doc, v in zip(docs, values, strict=True):
            doc["columns"] = {k: v[k] for k in q.columns}
    return docs


#: Jobs a list with ``filter`` looks through (newest first, by the other filters).
MAX_FILTERED = 5000


def job_values_of(job: Job, keys: Any, jobs: JobStore, store: ArtifactStore) -> dict[str, Any]:
    """``job``'s value for each column key; metrics from its result rows (a job that did
    not succeed, or whose rows cannot be read, has none)."""

    def metrics() -> dict[str, float]:
        if job.state != "succeeded":
            return {}
        try:
            return metric_means(job_rows(jobs.get(job.id), jobs, store))
        except Exception:  # a job's unreadable artifacts hide its metrics, not the list
            log.debug("no result rows for job %s", job.id, exc_info=True)
            return {}

    return job_values(job.spec, keys, metrics)


@router.get("/{job_id}", response_model=JobPublic, responses=_ERRORS, summary="A job")
def get_job(job_id: JobId, jobs: JobsDep) -> Any:
    """The job document, with its artifacts once it succeeded."""
    return jobs.get(job_id).document()


#: A tag: what ``matforge tag`` accepts (no spaces or commas, so lists stay readable).
TAG_PATTERN = r"^[A-Za-z0-9_.:+\-]{1,64}$"
TAG = re.compile(TAG_PATTERN)
#: A tag in the OpenAPI document: the rule :func:`patch_job` checks (matched whole, as the
#: schema means it), whose refusal names the tag (a schema-valid tag is never a 422).
TagText = Annotated[str, WithJsonSchema({"type": "string", "pattern": TAG_PATTERN})]


class JobPatch(BaseModel):
    """``PATCH /api/jobs/{id}``: what to change (each field optional)."""

    model_config = ConfigDict(extra="forbid")

    name: str | None = Field(default=None, max_length=200, description='a new name (`""`: no name)')
    add_tags: list[TagText] = Field(default_factory=list, max_length=64, description="tags to add")
    remove_tags: list[TagText] = Field(
        default_factory=list, max_length=64, description="tags to remove"
    )


@router.patch("/{job_id}", response_model=JobPublic, responses=_ERRORS, summary="Rename, tag")
def patch_job(job_id: JobId, patch: JobPatch, jobs: JobsDep) -> Any:
    """Rename a job (`name`) and add or remove its tags; the job, as changed. A name and
    tags are labels, not inputs: the spec's identity (`spec_hash`) does not change. A tag
    is 1 to 64 letters, digits or `_.:+-` (a 422 names the one that is not)."""
    for field_name in ("add_tags", "remove_tags"):
        for i, t in enumerate(getattr(patch, field_name)):
            if not TAG.fullmatch(t):
                raise SpecError(
                    [
                        (
                            f"body.{field_name}.{i}",
                            f"{t!r} is not a tag: 1 to 64 letters, digits or _.:+-",
                        )
                    ]
                )
    jobs.get(job_id)  # 404 first
    if "name" in patch.model_fields_set:
        jobs.rename(job_id, " ".join((patch.name or "").split()) or None)
    job = jobs.tag(job_id, add=patch.add_tags, remove=patch.remove_tags)
    return job.document()


@router.post(
    "/{job_id}/cancel", response_model=JobPublic, responses=_ERRORS, summary="Cancel a job"
)
def cancel_job(job_id: JobId, jobs: JobsDep) -> Any:
    """Cancel a queued or running job (a running job stops at its worker's next heartbeat).
    A finished job is returned unchanged."""
    return jobs.cancel(job_id).document()


@router.get(
    "/{job_id}/artifacts",
    response_model=list[ArtifactPublic],
    responses=_ERRORS,
    summary="A job's artifacts",
)
def list_artifacts(job_id: JobId, jobs: JobsDep) -> Any:
    """`[{name, digest, size, media_type}]`; empty until the job succeeded. Download the
    bytes with `GET /api/artifacts/{digest}`."""
    jobs.get(job_id)  # 404 for an unknown job
    return [a.public() for a in jobs.artifacts(job_id)]


@router.get(
    "/{job_id}/manifest",
    responses={
        **_ERRORS,
        409: {"model": ErrorPublic, "description": "the job has not succeeded: no manifest yet"},
    },
    summary="A job's manifest",
)
def get_manifest(job_id: JobId, jobs: JobsDep, store: StoreDep) -> dict[str, Any]:
    """The manifest a finished job wrote: spec, artifacts, code version, package versions,
    worker, attempt and timings. 404 for an unknown job; 409 while the job exists but has
    not succeeded (queued, running, failed, cancelled): it has no manifest yet."""
    job = jobs.get(job_id)
    if not job.manifest_digest:
        when = (
            "it is written when the job succeeds"
            if job.state in ("queued", "running")
            else ("only a job that succeeded has one")
        )
        raise HTTPException(409, f"job {job_id} is {job.state}: no manifest; {when}")
    manifest: dict[str, Any] = json.loads(store.read(job.manifest_digest))
    return manifest


@router.get(
    "/{job_id}/log",
    response_class=Response,
    responses={
        **_ERRORS,
        200: {"content": {"text/plain": {"schema": {"type": "string"}}}, "description": "the log"},
    },
    summary="A job's log (the same as /logs)",
)
@router.get(
    "/{job_id}/logs",
    response_class=Response,
    responses={
        **_ERRORS,
        200: {"content": {"text/plain": {"schema": {"type": "string"}}}, "description": "the log"},
    },
    summary="A job's log",
)
def get_logs(
    job_id: JobId,
    jobs: JobsDep,
    settings: SettingsDep,
    tail: Annotated[int | None, Query(ge=0, le=100_000, description="last N lines")] = None,
) -> PlainTextResponse:
    """What the job's runs wrote (`text/plain`, one line per entry, UTC time first): each
    attempt's start (worker, attempt) and end (state, error), its progress lines (one every
    2 s at most) and the worker's log records while it ran. Empty until a worker starts
    the job; at most 1 MiB. `tail` keeps the last N lines."""
    job = jobs.get(job_id)
    text = JobLog(log_dir(settings.data_dir), job.id).read(tail)
    return PlainTextResponse(text)


@router.get("/{job_id}/live/{name}", responses=_ERRORS, summary="A running job's live document")
def get_live(job_id: JobId, name: str, jobs: JobsDep, store: StoreDep) -> Any:
    """The latest JSON document a running job published under `name` (e.g. `curves.json`,
    its training curves so far), for live charts; `null` when it published none yet (or
    has finished: then its artifact of that name is what counts)."""
    digest = jobs.shards(job_id).get(LIVE_PREFIX + name)
    return None if digest is None else json.loads(store.read(digest))


@router.get("/{job_id}/summary", responses=_ERRORS, summary="A job's result table")
def get_summary(job_id: JobId, jobs: JobsDep, store: StoreDep) -> dict[str, Any] | None:
    """The result table the job's kind makes of its artifacts: `{title, label_header,
    labels, names, rows: {label: {column: value}}, reference, settings, claims}`; `null`
    for a kind without one, or a job that has not succeeded."""
    return job_summary(jobs.get(job_id), store)
