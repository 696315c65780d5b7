"""The dashboard: server-rendered pages (Jinja2) whose small scripts poll the JSON API.

``/`` lists the jobs with live state and progress; ``/jobs/{id}`` shows one job: spec,
manifest, artifacts, image previews (PNGs such as ``curves.png``, ``pareto.png``) and the
result table its kind's summary hook returns (:attr:`jobapi.kinds.Kind.summary`); the
dashboard knows no kind's fields.
Static files (our CSS and JS, and the vendored Chart.js) are served from ``/static`` behind
the same token check as every page.
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import Any

from fastapi import APIRouter, Request, Response
from fastapi.responses import HTMLResponse
from fastapi.staticfiles import StaticFiles
from fastapi.templating import Jinja2Templates
from markupsafe import Markup, escape
from starlette.datastructures import Headers
from starlette.requests import HTTPConnection
from starlette.responses import JSONResponse
from starlette.types import Receive, Scope, Send

from jobapi.kinds import Figure
from jobapi.params import JOB_REF, SHA_REF
from service import kinds
from service.deps import (
    JobId,
    JobsDep,
    PageAuth,
    StoreDep,
    request_authorized,
    set_token_cookie,
)
from service.metric_directions import best_labels, direction
from service.summaries import job_summary, read_json
from storage.artifacts import ArtifactStore
from storage.errors import NotFoundError
from storage.jobs import STATES, ArtifactRecord, Job, JobStore

DASHBOARD_DIR = Path(__file__).resolve().parent.parent / "dashboard"
router = APIRouter(include_in_schema=False)

IMAGE_TYPES = frozenset({"image/png", "image/jpeg"})
EXR_TYPE = "image/x-exr"


def fmt_number(value: Any) -> str:
    """A metric value for a table: 4 significant digits, ``–`` for missing."""
    if isinstance(value, bool) or value is None:
        return "–" if value is None else str(value)
    if isinstance(value, int | float):
        return f"{value:.4g}"
    return str(value)


def fmt_filesize(n: Any) -> str:
    """Bytes as ``"12.3 KiB"``."""
    size = float(n or 0)
    for unit in ("B", "KiB", "MiB", "GiB"):
        if size < 1024 or unit == "GiB":
            return f"{size:.0f} {unit}" if unit == "B" else f"{size:.1f} {unit}"
        size /= 1024
    return f"{size:.1f} GiB"


def fmt_seconds(s: Any) -> str:
    """A duration in seconds as ``"850 ms"``, ``"12.3 s"``, ``"4 min 05 s"`` or ``"2 h 05
    min"``: rounded once, then split (``MF.seconds`` in ``common.js`` says the same)."""
    if not isinstance(s, int | float):
        return "–"
    if s < 0.9995:  # (rounded, 0.9996 s would read "1000 ms")
        return f"{s * 1000:.0f} ms"
    if s < 59.95:  # (rounded, 59.96 s would read "60.0 s")
        return f"{s:.1f} s"
    whole = int(round(s))
    if whole < 3600:
        minutes, sec = divmod(whole, 60)
        return f"{minutes} min {sec:02d} s"
    hours, minutes = divmod(int(round(s / 60)), 60)
    return f"{hours} h {minutes:02d} min"


def fmt_epoch(t: Any) -> str:
    """Unix time as ISO 8601 UTC (the page shows it in local time)."""
    if not isinstance(t, int | float):
        return ""
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(t))


def breakable(name: Any) -> Markup:
    """A column name that may wrap after its dots (``baseline.rgb.rel``), HTML-escaped."""
    return Markup(escape(str(name)).replace(".", Markup(".<wbr>")))


templates = Jinja2Templates(directory=DASHBOARD_DIR / "templates")
templates.env.filters.update(
    num=fmt_number, filesize=fmt_filesize, seconds=fmt_seconds, epoch=fmt_epoch, wbr=breakable
)


class ProtectedStatic(StaticFiles):
    """``StaticFiles`` that asks for the token (header or dashboard cookie) like any route."""

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http":
            settings = scope["app"].state.settings
            conn = HTTPConnection(scope)
            if not request_authorized(settings, Headers(scope=scope), conn.cookies):
                detail = "missing or wrong bearer token"
                response = JSONResponse(
                    {"detail": detail, "error": detail},
                    status_code=401,
                    headers={"WWW-Authenticate": "Bearer"},
                )
                await response(scope, receive, send)
                return
        await super().__call__(scope, receive, send)


def static_files() -> ProtectedStatic:
    """The app mounted at ``/static``."""
    return ProtectedStatic(directory=DASHBOARD_DIR / "static")


def render_error_page(request: Request, status: int, message: str) -> Response:
    """An HTML error page for a browser that asked for a dashboard page."""
    return templates.TemplateResponse(
        request, "error.html", {"status": status, "message": message}, status_code=status
    )


def _figure(kind: str, name: str) -> Figure | None:
    try:
        return kinds.get_kind(kind).figure(name)
    except KeyError:  # a kind no longer registered
        return None


def picture_views(artifacts: list[ArtifactRecord], kind: str = "") -> list[dict[str, Any]]:
    """Image previews: PNGs as they are, EXRs through the preview route. The kind's lead
    picture comes first (:attr:`jobapi.kinds.Figure.lead`), FLIP maps last; a picture the
    kind describes as a plot carries its axes."""
    out: list[dict[str, Any]] = []
    for a in artifacts:
        if a.media_type in IMAGE_TYPES:
            src = f"/api/artifacts/{a.digest}"
        elif a.media_type == EXR_TYPE or a.name.endswith(".exr"):
            src = f"/api/artifacts/{a.digest}/preview.png"
        else:
            continue
        is_flip = Path(a.name).name.startswith("flip_")
        caption = a.name + (" (tone-mapped preview)" if src.endswith("preview.png") else "")
        figure = _figure(kind, a.name)
        out.append(
            {
                "name": a.name,
                "src": src,
                "caption": caption,
                "group": "flip" if is_flip else "lead" if figure and figure.lead else "image",
                "note": figure.caption if figure else "",
                "x": figure.x if figure else None,
                "y": figure.y if figure else None,
            }
        )
    order = {"lead": 0, "image": 1, "flip": 2}
    return sorted(out, key=lambda i: (order[i["group"]], i["name"]))


def _with_directions(table: dict[str, Any] | None) -> dict[str, Any] | None:
    """The result table with each column's better direction and its best row, for the
    table's highlight and the charts (see :mod:`service.metric_directions`)."""
    if not table:
        return table
    names = list(table.get("names") or [])
    return {
        **table,
        "better": {n: direction(n) for n in names},
        # a dataset's items are measured, not ranked: no "best: <material>"
        "best": best_labels(table.get("rows") or {}, names) if table.get("ranked", True) else {},
    }


def _param_strings(obj: Any, path: str = "") -> list[tuple[str, str]]:
    if isinstance(obj, str):
        return [(path, obj)]
    if isinstance(obj, dict):
        return [x for k, v in obj.items() for x in _param_strings(v, f"{path}.{k}" if path else k)]
    if isinstance(obj, list):
        return [x for i, v in enumerate(obj) for x in _param_strings(v, f"{path}.{i}")]
    return []


def input_pictures(job: Job, jobs: JobStore) -> list[dict[str, Any]]:
    """The pictures a job's params refer to (a score's reference and candidates, say),
    each labelled with its param and linked to the job that made it; a ``reference``
    first."""
    out = []
    for loc, value in _param_strings(job.spec.get("params") or {}):
        m, record, source = JOB_REF.match(value), None, None
        try:
            if m:
                record, source = jobs.artifact(m["job"], m["name"]), m["job"]
            elif (s := SHA_REF.match(value)) is not None:
                record = jobs.find_digest(s["digest"])
        except NotFoundError:
            continue
        if record is None:
            continue
        views = picture_views([record])
        if views:
            out.append({**views[0], "param": loc, "job": source, "ref": value})
    return sorted(out, key=lambda i: (i["param"].split(".")[0] != "reference", i["param"]))


#: JSON artifacts the job page draws as interactive charts (``static/js/plots.js``), by
#: name: ``curves.json`` (series against ``step``) and ``pareto.json`` (cost against
#: accuracy per configuration, with the front).
PLOTTED = ("curves.json", "pareto.json")


def _live_plots(job: Job) -> dict[str, str]:
    """While a job of a kind that makes ``curves.json`` runs: the route of its live curves
    (``static/js/plots.js`` polls it until the page reloads with the artifact)."""
    if job.finished:
        return {}
    try:
        makes = kinds.get_kind(job.kind).artifacts
    except KeyError:
        return {}
    return {"live-curves": f"/api/jobs/{job.id}/live/curves.json"} if "curves.json" in makes else {}


#: The artifact that holds the tidy result rows a job read (a report's inputs): its
#: method x metric table is shown on the job page.
ROWS_ARTIFACT = "rows.json"


#: SI prefixes of the method table's costs and metrics (``_si``), by power of 1000.
_PREFIXES = {-4: "p", -3: "n", -2: "\u00b5", -1: "m", 0: "", 1: "k", 2: "M", 3: "G", 4: "T"}


def _si(value: float, unit: str) -> str:
    """``value`` (in ``unit``) with an SI prefix and 4 significant digits: ``82.7 \u00b5s``,
    ``1.528 MB``; plain ``.4g`` without a unit."""
    if not unit:
        return f"{value:.4g}"
    if value == 0 or not math.isfinite(value):
        return f"{value:.4g} {unit}"
    power = max(-4, min(4, math.floor(math.log10(abs(value)) / 3)))
    return f"{value / 1000.0**power:.4g} {_PREFIXES[power]}{unit}"


def _unit(name: str) -> tuple[float, str]:
    """The scale to base units and the unit of a result-row column, from its name:
    ``*_ns``/``ns_per_eval`` nanoseconds (shown in s), ``*seconds`` s, ``*bytes*`` B,
    ``psnr`` dB; other metrics are unitless."""
    if name.endswith("_ns") or name.startswith("ns_"):
        return 1e-9, "s"
    if name.endswith("seconds"):
        return 1.0, "s"
    if "bytes" in name:
        return 1.0, "B"
    if name.startswith("psnr"):
        return 1.0, "dB"
    return 1.0, ""


def _shown(value: float, scale: float, unit: str) -> str:
    """A value of a column in ``unit`` (decibels take no SI prefix)."""
    return f"{value:.4g} dB" if unit == "dB" else _si(value * scale, unit)


def _pivot_cell(col: dict[str, Any], got: dict[str, Any] | None) -> dict[str, Any]:
    """One cell: its ``text`` (SI prefixes and units) and its raw ``value`` (the mean of a
    metric, the median of a cost; ``None`` for an empty cell)."""
    if got is None:
        return {"text": "", "value": None}
    scale, unit = _unit(str(col["name"]))
    if col["role"] != "metric":
        return {"text": _shown(got["median"], scale, unit), "value": got["median"]}
    text = _shown(got["mean"], scale, unit)
    std = got.get("std")
    if std is not None:
        text += f" \u00b1 {_shown(std, scale, unit) if unit else format(std, '.2g')}"
    return {"text": text, "value": got["mean"]}


def methods_view(rows: list[Any], by: str = "candidate") -> dict[str, Any] | None:
    """The method x metric table (:func:`service.results_pivot.pivot`, as ``matforge
    results --pivot`` prints it) of tidy result rows, ready for the ``_methods.html``
    partial: a row per method, each metric's mean ± spread and each cost's median, the best
    per column; ``None`` when the rows are not a list of rows or name a single method."""
    from service.results_pivot import pivot

    if not isinstance(rows, list) or not all(isinstance(r, dict) for r in rows):
        return None
    doc = pivot(rows, by)
    if len(doc["methods"]) < 2 or not doc["columns"]:
        return None
    return {
        "by": doc["by"],
        "columns": doc["columns"],
        "rows": [
            {
                "method": m,
                "cells": [_pivot_cell(c, doc["cells"][m].get(c["name"])) for c in doc["columns"]],
                "best": [doc["best"].get(c["name"]) == m for c in doc["columns"]],
            }
            for m in doc["methods"]
        ],
        "unranked": [{"column": c, "why": why} for c, why in doc.get("unranked", {}).items()],
    }


def methods_table(job: Job, store: ArtifactStore) -> dict[str, Any] | None:
    """:func:`methods_view` of the result rows in the job's ``rows.json`` (a report's
    inputs); ``None`` when the job has no such rows or a single method."""
    record = next((a for a in job.artifacts if a.name == ROWS_ARTIFACT), None)
    rows = read_json(store, record.digest) if record is not None else None
    if isinstance(rows, dict):
        rows = rows.get("rows")
    return methods_view(rows) if isinstance(rows, list) else None


def job_view(job: Job, store: ArtifactStore, jobs: JobStore | None = None) -> dict[str, Any]:
    """Everything the job page shows, from the job row and its (small) JSON artifacts."""
    manifest = read_json(store, job.manifest_digest) if job.manifest_digest else None
    return {
        "job": job.document(),
        "spec_json": json.dumps(job.spec, indent=2, sort_keys=True),
        "manifest": manifest if isinstance(manifest, dict) else None,
        "manifest_json": json.dumps(manifest, indent=2, sort_keys=True) if manifest else None,
        "images": picture_views(job.artifacts, job.kind),
        "inputs": input_pictures(job, jobs) if jobs is not None else [],
        "metrics": _with_directions(job_summary(job, store)),
        "methods": methods_table(job, store),
        "plots": {
            a.name.removesuffix(".json"): f"/api/artifacts/{a.digest}"
            for a in job.artifacts
            if a.name in PLOTTED
        }
        or _live_plots(job),
    }


@router.get("/", response_class=HTMLResponse)
def index(request: Request, cookie_token: PageAuth) -> Response:
    """The jobs list (rows are filled in and refreshed by ``static/js/jobs.js``)."""
    response = templates.TemplateResponse(
        request, "index.html", {"states": STATES, "kinds": sorted(kinds.all_kinds())}
    )
    set_token_cookie(response, cookie_token, request)
    return response


@router.get("/jobs/{job_id}", response_class=HTMLResponse)
def job_page(
    request: Request, cookie_token: PageAuth, job_id: JobId, jobs: JobsDep, store: StoreDep
) -> Response:
    """One job; ``static/js/job.js`` keeps state and progress live until it finishes.
    (``cookie_token`` comes first: the token is checked before the short id is looked up.)"""
    view = job_view(jobs.get(job_id), store, jobs)
    response = templates.TemplateResponse(request, "job.html", view)
    set_token_cookie(response, cookie_token, request)
    return response
