"""The dashboard: server-rendered pages (Jinja2) whose small scripts poll the JSON API.

``/`` lists the jobs with live state and progress; ``/jobs/{id}`` shows one job: spec,
manifest, artifacts, image previews (PNGs such as ``curves.png``, ``pareto.png``) and one
table: ``score``'s metrics per candidate, a training job's ``metrics.json`` per material
(``train.brdf``), or ``report.brdf``'s ``pareto.json`` per configuration with its claims.
Static files (our CSS and JS, and the vendored Chart.js) are served from ``/static`` behind
the same token check as every page.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

from fastapi import APIRouter, Request, Response
from fastapi.responses import HTMLResponse
from fastapi.staticfiles import StaticFiles
from fastapi.templating import Jinja2Templates
from starlette.datastructures import Headers
from starlette.requests import HTTPConnection
from starlette.responses import JSONResponse
from starlette.types import Receive, Scope, Send

from service import registry
from service.deps import (
    JobId,
    JobsDep,
    PageAuth,
    StoreDep,
    request_authorized,
    set_token_cookie,
)
from storage.artifacts import ArtifactStore
from storage.errors import StorageError
from storage.jobs import STATES, ArtifactRecord, Job

DASHBOARD_DIR = Path(__file__).resolve().parent.parent / "dashboard"
router = APIRouter(include_in_schema=False)

#: JSON artifacts above this size are linked, not rendered into the page.
MAX_INLINE_JSON = 2 * 1024 * 1024
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
    """A duration in seconds as ``"850 ms"``, ``"12.3 s"`` or ``"4 min 05 s"``."""
    if not isinstance(s, int | float):
        return "–"
    if s < 1:
        return f"{s * 1000:.0f} ms"
    if s < 60:
        return f"{s:.1f} s"
    minutes, sec = divmod(int(round(s)), 60)
    return f"{minutes} min {sec:02d} s"


def fmt_epoch(t: Any) -> str:
    """Unix time as ISO 8601 UTC (the page shows it in local time)."""
    if not isinstance(t, int | float):
        return ""
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(t))


templates = Jinja2Templates(directory=DASHBOARD_DIR / "templates")
templates.env.filters.update(
    num=fmt_number, filesize=fmt_filesize, seconds=fmt_seconds, epoch=fmt_epoch
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


def _read_json(store: ArtifactStore, digest: str) -> Any:
    """A small JSON object from the store, or ``None`` if it is too big, missing or corrupt
    (the page then links to it instead; the download route reports the problem)."""
    try:
        if store.size(digest) > MAX_INLINE_JSON:
            return None
        return json.loads(store.read(digest))
    except (StorageError, ValueError):
        return None


def _images(artifacts: list[ArtifactRecord]) -> list[dict[str, str]]:
    """Image previews: PNGs as they are, EXRs through the preview route; FLIP maps last."""
    out = []
    for a in artifacts:
        if a.media_type in IMAGE_TYPES:
            src = f"/api/artifacts/{a.digest}"
        elif a.media_type == EXR_TYPE or a.name.endswith(".exr"):
            src = f"/api/artifacts/{a.digest}/preview.png"
        else:
            continue
        is_flip = Path(a.name).name.startswith("flip_")
        caption = a.name + (" (tone-mapped preview)" if src.endswith("preview.png") else "")
        out.append(
            {
                "name": a.name,
                "src": src,
                "caption": caption,
                "group": "flip" if is_flip else "image",
            }
        )
    return sorted(out, key=lambda i: (i["group"] == "flip", i["name"]))


def _artifact_json(store: ArtifactStore, artifacts: list[ArtifactRecord], name: str) -> Any:
    rec = next((a for a in artifacts if Path(a.name).name == name), None)
    return _read_json(store, rec.digest) if rec else None


#: Columns of a training job's per-material table (``train.brdf`` ``metrics.json``).
MATERIAL_COLUMNS = ("family", "split", "smape", "mae", "smape_analytic", "mae_analytic")
#: Columns of ``train.fabric``'s ``metrics.json`` (held-out errors against the Monte Carlo
#: estimates, flattened; ``baseline.*``: the per-material mean predictor).
FABRIC_COLUMNS = (
    "pattern",
    "queries",
    "loss",
    "baseline.loss",
    "rgb.rel",
    "baseline.rgb.rel",
    "rgb.mse",
    "C_warp.rel",
    "C_weft.rel",
    "S_warp.rel",
    "S_weft.rel",
)
#: Columns of ``report.brdf``'s ``pareto.json`` points.
PARETO_COLUMNS = (
    "per_material_params",
    "n",
    "smape_mean",
    "smape_std",
    "smape_min",
    "smape_max",
    "ns_per_eval",
    "torch_ns",
    "bytes_per_material",
    "pareto",
)


def _table(
    title: str, header: str, rows: dict[str, dict[str, Any]], names: list[str], **extra: Any
) -> dict[str, Any]:
    """The view of one metrics table: ``labels`` (rows), ``names`` (columns), ``rows``."""
    return {
        "title": title,
        "label_header": header,
        "labels": list(rows),
        "names": names,
        "rows": rows,
        **extra,
    }


def _flat(doc: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested metrics as dotted keys: ``{"rgb": {"rel": x}}`` -> ``{"rgb.rel": x}``."""
    out: dict[str, Any] = {}
    for key, value in doc.items():
        if isinstance(value, dict):
            out.update(_flat(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


def _per_material(doc: dict[str, Any]) -> dict[str, Any] | None:
    """A training ``metrics.json`` (``{"materials": [{"name", ...}], "mean": {...}}``):
    one row per material, then the mean. ``train.brdf`` rows show :data:`MATERIAL_COLUMNS`;
    ``train.fabric`` rows (nested per component) show :data:`FABRIC_COLUMNS`."""
    mats = [m for m in doc["materials"] if isinstance(m, dict) and "name" in m]
    if not mats:
        return None
    columns = MATERIAL_COLUMNS if any("smape" in m for m in mats) else FABRIC_COLUMNS
    rows = {str(m["name"]): {k: _flat(m).get(k) for k in columns} for m in mats}
    if isinstance(doc.get("mean"), dict):
        rows["mean"] = {k: _flat(doc["mean"]).get(k) for k in columns}
    names = [k for k in columns if any(r.get(k) is not None for r in rows.values())]
    return _table("Metrics per material", "Material", rows, names, settings=doc.get("settings"))


def _pareto(doc: dict[str, Any]) -> dict[str, Any] | None:
    """``report.brdf``'s ``pareto.json``: one row per configuration, and its claims."""
    points = [p for p in doc.get("points", []) if isinstance(p, dict) and "config" in p]
    if not points:
        return None
    rows = {str(p["config"]): {k: p.get(k) for k in PARETO_COLUMNS} for p in points}
    claims = [c for c in doc.get("claims", []) if isinstance(c, dict) and "claim" in c]
    return _table(
        "Accuracy against cost",
        "Configuration",
        rows,
        list(PARETO_COLUMNS),
        claims=claims,
        settings=doc.get("settings"),
    )


def _with_material_rows(
    rows: dict[str, dict[str, Any]], per: dict[str, Any]
) -> dict[str, dict[str, Any]]:
    """Each label's row followed by its ``"<label> / <material>"`` rows."""
    out: dict[str, dict[str, Any]] = {}
    for label, row in rows.items():
        out[label] = row
        for name, vals in (per.get(label) or {}).items():
            if isinstance(vals, dict):
                out[f"{label} / {name}"] = vals
    return out


def _metrics(store: ArtifactStore, artifacts: list[ArtifactRecord]) -> dict[str, Any] | None:
    """The job's table: ``score``'s ``metrics.json`` (one row per candidate), a training
    job's ``metrics.json`` (one row per material) or ``report.brdf``'s ``pareto.json``;
    as ``{"title", "label_header", "reference", "labels", "names", "rows", "settings"}``."""
    doc = _artifact_json(store, artifacts, "metrics.json")
    if isinstance(doc, dict) and isinstance(doc.get("materials"), list):
        return _per_material(doc)
    if not isinstance(doc, dict) or not isinstance(doc.get("metrics"), dict):
        pareto = _artifact_json(store, artifacts, "pareto.json")
        return _pareto(pareto) if isinstance(pareto, dict) else None
    table: dict[str, Any] = doc["metrics"]
    names: list[str] = []
    for values in table.values():
        for m in values if isinstance(values, dict) else {}:
            if m not in names:
                names.append(str(m))
    rows = {
        label: {m: v for m, v in (vals.items() if isinstance(vals, dict) else [])}
        for label, vals in table.items()
    }
    per = doc.get("per_material")  # whole models against a set of tables
    if isinstance(per, dict):
        rows = _with_material_rows(rows, per)
    reference = doc.get("reference")
    return _table(
        "Metrics",
        "Candidate",
        rows,
        names,
        settings=doc.get("settings"),
        reference=reference if isinstance(reference, str) else None,
    )


def job_view(job: Job, store: ArtifactStore) -> dict[str, Any]:
    """Everything the job page shows, from the job row and its (small) JSON artifacts."""
    manifest = _read_json(store, job.manifest_digest) if job.manifest_digest else None
    return {
        "job": job.document(),
        "spec_json": json.dumps(job.spec, indent=2, sort_keys=True),
        "manifest": manifest if isinstance(manifest, dict) else None,
        "manifest_json": json.dumps(manifest, indent=2, sort_keys=True) if manifest else None,
        "images": _images(job.artifacts),
        "metrics": _metrics(store, job.artifacts),
    }


@router.get("/", response_class=HTMLResponse)
def index(request: Request, cookie_token: PageAuth) -> Response:
    """The jobs list (rows are filled in and refreshed by ``static/js/jobs.js``)."""
    response = templates.TemplateResponse(
        request, "index.html", {"states": STATES, "kinds": sorted(registry.kinds())}
    )
    set_token_cookie(response, cookie_token)
    return response


@router.get("/jobs/{job_id}", response_class=HTMLResponse)
def job_page(
    request: Request, job_id: JobId, cookie_token: PageAuth, jobs: JobsDep, store: StoreDep
) -> Response:
    """One job; ``static/js/job.js`` keeps state and progress live until it finishes."""
    response = templates.TemplateResponse(request, "job.html", job_view(jobs.get(job_id), store))
    set_token_cookie(response, cookie_token)
    return response
