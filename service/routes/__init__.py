"""The routers of the app, one per resource. :func:`service.api.create_app` includes them in
the order of :data:`ROUTERS`."""

from __future__ import annotations

from fastapi import APIRouter

from service.routes import artifacts, compare, dashboard, jobs, meta, results

ROUTERS: tuple[APIRouter, ...] = (
    meta.health_router,
    meta.router,
    jobs.router,
    artifacts.router,
    results.router,
    dashboard.router,
    compare.router,
)

__all__ = ["ROUTERS", "artifacts", "compare", "dashboard", "jobs", "meta", "results"]
