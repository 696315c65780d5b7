"""The compare view: ``/compare?jobs=<id>,<id>,...`` (ids or unique prefixes) or
``/compare?batch=<label>`` puts the pictures of several jobs side by side.

Pictures are paired by *role* (:mod:`service.compare_pictures`), not by file name: the
page shows one view at a time — every job's main pictures (its lead picture, or a score
job's reference and candidates, each a panel), the error maps, the signed difference of
each candidate to its reference (with its colour bar), or one artifact name — side by side
with linked zoom and pan, or two panels under an A/B slider; pixels stay square when
zoomed, and HDR images (EXR, through the preview route) get an exposure slider. Under the
cursor the page reads every panel's pixel value (``/api/artifacts/{digest}/pixels``: linear
values of EXRs, a FLIP map's error). The view, mode, zoom, exposure and A/B choice are
kept in the address, so a view can be shared. Jobs with ``curves.json`` (training runs)
get their curves overlaid in one chart, a series at a time; jobs with ``pareto.json``
(reports) their panels, a panel (error against cost) at a time. A batch gets its method x
metric table (nerfbaselines style, the one ``matforge results --pivot`` prints): a row per
method over the rows of all its jobs, mean metrics and costs, the best per column marked.
The server gathers the jobs, their pictures with roles, their charts and the table;
``static/js/compare_pictures.js`` and ``static/js/compare.js`` do the rest.
"""

from __future__ import annotations

import re
from typing import Annotated, Any

from fastapi import APIRouter, Query, Request, Response
from fastapi.responses import HTMLResponse

from jobapi.errors import SpecError
from service import compare_pictures  # a module: it imports routes.dashboard
from service.deps import JOB_ID_PATTERN, JobsDep, PageAuth, StoreDep, set_token_cookie
from service.results import MAX_JOBS as MAX_ROW_JOBS
from service.results import in_given_order, job_rows
from service.routes.dashboard import methods_view, templates
from storage.artifacts import ArtifactStore
from storage.job_queries import resolve_job_id
from storage.jobs import Job, JobStore

router = APIRouter(include_in_schema=False)

JOB_ID = re.compile(JOB_ID_PATTERN)
#: At most this many jobs side by side.
MAX_JOBS = 12


def _jobs(store: JobStore, ids: str | None, batch: str | None) -> list[Job]:
    if ids:
        wanted = [i.strip() for i in ids.split(",") if i.strip()]
        if len(wanted) > MAX_JOBS:
            raise SpecError([("query.jobs", f"at most {MAX_JOBS} jobs, got {len(wanted)}")])
        bad = [i for i in wanted if not JOB_ID.fullmatch(i)]
        if bad:  # as /api/jobs/{id} answers a malformed id: 422, not 404 (issue 21, item 12)
            raise SpecError(
                [("query.jobs", f"not a job id: {bad[0]!r}; expected up to 32 lowercase hex "
                                "digits (an id or a unique prefix of one)")]
            )  # fmt: skip
        full = list(dict.fromkeys(resolve_job_id(store, i) for i in wanted))
        return [store.get(i) for i in full]
    if batch:
        found = store.list_jobs(state="succeeded", limit=MAX_JOBS, batch=batch, sort="created")
        return [store.get(j.id) for j in found]
    return []


def panel(job: Job, jobs: JobStore) -> dict[str, Any]:
    """What the page shows of one job: its title, link, pictures by role
    (:func:`service.compare_pictures.job_pictures`) and chart documents."""
    curves = next((a for a in job.artifacts if a.name == "curves.json"), None)
    pareto = next((a for a in job.artifacts if a.name == "pareto.json"), None)
    return {
        "id": job.id,
        "curves": f"/api/artifacts/{curves.digest}" if curves else None,
        "pareto": f"/api/artifacts/{pareto.digest}" if pareto else None,
        "short": job.id[:12],
        "title": job.name or job.kind,
        "kind": job.kind,
        "state": job.state,
        **compare_pictures.job_pictures(job, jobs),
    }


def batch_methods(jobs: JobStore, store: ArtifactStore, batch: str) -> dict[str, Any] | None:
    """The batch's method x metric table (:func:`service.routes.dashboard.methods_view`,
    the table ``matforge results --pivot`` prints for the batch's file): the result rows of
    every succeeded job of the batch (not only the panels shown), oldest first, each row's
    ``step`` its job's name, a step's candidates in the order its spec gives them."""
    found = jobs.list_jobs(state="succeeded", limit=MAX_ROW_JOBS, batch=batch, sort="created")
    rows: list[dict[str, Any]] = []
    for listed in found:
        job = jobs.get(listed.id)  # with artifacts
        got = job_rows(job, jobs, store)
        if job.name:
            got = [r.with_(step=job.name) for r in got]
        rows += [r.document() for r in in_given_order(got, job.spec)]
    return methods_view(rows)


@router.get("/compare", response_class=HTMLResponse)
def compare_page(
    request: Request,
    cookie_token: PageAuth,
    jobs: JobsDep,
    store: StoreDep,
    ids: Annotated[str | None, Query(alias="jobs", max_length=800)] = None,
    batch: Annotated[str | None, Query(max_length=200)] = None,
) -> Response:
    """Several jobs' pictures side by side (see the module docstring)."""
    panels = [panel(j, jobs) for j in _jobs(jobs, ids, batch)]
    methods = batch_methods(jobs, store, batch) if batch and not ids else None
    context = {
        "panels": panels,
        "views": compare_pictures.compare_views(panels),
        "batch": batch,
        "methods": methods,
    }
    response = templates.TemplateResponse(request, "compare.html", context)
    set_token_cookie(response, cookie_token, request)
    return response
