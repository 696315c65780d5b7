"""Service-level routes: health (the one route without auth), kinds and stats."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter

from service import kinds
from service.deps import AuthDep, JobsDep
from service.kind_docs import kind_document
from service.schemas import HealthPublic, KindPublic, PluginPublic, StatsPublic

health_router = APIRouter(prefix="/api", tags=["service"])
router = APIRouter(prefix="/api", tags=["service"], dependencies=[AuthDep])


@health_router.get("/health", response_model=HealthPublic, summary="Liveness")
async def health() -> dict[str, str]:
    """`{"status": "ok"}`; never needs a token."""
    # async: answered on the event loop, without a hop through the thread pool, whose
    # threads may be busy validating specs (issue 21, item 5)
    return {"status": "ok"}


@router.get("/kinds", response_model=list[KindPublic], summary="Registered job kinds")
def list_kinds() -> list[dict[str, Any]]:
    """Every job kind with its summary, fixed artifact names, params JSON schema and, for a
    plugin's kind, the package that added it."""
    return [kind_document(k) for k in kinds.all_kinds().values()]


@router.get("/plugins", response_model=list[PluginPublic], summary="Installed kind plugins")
def list_plugins() -> list[dict[str, Any]]:
    """Every entry point of the group ``matforge.kinds``: the kinds it added, or why it was
    not loaded (an import error, a name taken by a built-in kind, ...)."""
    return [p.document() for p in kinds.plugins()]


@router.get("/stats", response_model=StatsPublic, summary="Job counts by state")
def stats(jobs: JobsDep) -> dict[str, Any]:
    """How many jobs are in each of the five states."""
    counts = jobs.counts()
    return {"counts": counts, "total": sum(counts.values())}
