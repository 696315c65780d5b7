"""Service-level routes: health (the one route without auth), kinds and stats."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter

from service import kinds
from service.deps import AuthDep, JobsDep
from service.schemas import HealthPublic, KindPublic, StatsPublic

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
    """Every job kind with its summary, fixed artifact names and params JSON schema."""
    return [
        {
            "name": k.name,
            "summary": k.description,
            "artifacts": list(k.artifacts),
            "params_schema": k.params.model_json_schema(),
        }
        for k in kinds.all_kinds().values()
    ]


@router.get("/stats", response_model=StatsPublic, summary="Job counts by state")
def stats(jobs: JobsDep) -> dict[str, Any]:
    """How many jobs are in each of the five states."""
    counts = jobs.counts()
    return {"counts": counts, "total": sum(counts.values())}
