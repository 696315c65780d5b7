"""``/api/results``: every measured value as one long-format row, JSON or CSV.

``GET /api/results`` reads the named jobs (``job=``, repeatable, in that order) or the
newest succeeded ones; ``POST /api/results/batch`` takes a batch's steps and answers their
rows in step order. Rows come from :mod:`service.results`; the columns are
:data:`jobapi.rows.COLUMNS`. CSV when ``format=csv`` or when ``Accept`` prefers
``text/csv``; JSON otherwise.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from fastapi import APIRouter, Depends, Query, Request, Response
from fastapi.exceptions import RequestValidationError
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from jobapi.errors import SpecError
from jobapi.rows import ResultRow
from service.deps import JOB_ID_PATTERN, AuthDep, JobsDep, SettingsDep, StoreDep
from service.parse_threads import off_loop
from service.results import (
    MAX_JOBS,
    RowFilter,
    batch_rows,
    check_row_filter,
    rows_csv,
    select_rows,
)
from service.schemas import ErrorPublic, ResultRowPublic
from service.spec_text import parse_json_text
from service.workers.backend import identity_variant

router = APIRouter(prefix="/api/results", tags=["results"], dependencies=[AuthDep])
CSV = "text/csv"


class BatchStep(BaseModel):
    """A step of a batch file: its name and its spec (``step:`` refs allowed)."""

    model_config = ConfigDict(extra="forbid")
    name: str = Field(min_length=1, max_length=200)
    spec: dict[str, Any] = Field(
        description="the step's job spec, as `POST /api/jobs` takes it (`step:<name>` refs "
        "to earlier steps allowed); its `kind` is one of the registered kinds",
        # The kinds are filled in when the OpenAPI document is built (service.api).
        json_schema_extra={"required": ["kind"], "properties": {"kind": {"type": "string"}}},
    )


class BatchQuery(BaseModel):
    """The body of ``POST /api/results/batch``: the batch's steps, in order."""

    model_config = ConfigDict(extra="forbid")
    steps: list[BatchStep] = Field(min_length=1, max_length=1000)


class StepPublic(BaseModel):
    step: str
    kind: str | None
    job: str | None
    state: Literal["succeeded", "missing"]


class BatchResultsPublic(BaseModel):
    steps: list[StepPublic]
    rows: list[ResultRowPublic]


Format = Annotated[
    Literal["json", "csv"] | None,
    Query(description="`csv` or `json`; default: `Accept: text/csv` gives CSV, else JSON"),
]
KindQ = Annotated[
    str | None, Query(max_length=64, description="only rows of this job kind (422 if none)")
]
DatasetQ = Annotated[
    str | None, Query(max_length=200, description="only this dataset (a ref or its job id)")
]
MetricQ = Annotated[
    list[str],
    Query(
        max_length=64,
        description="only these metrics (old names too: `smape` keeps `brdf.smape`; a name "
        "no kind declares is a 422 with the closest ones)",
    ),
]
CandidateQ = Annotated[str | None, Query(max_length=200, description="only this candidate")]
SceneQ = Annotated[str | None, Query(max_length=64, description="only this scene")]
_CSV_DOC: dict[int | str, dict[str, Any]] = {
    200: {"content": {CSV: {"schema": {"type": "string"}}}},
    404: {"model": ErrorPublic, "description": "no such job"},
    422: {"model": ErrorPublic, "description": "invalid input"},
}


def _wants_csv(request: Request, fmt: str | None) -> bool:
    if fmt is not None:
        return fmt == "csv"
    accept = request.headers.get("accept", "")
    return CSV in accept and "application/json" not in accept


def _csv(rows: list[ResultRow]) -> Response:
    return Response(rows_csv(rows), media_type=f"{CSV}; charset=utf-8")


@router.get("", response_model=list[ResultRowPublic], responses=_CSV_DOC, summary="Result rows")
def get_results(
    request: Request,
    jobs: JobsDep,
    store: StoreDep,
    job: Annotated[
        list[Annotated[str, Field(pattern=JOB_ID_PATTERN)]],
        Query(max_length=1000, description="only these jobs (ids), in this order"),
    ] = [],  # noqa: B006 (FastAPI copies query defaults)
    kind: KindQ = None,
    dataset: DatasetQ = None,
    metric: MetricQ = [],  # noqa: B006
    candidate: CandidateQ = None,
    scene: SceneQ = None,
    limit: Annotated[
        int, Query(ge=1, le=MAX_JOBS, description="newest succeeded jobs read, without job=")
    ] = MAX_JOBS,
    format: Format = None,
) -> Any:
    """Every value the jobs measured, one row each: job, kind, dataset, scene, candidate,
    material, config, metric, value, lower_is_better, seed and the costs."""
    where = check_row_filter(RowFilter(kind=kind, dataset=dataset, metric=tuple(metric),
                                       candidate=candidate, scene=scene))  # fmt: skip
    rows = select_rows(jobs, store, job_ids=job, where=where, max_jobs=limit)
    if _wants_csv(request, format):
        return _csv(rows)
    return [r.document() for r in rows]


def parse_batch_body(raw: bytes) -> BatchQuery:
    """The body of ``POST /api/results/batch``, parsed as a spec is (hostile input refused
    before anything is built) and validated; 422 (``RequestValidationError`` or
    ``SpecError``) otherwise."""
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise SpecError([("body", "the request body is not UTF-8 text")]) from None
    doc = parse_json_text(text, "body")
    try:
        return BatchQuery.model_validate(doc)
    except ValidationError as exc:
        errors = [{**e, "loc": ("body", *e["loc"])} for e in exc.errors(include_url=False)]
        raise RequestValidationError(errors) from None


async def batch_body(request: Request) -> BatchQuery:
    """The batch, read here (a body over the limit is a 413, also when sent chunked) and
    parsed in a worker thread, never on the event loop (issue 21, items 5 and 12)."""
    raw = await request.body()
    return await off_loop(parse_batch_body, raw, size=len(raw))


#: The request body in the OpenAPI document (the schemas are added by
#: :func:`service.api.build_openapi`, from :data:`OPENAPI_MODELS`).
_BATCH_BODY_DOC: dict[str, Any] = {
    "requestBody": {
        "required": True,
        "content": {"application/json": {"schema": {"$ref": "#/components/schemas/BatchQuery"}}},
    }
}
OPENAPI_MODELS: tuple[type[BaseModel], ...] = (BatchQuery,)


@router.post(
    "/batch",
    response_model=BatchResultsPublic,
    responses={
        **_CSV_DOC,
        413: {"model": ErrorPublic, "description": "body over the JSON size limit"},
        422: {
            "model": ErrorPublic,
            "description": "invalid input: a query parameter, the body, or a step's spec "
            "that does not validate (`error` names the step and the field)",
        },
    },
    openapi_extra=_BATCH_BODY_DOC,
    summary="A batch's rows",
)
def post_batch_results(
    body: Annotated[BatchQuery, Depends(batch_body)],
    request: Request,
    jobs: JobsDep,
    store: StoreDep,
    settings: SettingsDep,
    kind: KindQ = None,
    dataset: DatasetQ = None,
    metric: MetricQ = [],  # noqa: B006
    candidate: CandidateQ = None,
    scene: SceneQ = None,
    format: Format = None,
) -> Any:
    """The rows of a batch's steps in step order (each row names its `step`), and each
    step's job: the succeeded job of its spec once its `step:` refs name the earlier
    steps' jobs (`missing` if there is none). A spec that does not validate is a 422."""
    where = check_row_filter(RowFilter(kind=kind, dataset=dataset, metric=tuple(metric),
                                       candidate=candidate, scene=scene))  # fmt: skip
    variant = identity_variant(settings)  # a sync route: in the thread pool already
    result = batch_rows([s.model_dump() for s in body.steps], jobs, store, where, variant)
    if _wants_csv(request, format):
        return _csv(result.rows)
    return result.document()
