"""A job's result table, from its kind's summary hook (:attr:`jobapi.kinds.Kind.summary`).

The dashboard's job page and ``GET /api/jobs/{id}/summary`` (which the CLI's batch table
reads) both come through here; neither knows any kind's fields.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from jobapi.results import ArtifactReader
from service import kinds
from storage.artifacts import ArtifactStore
from storage.errors import StorageError
from storage.jobs import ArtifactRecord, Job

#: JSON artifacts above this size are not read for a summary (the page links to them).
MAX_INLINE_JSON = 2 * 1024 * 1024


def read_json(store: ArtifactStore, digest: str) -> Any:
    """A small JSON object from the store, or ``None`` if it is too big, missing or corrupt
    (the download route reports the problem)."""
    try:
        if store.size(digest) > MAX_INLINE_JSON:
            return None
        return json.loads(store.read(digest))
    except (StorageError, ValueError):
        return None


def artifact_reader(store: ArtifactStore, artifacts: list[ArtifactRecord]) -> ArtifactReader:
    """``read(name)`` for a summary hook: the job's JSON artifact ``name`` (matched on the
    file name), parsed, or ``None``."""

    def read(name: str) -> Any:
        rec = next((a for a in artifacts if Path(a.name).name == name), None)
        return read_json(store, rec.digest) if rec else None

    return read


def job_summary(job: Job, store: ArtifactStore) -> dict[str, Any] | None:
    """The job's result table as JSON (:meth:`jobapi.results.ResultTable.document`), or
    ``None`` when its kind has no summary hook or the job no table (yet)."""
    try:
        kind = kinds.get_kind(job.kind)
    except KeyError:
        return None
    if kind.summary is None or job.state != "succeeded":
        return None
    table = kind.summary(artifact_reader(store, job.artifacts))
    return table.document() if table is not None else None
