"""A data directory's job queue and artifact store for the diagnostics in ``tools/``.

The diagnostics read a finished study's jobs through :class:`storage.jobs.JobStore` and
:class:`storage.artifacts.ArtifactStore` (the same paths as ``matforge serve``:
:class:`service.settings.Settings`), never with SQL of their own, so a change of the
queue's schema cannot break them silently.
"""

from __future__ import annotations

from pathlib import Path

from service.settings import Settings
from storage.artifacts import ArtifactStore
from storage.jobs import Job, JobStore


def open_data_dir(data_dir: Path) -> tuple[JobStore, ArtifactStore]:
    """``(jobs, store)`` of ``data_dir``; ``SystemExit`` naming it when it holds no jobs."""
    settings = Settings(data_dir=data_dir)
    if not settings.db_path.is_file():
        raise SystemExit(f"{data_dir}: not a matforge data directory (no {settings.db_path.name})")
    return JobStore(settings.db_path), ArtifactStore(settings.store_dir)


def succeeded(jobs: JobStore, kind: str | None = None) -> list[Job]:
    """Every succeeded job (of ``kind``), oldest first, with its artifacts."""
    listed = jobs.list_jobs(state="succeeded", kind=kind, limit=1 << 30, sort="created")
    return [jobs.get(j.id) for j in listed]


def latest_artifact(jobs: JobStore, store: ArtifactStore, kind: str, name: str) -> bytes:
    """The bytes of artifact ``name`` of the newest succeeded ``kind`` job that has one."""
    for job in reversed(succeeded(jobs, kind)):
        for art in job.artifacts:
            if art.name == name:
                return store.read(art.digest)
    raise SystemExit(f"no finished {kind} job with {name}")
