"""Finished jobs as rows hooks read them (:class:`jobapi.rows.RowSource`), over a job queue
and an artifact store: for the REST API and the CLI (``service.results``) and for report
kinds that gather other jobs' rows (``report.pareto``)."""

from __future__ import annotations

import json
import logging
import re
from pathlib import Path
from typing import Any

from jobapi.kinds import registered
from jobapi.rows import JobFacts, ResultRow, RowSource
from storage.artifacts import ArtifactStore
from storage.errors import NotFoundError, StorageError
from storage.jobs import Job, JobStore

log = logging.getLogger(__name__)

#: JSON artifacts above this size are not read for rows.
MAX_JSON_BYTES = 2 * 1024 * 1024
_JOB_ID = re.compile(r"^job:(?P<job>[0-9a-f]{32})(?:/.+)?$")


def job_id_of_ref(ref: str) -> str | None:
    """The job id of ``job:<id>`` or ``job:<id>/<name>``, else ``None``."""
    m = _JOB_ID.match(ref)
    return m["job"] if m else None


def job_facts(job: Job, measured: dict[str, Any] | None = None) -> JobFacts:
    """The :class:`JobFacts` of a queue row (``run_seconds`` from its start and end;
    ``measured``: the timings of its manifest, see :func:`measured_timings`)."""
    run_s = None
    if job.started_at is not None and job.finished_at is not None:
        run_s = job.finished_at - job.started_at
    params = job.spec.get("params") if isinstance(job.spec, dict) else None
    return JobFacts(
        id=job.id,
        kind=job.kind,
        seed=job.seed,
        name=job.name,
        params=params if isinstance(params, dict) else {},
        run_seconds=run_s,
        measured=measured or {},
    )


def measured_timings(job: Job, store: ArtifactStore) -> dict[str, Any]:
    """The timings ``job``'s kind measured itself (``timings.measured`` of its manifest),
    ``{}`` when it has no manifest or the manifest has none."""
    digest = getattr(job, "manifest_digest", None)
    if not digest:
        return {}
    try:
        if store.size(digest) > MAX_JSON_BYTES:
            return {}
        doc = json.loads(store.read(digest))
    except (StorageError, ValueError):
        return {}
    got = (doc.get("timings") or {}).get("measured") if isinstance(doc, dict) else None
    if not isinstance(got, dict):
        return {}
    out: dict[str, Any] = {}
    for k, v in got.items():
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            out[str(k)] = float(v)
        elif isinstance(v, dict):
            out[str(k)] = v
    return out


class StoreSource:
    """A succeeded job of a queue and a store, as a rows hook reads it."""

    def __init__(self, job: Job, jobs: JobStore, store: ArtifactStore) -> None:
        self._jobs, self._store = jobs, store
        self._artifacts = {Path(a.name).name: a for a in job.artifacts}
        self.job = job_facts(job, measured_timings(job, store))

    def read(self, name: str) -> Any:
        """The JSON artifact ``name`` (matched on the file name), parsed; ``None`` if the job
        has none, or it is too large, missing from the store or not JSON."""
        rec = self._artifacts.get(name)
        if rec is None:
            return None
        try:
            if self._store.size(rec.digest) > MAX_JSON_BYTES:
                return None
            return json.loads(self._store.read(rec.digest))
        except (StorageError, ValueError):
            return None

    def source(self, ref: str) -> RowSource | None:
        """The succeeded job ``ref`` names, or ``None``."""
        job_id = job_id_of_ref(ref)
        if job_id is None:
            return None
        try:
            job = self._jobs.get(job_id)
        except NotFoundError:
            return None
        return StoreSource(job, self._jobs, self._store) if job.state == "succeeded" else None


def job_rows(job: Job, jobs: JobStore, store: ArtifactStore) -> list[ResultRow]:
    """Every value ``job`` measured: its kind's rows hook (``[]`` for a job that has not
    succeeded, or a kind without one). A hook that trips over a malformed artifact is
    logged and gives no rows, so one bad job does not hide the others' results."""
    kind = registered().get(job.kind)
    if job.state != "succeeded" or kind is None or kind.rows is None:
        return []
    try:
        return kind.rows(StoreSource(job, jobs, store))
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        log.warning("job %s (%s): no result rows: %s: %s", job.id, job.kind,
                    type(exc).__name__, exc)  # fmt: skip
        return []
