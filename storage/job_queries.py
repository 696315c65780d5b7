"""The queries of the job list: filters, sort orders and short (prefix) job ids.

Kept apart from :mod:`storage.jobs` (the queue's writes and leases) so that the list's
options can grow without growing the queue.
"""

from __future__ import annotations

import re
import sqlite3
from typing import Protocol

from storage.errors import AmbiguousIdError, NotFoundError
from storage.job_records import Job

#: The columns of a job row, in the order :class:`storage.job_records.Job` takes them.
JOB_COLS = (
    "id, kind, name, seed, spec_hash, spec, state, progress, message, error, worker, "
    "attempts, lease_token, lease_expires, created_at, started_at, finished_at, "
    "updated_at, manifest_digest, "
    "(SELECT group_concat(tag, char(31)) FROM job_tags WHERE job_tags.job_id = jobs.id) AS tags"
)

#: A job id or a prefix of one, as users type it (git-style short ids).
JOB_ID_PREFIX = re.compile(r"^[0-9a-f]{1,32}$")

#: The sort orders of :meth:`storage.jobs.JobStore.list_jobs`: a column, ``-`` for
#: descending. Ties are broken newest first.
JOB_SORTS: dict[str, str] = {
    "-created": "seq DESC",
    "created": "seq ASC",
    "kind": "kind ASC, seq DESC",
    "-kind": "kind DESC, seq DESC",
    "name": "name IS NULL, name COLLATE NOCASE ASC, seq DESC",
    "-name": "name IS NULL, name COLLATE NOCASE DESC, seq DESC",
    "state": "state ASC, seq DESC",
    "-state": "state DESC, seq DESC",
    "progress": "progress ASC, seq DESC",
    "-progress": "progress DESC, seq DESC",
    "duration": "(COALESCE(finished_at, updated_at) - started_at) IS NULL, "
    "COALESCE(finished_at, updated_at) - started_at ASC, seq DESC",
    "-duration": "(COALESCE(finished_at, updated_at) - started_at) IS NULL, "
    "COALESCE(finished_at, updated_at) - started_at DESC, seq DESC",
}


def _like_escape(text: str) -> str:
    return text.replace("\\", "\\\\").replace("%", "\\%").replace("_", "\\_")


def job_filter(
    *,
    state: str | None = None,
    kind: str | None = None,
    name: str | None = None,
    batch: str | None = None,
    tag: str | None = None,
) -> tuple[str, list[str]]:
    """``(" WHERE ...", args)`` for the list filters (``("", [])`` when none is set);
    ``name`` matches any job whose name contains it, ignoring case; ``batch`` is the exact
    batch label of the job's spec, or of a batch that asked for the job again and was
    given it (its spec already ran: :meth:`storage.jobs.JobStore.submit`); ``tag`` an
    exact tag."""
    where, args = [], []
    if batch:
        where.append(
            "(json_extract(spec, '$.batch')=? OR "
            "id IN (SELECT job_id FROM batch_members WHERE batch=?))"
        )
        args += [batch, batch]
    if tag:
        where.append("id IN (SELECT job_id FROM job_tags WHERE tag=?)")
        args.append(tag)
    if state:
        where.append("state=?")
        args.append(state)
    if kind:
        where.append("kind=?")
        args.append(kind)
    if name:
        where.append("name LIKE ? ESCAPE '\\'")
        args.append(f"%{_like_escape(name)}%")
    return (" WHERE " + " AND ".join(where) if where else ""), args


class _IdSource(Protocol):
    def ids_with_prefix(self, prefix: str, limit: int = 6) -> list[str]: ...


def resolve_job_id(jobs: _IdSource, text: str) -> str:
    """The full id of the one job whose id starts with ``text`` (git-style short ids).

    Raises ``NotFoundError`` when no job matches (or ``text`` is not lowercase hex of at
    most 32 digits) and :class:`AmbiguousIdError` when several do.
    """
    if not JOB_ID_PREFIX.match(text):
        raise NotFoundError(f"no job {text!r}: a job id is 1 to 32 lowercase hex digits")
    matches = jobs.ids_with_prefix(text)
    if not matches:
        raise NotFoundError(f"no job {text!r}")
    if len(matches) > 1:
        raise AmbiguousIdError(text, matches)
    return matches[0]


class JobListing:
    """The list queries of :class:`storage.jobs.JobStore` (a mixin: the store provides the
    connection and turns rows into jobs)."""

    def _conn(self) -> sqlite3.Connection:
        raise NotImplementedError

    def _row_to_job(self, row: sqlite3.Row, with_artifacts: bool = True) -> Job:
        raise NotImplementedError

    def ids_with_prefix(self, prefix: str, limit: int = 6) -> list[str]:
        """Up to ``limit`` job ids starting with ``prefix`` (lowercase hex), oldest first."""
        rows = self._conn().execute(
            "SELECT id FROM jobs WHERE id >= ? AND id < ? ORDER BY seq LIMIT ?",
            (prefix, prefix + "g", limit),
        )
        return [r[0] for r in rows]

    def list_jobs(
        self,
        state: str | None = None,
        kind: str | None = None,
        limit: int = 200,
        offset: int = 0,
        *,
        name: str | None = None,
        batch: str | None = None,
        sort: str = "-created",
        tag: str | None = None,
    ) -> list[Job]:
        """Jobs in the order ``sort`` names (a key of :data:`JOB_SORTS`; by default newest
        first), filtered by state, kind and a case-insensitive substring of the name."""
        where, args = job_filter(state=state, kind=kind, name=name, batch=batch, tag=tag)
        sql = f"SELECT {JOB_COLS} FROM jobs{where} ORDER BY {JOB_SORTS[sort]} LIMIT ? OFFSET ?"
        rows = self._conn().execute(sql, (*args, limit, offset)).fetchall()
        return [self._row_to_job(r, with_artifacts=False) for r in rows]

    def count_jobs(
        self,
        state: str | None = None,
        kind: str | None = None,
        *,
        name: str | None = None,
        batch: str | None = None,
        tag: str | None = None,
    ) -> int:
        """How many jobs :meth:`list_jobs` would page through with these filters."""
        where, args = job_filter(state=state, kind=kind, name=name, batch=batch, tag=tag)
        return int(self._conn().execute(f"SELECT COUNT(*) FROM jobs{where}", args).fetchone()[0])
