"""The compare view: ``/compare?jobs=<id>,<id>,...`` (ids or unique prefixes) or
``/compare?batch=<label>`` puts the pictures of several jobs side by side.

The page shows one artifact name at a time (``image.exr``, ``preview.png``, ...) for every
job that has it: side by side with linked zoom and pan, or two of them under an A/B
slider; pixels stay square when zoomed, and HDR images (EXR, through the preview route)
get an exposure slider. Jobs with ``curves.json`` (training runs) get their curves overlaid
in one chart, a series at a time; jobs with ``pareto.json`` (reports) their panels, a panel
(error against cost) at a time. The server only gathers the jobs, their pictures and
curves; ``static/js/compare.js`` does the rest.
"""

from __future__ import annotations

import re
from collections import Counter
from typing import Annotated, Any

from fastapi import APIRouter, Query, Request, Response
from fastapi.responses import HTMLResponse

from jobapi.errors import SpecError
from service.deps import JOB_ID_PATTERN, JobsDep, PageAuth, set_token_cookie
from service.routes.dashboard import EXR_TYPE, picture_views, templates
from storage.job_queries import resolve_job_id
from storage.jobs import Job, JobStore

router = APIRouter(include_in_schema=False)

JOB_ID = re.compile(JOB_ID_PATTERN)
#: At most this many jobs side by side.
MAX_JOBS = 12
#: Artifact names shown first when several are common, most telling first.
PREFERRED = ("image.exr", "preview.png")


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


def panel(job: Job) -> dict[str, Any]:
    """What the page shows of one job: its title, link and pictures (EXRs flagged HDR)."""
    pictures = []
    exr = {a.name for a in job.artifacts if a.media_type == EXR_TYPE or a.name.endswith(".exr")}
    for image in picture_views(job.artifacts, job.kind):
        pictures.append({"name": image["name"], "src": image["src"], "hdr": image["name"] in exr})
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
        "images": pictures,
    }


def artifact_choices(panels: list[dict[str, Any]]) -> list[str]:
    """Picture names, those most jobs have first (the preferred ones first among equals)."""
    counts = Counter(i["name"] for p in panels for i in p["images"])

    def key(name: str) -> tuple[int, int, str]:
        rank = PREFERRED.index(name) if name in PREFERRED else len(PREFERRED)
        return (-counts[name], rank, name)

    return sorted(counts, key=key)


@router.get("/compare", response_class=HTMLResponse)
def compare_page(
    request: Request,
    cookie_token: PageAuth,
    jobs: JobsDep,
    ids: Annotated[str | None, Query(alias="jobs", max_length=800)] = None,
    batch: Annotated[str | None, Query(max_length=200)] = None,
) -> Response:
    """Several jobs' pictures side by side (see the module docstring)."""
    panels = [panel(j) for j in _jobs(jobs, ids, batch)]
    context = {"panels": panels, "choices": artifact_choices(panels), "batch": batch}
    response = templates.TemplateResponse(request, "compare.html", context)
    set_token_cookie(response, cookie_token, request)
    return response
