"""The job queue: SQLite in WAL mode, every write in a ``BEGIN IMMEDIATE`` transaction.

States: ``queued`` → ``running`` → ``succeeded`` | ``failed`` | ``cancelled``.

Leases and fencing: :meth:`JobStore.claim` atomically takes the oldest queued job, bumps
``attempts`` and hands out a fresh random ``lease_token`` valid until ``lease_expires``.
Heartbeats, completion and failure all name that token, and change nothing unless the row
still carries it in state ``running``: a worker whose lease was reaped (and the job handed to
another worker) or whose job was cancelled can no longer write. :meth:`JobStore.reap`
re-queues running jobs whose lease ran out, up to ``max_attempts``, then fails them.
"""

from __future__ import annotations

import json
import os
import sqlite3
import threading
import time
import uuid
from collections.abc import Callable, Collection, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from storage.errors import NotFoundError
from storage.job_queries import JOB_COLS as _JOB_COLS
from storage.job_queries import JobListing
from storage.job_records import (
    FINAL_STATES,
    STATES,
    ArtifactRecord,
    HeartbeatStatus,
    Job,
)
from storage.write_lock import WriteLock, write_lock

__all__ = ["FINAL_STATES", "STATES", "ArtifactRecord", "HeartbeatStatus", "Job", "JobStore"]

_SCHEMA = """
CREATE TABLE IF NOT EXISTS jobs (
    id TEXT PRIMARY KEY,
    seq INTEGER NOT NULL,
    kind TEXT NOT NULL,
    name TEXT,
    seed INTEGER NOT NULL,
    spec_hash TEXT NOT NULL,
    spec TEXT NOT NULL,
    state TEXT NOT NULL,
    progress REAL NOT NULL DEFAULT 0,
    message TEXT NOT NULL DEFAULT '',
    error TEXT,
    worker TEXT,
    attempts INTEGER NOT NULL DEFAULT 0,
    lease_token TEXT,
    lease_expires REAL,
    created_at REAL NOT NULL,
    started_at REAL,
    finished_at REAL,
    updated_at REAL NOT NULL,
    manifest_digest TEXT
);
CREATE INDEX IF NOT EXISTS jobs_state_seq ON jobs(state, seq);
CREATE INDEX IF NOT EXISTS jobs_hash ON jobs(spec_hash, state);
CREATE INDEX IF NOT EXISTS jobs_seq ON jobs(seq);
CREATE TABLE IF NOT EXISTS artifacts (
    job_id TEXT NOT NULL REFERENCES jobs(id),
    name TEXT NOT NULL,
    digest TEXT NOT NULL,
    size INTEGER NOT NULL,
    media_type TEXT NOT NULL,
    PRIMARY KEY (job_id, name)
);
CREATE INDEX IF NOT EXISTS artifacts_digest ON artifacts(digest);
CREATE TABLE IF NOT EXISTS shards (
    job_id TEXT NOT NULL REFERENCES jobs(id),
    key TEXT NOT NULL,
    digest TEXT NOT NULL,
    created_at REAL NOT NULL,
    PRIMARY KEY (job_id, key)
);
CREATE TABLE IF NOT EXISTS job_tags (
    job_id TEXT NOT NULL REFERENCES jobs(id),
    tag TEXT NOT NULL,
    PRIMARY KEY (job_id, tag)
);
CREATE INDEX IF NOT EXISTS job_tags_tag ON job_tags(tag);
CREATE TABLE IF NOT EXISTS batch_members (
    batch TEXT NOT NULL,
    job_id TEXT NOT NULL REFERENCES jobs(id),
    PRIMARY KEY (batch, job_id)
);
CREATE TABLE IF NOT EXISTS uploads (
    digest TEXT PRIMARY KEY,
    name TEXT NOT NULL,
    media_type TEXT NOT NULL,
    size INTEGER NOT NULL,
    created_at REAL NOT NULL
);
-- Every format an uploaded object was validated as (one row per media type, the first
-- name it was uploaded under): the same bytes can pass two validators (a PNG with a zip
-- appended is a valid .png and may be a valid .btf.zip), and ``uploads`` keeps only the
-- first upload's record.
CREATE TABLE IF NOT EXISTS upload_formats (
    digest TEXT NOT NULL,
    media_type TEXT NOT NULL,
    name TEXT NOT NULL,
    PRIMARY KEY (digest, media_type)
);
"""


def _not_in(column: str, values: Collection[str]) -> str:
    """`` AND <column> NOT IN (?, ...)`` for ``values``, or nothing when there are none
    (``NOT IN (NULL)`` would match no row)."""
    return f" AND {column} NOT IN ({','.join('?' * len(values))})" if values else ""


class JobStore(JobListing):
    """SQLite-backed job queue. Safe to share between threads (one connection per thread)
    and between processes (SQLite file locking; WAL lets readers run beside a writer). Its
    list queries are in :class:`storage.job_queries.JobListing`."""

    def __init__(
        self,
        path: str | Path,
        busy_timeout_s: float = 30.0,
        clock: Callable[[], float] = time.time,
    ) -> None:
        """``clock`` gives the wall time in seconds since the epoch for leases, heartbeats
        and timestamps (tests pass a fake one instead of sleeping)."""
        self.path = Path(path)
        self._clock = clock
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._busy_ms = int(busy_timeout_s * 1000)
        self._local = threading.local()
        self._lock: tuple[int, WriteLock] | None = None  # (pid, this process's lock)
        self._conn().executescript(_SCHEMA)

    # -- connections ---------------------------------------------------------------------
    def _conn(self) -> sqlite3.Connection:
        conn: sqlite3.Connection | None = getattr(self._local, "conn", None)
        if conn is None:
            conn = sqlite3.connect(self.path, isolation_level=None, timeout=self._busy_ms / 1000)
            conn.row_factory = sqlite3.Row
            conn.execute(f"PRAGMA busy_timeout={self._busy_ms}")
            conn.execute("PRAGMA journal_mode=WAL")
            conn.execute("PRAGMA synchronous=NORMAL")
            conn.execute("PRAGMA foreign_keys=ON")
            self._local.conn = conn
        return conn

    def close(self) -> None:
        conn = getattr(self._local, "conn", None)
        if conn is not None:
            conn.close()
            self._local.conn = None

    @contextmanager
    def _write(self) -> Iterator[sqlite3.Connection]:
        # Writers, of this process and others, queue on a lock instead of on SQLite's busy
        # handler, whose growing sleeps (up to 100 ms) made the tail latency of concurrent
        # submissions ten times the median (storage.write_lock).
        db = self._conn()
        with self._write_lock().hold():
            db.execute("BEGIN IMMEDIATE")
            try:
                yield db
            except BaseException:
                db.execute("ROLLBACK")
                raise
            else:
                db.execute("COMMIT")

    def _write_lock(self) -> WriteLock:
        """This process's :func:`storage.write_lock.write_lock` of the database, looked up
        once per process (the look-up resolves the path: a few system calls per write)."""
        pid = os.getpid()
        if self._lock is None or self._lock[0] != pid:
            self._lock = (pid, write_lock(self.path))
        return self._lock[1]

    # -- reading -------------------------------------------------------------------------
    def _row_to_job(self, row: sqlite3.Row, with_artifacts: bool = True) -> Job:
        d = dict(row)
        d["spec"] = json.loads(d["spec"])
        d["tags"] = tuple(sorted(d["tags"].split("\x1f"))) if d.get("tags") else ()
        arts: list[ArtifactRecord] = []
        if with_artifacts and d["state"] == "succeeded":
            arts = self.artifacts(d["id"])
        return Job(**d, artifacts=arts)

    def get(self, job_id: str) -> Job:
        row = self._conn().execute(f"SELECT {_JOB_COLS} FROM jobs WHERE id=?", (job_id,)).fetchone()
        if row is None:
            raise NotFoundError(f"no job {job_id!r}")
        return self._row_to_job(row)

    def succeeded_with_hash(self, spec_hash: str, exclude: Collection[str] = ()) -> Job | None:
        """The newest succeeded job of the spec whose canonical hash is ``spec_hash`` (what
        resubmitting that spec would return), or ``None``; jobs in ``exclude`` are skipped.

        By the hash index: left to itself, SQLite walks ``jobs_state_seq`` (no sort needed)
        through every succeeded job, 40 ms per call at 100,000 jobs."""
        row = (
            self._conn()
            .execute(
                f"SELECT {_JOB_COLS} FROM jobs INDEXED BY jobs_hash "
                "WHERE spec_hash=? AND state='succeeded'"
                f"{_not_in('id', exclude)} ORDER BY seq DESC LIMIT 1",
                (spec_hash, *exclude),
            )
            .fetchone()
        )
        return None if row is None else self._row_to_job(row)

    def counts(self) -> dict[str, int]:
        rows = self._conn().execute("SELECT state, COUNT(*) FROM jobs GROUP BY state").fetchall()
        out = dict.fromkeys(STATES, 0)
        out.update({r[0]: r[1] for r in rows})
        return out

    def artifacts(self, job_id: str) -> list[ArtifactRecord]:
        rows = (
            self._conn()
            .execute(
                "SELECT name, digest, size, media_type FROM artifacts WHERE job_id=? ORDER BY name",
                (job_id,),
            )
            .fetchall()
        )
        return [ArtifactRecord(**dict(r)) for r in rows]

    def artifact(self, job_id: str, name: str) -> ArtifactRecord:
        row = (
            self._conn()
            .execute(
                "SELECT name, digest, size, media_type FROM artifacts WHERE job_id=? AND name=?",
                (job_id, name),
            )
            .fetchone()
        )
        if row is None:
            job = self.get(job_id)
            if job.state != "succeeded":
                raise NotFoundError(f"job {job_id} is {job.state}; it has no artifacts yet")
            raise NotFoundError(f"job {job_id} has no artifact {name!r}")
        return ArtifactRecord(**dict(row))

    def find_digest(self, digest: str) -> ArtifactRecord | None:
        """An artifact or upload record for ``digest`` (for its name and media type)."""
        db = self._conn()
        row = db.execute(
            "SELECT name, digest, size, media_type FROM artifacts WHERE digest=? LIMIT 1", (digest,)
        ).fetchone()
        if row is None:
            row = db.execute(
                "SELECT name, digest, size, media_type FROM uploads WHERE digest=?", (digest,)
            ).fetchone()
        return ArtifactRecord(**dict(row)) if row else None

    def producers(self, digest: str) -> list[str]:
        """Ids of the jobs that list ``digest`` as an artifact, oldest first."""
        rows = (
            self._conn()
            .execute(
                "SELECT DISTINCT a.job_id, j.seq FROM artifacts a JOIN jobs j ON j.id = a.job_id "
                "WHERE a.digest=? ORDER BY j.seq",
                (digest,),
            )
            .fetchall()
        )
        return [r[0] for r in rows]

    def running(self) -> list[tuple[str, str | None]]:
        """``(job id, worker)`` of every running job."""
        rows = self._conn().execute("SELECT id, worker FROM jobs WHERE state='running'")
        return [(r[0], r[1]) for r in rows]

    def referenced_digests(self) -> set[str]:
        """Every digest a job, manifest, upload or unfinished job's shard refers to (the GC
        roots). Shard results of finished jobs are not roots: such a job never re-runs, and
        keeping them would double the disk use of every sharded dataset."""
        db = self._conn()
        out = {r[0] for r in db.execute("SELECT digest FROM artifacts")}
        out |= {
            r[0]
            for r in db.execute(
                "SELECT s.digest FROM shards s JOIN jobs j ON j.id = s.job_id "
                "WHERE j.state IN ('queued', 'running')"
            )
        }
        out |= {r[0] for r in db.execute("SELECT digest FROM uploads")}
        out |= {
            r[0]
            for r in db.execute(
                "SELECT manifest_digest FROM jobs WHERE manifest_digest IS NOT NULL"
            )
        }
        return out

    # -- submitting ----------------------------------------------------------------------
    def submit(
        self,
        *,
        kind: str,
        name: str | None,
        seed: int,
        spec_hash: str,
        spec: dict[str, Any],
        force: bool = False,
        exclude: Collection[str] = (),
    ) -> tuple[Job, bool]:
        """Queue a job; returns ``(job, created)``.

        Unless ``force``, an identical spec (same hash) that already succeeded, or is queued
        or running, is returned instead of queueing a duplicate; jobs in ``exclude`` (e.g.
        succeeded jobs whose artifacts were lost from the store) are never returned.
        """
        now = self._clock()
        with self._write() as db:
            if not force:
                row = db.execute(
                    f"SELECT {_JOB_COLS} FROM jobs WHERE spec_hash=? AND state IN "
                    f"('succeeded','running','queued'){_not_in('id', exclude)} "
                    "ORDER BY (state='succeeded') DESC, seq DESC LIMIT 1",
                    (spec_hash, *exclude),
                ).fetchone()
                if row is not None:
                    job_id = row["id"]
                    existing = True
                    batch = spec.get("batch")
                    if isinstance(batch, str) and batch != json.loads(row["spec"]).get("batch"):
                        # the batch that asked again for a job shows it in its group
                        db.execute(
                            "INSERT OR IGNORE INTO batch_members (batch, job_id) VALUES (?, ?)",
                            (batch, job_id),
                        )
                else:
                    existing = False
            else:
                existing = False
            if not existing:
                job_id = uuid.uuid4().hex
                # By the index on seq (without it: a scan of every job, 11 ms at 100,000).
                seq = db.execute("SELECT COALESCE(MAX(seq), 0) + 1 FROM jobs").fetchone()[0]
                db.execute(
                    "INSERT INTO jobs (id, seq, kind, name, seed, spec_hash, spec, state, "
                    "created_at, updated_at) VALUES (?,?,?,?,?,?,?,'queued',?,?)",
                    (
                        job_id,
                        seq,
                        kind,
                        name,
                        seed,
                        spec_hash,
                        json.dumps(spec, sort_keys=True),
                        now,
                        now,
                    ),
                )
        return self.get(job_id), not existing

    def rename(self, job_id: str, name: str | None) -> Job:
        """Give a job a new ``name`` (``None``: no name); the spec's identity is unchanged
        (a name is a label, not an input). Raises ``NotFoundError``."""
        with self._write() as db:
            row = db.execute("SELECT spec FROM jobs WHERE id=?", (job_id,)).fetchone()
            if row is None:
                raise NotFoundError(f"no job {job_id!r}")
            spec = json.loads(row["spec"])
            if name is None:
                spec.pop("name", None)
            else:
                spec["name"] = name
            db.execute(
                "UPDATE jobs SET name=?, spec=? WHERE id=?",
                (name, json.dumps(spec, sort_keys=True), job_id),
            )
        return self.get(job_id)

    def tag(self, job_id: str, add: Collection[str] = (), remove: Collection[str] = ()) -> Job:
        """Add and remove tags of a job (adding one it has, or removing one it lacks, is no
        change). Raises ``NotFoundError``."""
        with self._write() as db:
            if db.execute("SELECT 1 FROM jobs WHERE id=?", (job_id,)).fetchone() is None:
                raise NotFoundError(f"no job {job_id!r}")
            db.executemany(
                "INSERT OR IGNORE INTO job_tags (job_id, tag) VALUES (?, ?)",
                [(job_id, t) for t in add],
            )
            db.executemany(
                "DELETE FROM job_tags WHERE job_id=? AND tag=?", [(job_id, t) for t in remove]
            )
        return self.get(job_id)

    def record_upload(self, digest: str, name: str, media_type: str, size: int) -> None:
        """Record an object that was validated as a file called ``name`` of ``media_type``
        (:func:`service.submission.import_file`); the first upload of a digest names it, and
        each format it passed is kept (:meth:`upload_records`)."""
        with self._write() as db:
            db.execute(
                "INSERT OR IGNORE INTO uploads (digest, name, media_type, size, "
                "created_at) VALUES (?,?,?,?,?)",
                (digest, name, media_type, size, self._clock()),
            )
            db.execute(
                "INSERT OR IGNORE INTO upload_formats (digest, media_type, name) VALUES (?,?,?)",
                (digest, media_type, name),
            )

    def upload_records(self, digest: str) -> list[ArtifactRecord]:
        """Every record of ``digest`` as an upload: one per format it was validated as when
        it was stored (the first name it was uploaded under); ``[]`` for an
        object no upload or ``matforge import`` stored."""
        rows = (
            self._conn()
            .execute(
                "SELECT u.name, u.digest, u.size, u.media_type FROM uploads u WHERE u.digest=? "
                "UNION SELECT f.name, f.digest, u.size, f.media_type FROM upload_formats f "
                "JOIN uploads u ON u.digest = f.digest WHERE f.digest=?",
                (digest, digest),
            )
            .fetchall()
        )
        return [ArtifactRecord(**dict(r)) for r in rows]

    # -- leasing -------------------------------------------------------------------------
    def claim(self, worker: str, lease_seconds: float, job_id: str | None = None) -> Job | None:
        """Atomically take the oldest queued job (or ``job_id``) under a fresh lease."""
        now = self._clock()
        token = uuid.uuid4().hex
        with self._write() as db:
            if job_id is None:
                row = db.execute(
                    "SELECT id FROM jobs WHERE state='queued' ORDER BY seq LIMIT 1"
                ).fetchone()
            else:
                row = db.execute(
                    "SELECT id FROM jobs WHERE state='queued' AND id=?", (job_id,)
                ).fetchone()
            if row is None:
                return None
            db.execute(
                "UPDATE jobs SET state='running', worker=?, attempts=attempts+1, lease_token=?, "
                "lease_expires=?, started_at=?, updated_at=?, progress=0, error=NULL, "
                "message='started' WHERE id=?",
                (worker, token, now + lease_seconds, now, now, row["id"]),
            )
            claimed = row["id"]
        return self.get(claimed)

    def heartbeat(
        self,
        job_id: str,
        token: str,
        lease_seconds: float,
        progress: float | None = None,
        message: str | None = None,
    ) -> HeartbeatStatus:
        """Renew the lease and publish progress; says whether the worker still holds it."""
        now = self._clock()
        sets = ["lease_expires=?", "updated_at=?"]
        args: list[Any] = [now + lease_seconds, now]
        if progress is not None:
            sets.append("progress=?")
            args.append(min(1.0, max(0.0, float(progress))))
        if message is not None:
            sets.append("message=?")
            args.append(message[:500])
        with self._write() as db:
            cur = db.execute(
                f"UPDATE jobs SET {', '.join(sets)} WHERE id=? AND lease_token=? "
                "AND state='running'",
                (*args, job_id, token),
            )
            if cur.rowcount == 1:
                return "ok"
            row = db.execute("SELECT state FROM jobs WHERE id=?", (job_id,)).fetchone()
        return "cancelled" if row is not None and row["state"] == "cancelled" else "lost"

    def complete(
        self,
        job_id: str,
        token: str,
        artifacts: list[ArtifactRecord],
        manifest_digest: str,
        message: str = "done",
    ) -> bool:
        """Fenced success: records artifacts only if ``token`` still holds the lease."""
        now = self._clock()
        with self._write() as db:
            cur = db.execute(
                "UPDATE jobs SET state='succeeded', progress=1, message=?, finished_at=?, "
                "updated_at=?, lease_token=NULL, lease_expires=NULL, manifest_digest=? "
                "WHERE id=? AND lease_token=? AND state='running'",
                (message, now, now, manifest_digest, job_id, token),
            )
            if cur.rowcount != 1:
                return False
            # A finished job never re-runs: its shard results are no longer GC roots.
            db.execute("DELETE FROM shards WHERE job_id=?", (job_id,))
            db.executemany(
                "INSERT OR REPLACE INTO artifacts (job_id, name, digest, size, media_type) "
                "VALUES (?,?,?,?,?)",
                [(job_id, a.name, a.digest, a.size, a.media_type) for a in artifacts],
            )
        return True

    def fail(self, job_id: str, token: str, error: str) -> bool:
        """Fenced failure with a one-line error."""
        now = self._clock()
        line = " ".join(error.split())[:1000] or "job failed"
        with self._write() as db:
            cur = db.execute(
                "UPDATE jobs SET state='failed', error=?, message='failed', finished_at=?, "
                "updated_at=?, lease_token=NULL, lease_expires=NULL "
                "WHERE id=? AND lease_token=? AND state='running'",
                (line, now, now, job_id, token),
            )
            return cur.rowcount == 1

    def cancel(self, job_id: str) -> Job:
        """Cancel a queued or running job; a finished job is returned unchanged. A running
        job's worker learns of it at its next heartbeat and stops."""
        now = self._clock()
        with self._write() as db:
            row = db.execute("SELECT state FROM jobs WHERE id=?", (job_id,)).fetchone()
            if row is None:
                raise NotFoundError(f"no job {job_id!r}")
            if row["state"] in ("queued", "running"):
                db.execute(
                    "UPDATE jobs SET state='cancelled', message='cancelled', "
                    "finished_at=?, updated_at=?, lease_token=NULL, lease_expires=NULL "
                    "WHERE id=?",
                    (now, now, job_id),
                )
        return self.get(job_id)

    def reap(self, max_attempts: int, now: float | None = None) -> tuple[list[str], list[str]]:
        """Re-queue running jobs whose lease expired, or fail them after ``max_attempts``.

        Returns ``(requeued ids, failed ids)``.
        """
        t = self._clock() if now is None else now
        requeued, failed = [], []
        with self._write() as db:
            rows = db.execute(
                "SELECT id, attempts, worker FROM jobs WHERE state='running' AND lease_expires < ?",
                (t,),
            ).fetchall()
            for r in rows:
                if r["attempts"] >= max_attempts:
                    db.execute(
                        "UPDATE jobs SET state='failed', error=?, message='failed', "
                        "finished_at=?, updated_at=?, lease_token=NULL, lease_expires=NULL "
                        "WHERE id=?",
                        (
                            f"worker {r['worker']} stopped responding (lease expired) on attempt "
                            f"{r['attempts']} of {max_attempts}; giving up. Check the worker log "
                            "for a crash or out-of-memory kill, then submit the spec again "
                            "(a failed job is never reused, so no force is needed)",
                            t,
                            t,
                            r["id"],
                        ),
                    )
                    failed.append(r["id"])
                else:
                    db.execute(
                        "UPDATE jobs SET state='queued', lease_token=NULL, lease_expires=NULL, "
                        "message=?, updated_at=? WHERE id=?",
                        (
                            f"re-queued: worker {r['worker']} stopped responding "
                            f"(attempt {r['attempts']} of {max_attempts})",
                            t,
                            r["id"],
                        ),
                    )
                    requeued.append(r["id"])
        return requeued, failed

    # -- shards --------------------------------------------------------------------------
    def record_shard(self, job_id: str, key: str, digest: str) -> None:
        """Record a finished shard (its result object in the store) for ``job_id``."""
        with self._write() as db:
            db.execute(
                "INSERT OR REPLACE INTO shards (job_id, key, digest, created_at) VALUES (?,?,?,?)",
                (job_id, key, digest, self._clock()),
            )

    def shards(self, job_id: str) -> dict[str, str]:
        """Finished shards of a job: key → result digest."""
        rows = (
            self._conn()
            .execute("SELECT key, digest FROM shards WHERE job_id=?", (job_id,))
            .fetchall()
        )
        return {r["key"]: r["digest"] for r in rows}
