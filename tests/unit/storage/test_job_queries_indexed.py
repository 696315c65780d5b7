"""The queries of every submission stay index look-ups as the job table grows.

Reference: SQLite's own query planner (``EXPLAIN QUERY PLAN``) and a row count. Before, the
dedupe look-up of a succeeded job walked the ``(state, seq)`` index through every succeeded
job (40 ms per submission at 100,000 jobs), and the next ``seq`` scanned every job (11 ms).
"""

from __future__ import annotations

import sqlite3
from pathlib import Path

from storage.jobs import JobStore


def _plan(db: Path, sql: str, args: tuple[object, ...]) -> str:
    with sqlite3.connect(db) as conn:
        rows = conn.execute("EXPLAIN QUERY PLAN " + sql, args).fetchall()
    return " | ".join(str(r[3]) for r in rows)


def _fill(jobs: JobStore, n: int) -> None:
    for i in range(n):
        jobs.submit(kind="render", name=None, seed=i, spec_hash=f"h{i}", spec={"seed": i})


def test01_submission_queries_use_indexes(tmp_path: Path) -> None:
    """Each statement the store runs for a submission and its dedupe look-up (traced as it
    runs), planned by SQLite: no full scan of the job table or of the (state, seq) index."""
    jobs = JobStore(tmp_path / "jobs.sqlite3")
    _fill(jobs, 3)
    seen: list[str] = []
    conn = jobs._conn()
    conn.set_trace_callback(seen.append)
    jobs.succeeded_with_hash("h1")
    jobs.submit(kind="render", name=None, seed=9, spec_hash="h9", spec={"seed": 9})
    conn.set_trace_callback(None)
    selects = [q for q in seen if q.lstrip().upper().startswith("SELECT")]
    assert len(selects) >= 3, seen
    plans = {q: _plan(jobs.path, q, ()) for q in selects}
    for q, plan in plans.items():
        assert "SCAN" not in plan, (q, plan)
        if "FROM jobs" in q and "spec_hash=" in q:
            assert "jobs_hash" in plan, (q, plan)
        if "MAX(seq)" in q:
            assert "jobs_seq" in plan, (q, plan)
    assert any("MAX(seq)" in q for q in plans) and any("state='succeeded'" in q for q in plans)


def test02_succeeded_with_hash_among_many_succeeded_jobs(tmp_path: Path) -> None:
    """The answer is the newest succeeded job of that hash, not of another, and SQLite
    visits only that hash's rows (counted by the virtual machine's steps, through a
    progress handler, against the table's size)."""
    jobs = JobStore(tmp_path / "jobs.sqlite3")
    n = 2000
    with sqlite3.connect(jobs.path) as conn:
        conn.executemany(
            "INSERT INTO jobs (id, seq, kind, seed, spec_hash, spec, state, created_at, "
            "updated_at) VALUES (?, ?, 'render', 0, ?, '{}', 'succeeded', 0, 0)",
            [(f"{i:032x}", i + 1, f"h{i % 1000}") for i in range(n)],
        )
    steps = 0

    def count() -> int:
        nonlocal steps
        steps += 1
        return 0

    conn = jobs._conn()
    conn.set_progress_handler(count, 100)  # called every 100 VM instructions
    found = jobs.succeeded_with_hash("h7")
    conn.set_progress_handler(None, 0)
    assert found is not None and found.id == f"{1007:032x}"  # seq 1008 beats seq 8
    # Two matching rows cost a few hundred instructions; a walk of 2,000 rows costs tens
    # of thousands (several hundred calls).
    assert steps < 20, steps
    older = jobs.succeeded_with_hash("h7", exclude=[found.id])
    assert older is not None and older.id == f"{7:032x}"


def test03_an_older_database_gains_the_seq_index(tmp_path: Path) -> None:
    db = tmp_path / "jobs.sqlite3"
    JobStore(db)
    with sqlite3.connect(db) as conn:
        conn.execute("DROP INDEX jobs_seq")
    jobs = JobStore(db)  # opened by this version again
    _fill(jobs, 2)
    with sqlite3.connect(db) as conn:
        names = {r[0] for r in conn.execute("SELECT name FROM sqlite_master WHERE type='index'")}
    assert "jobs_seq" in names
    assert [j.seed for j in jobs.list_jobs(None, None, 10, 0)] == [1, 0]
