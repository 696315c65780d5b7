"""SQLite job queue: claims, leases, fencing, reaping, cancellation, dedupe."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import pytest

from storage.errors import NotFoundError
from storage.jobs import ArtifactRecord, JobStore


class FakeClock:
    """A wall clock the test moves by hand: leases expire without sleeping."""

    def __init__(self, t: float = 1_800_000_000.0) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t

    def advance(self, seconds: float) -> None:
        self.t += seconds


def _submit(jobs: JobStore, h: str = "h1", force: bool = False):
    return jobs.submit(kind="toy", name="n", seed=0, spec_hash=h, spec={"kind": "toy"}, force=force)


def test01_wal_mode(jobs: JobStore) -> None:
    assert jobs._conn().execute("PRAGMA journal_mode").fetchone()[0] == "wal"


def test02_submit_dedupes_unless_forced(jobs: JobStore) -> None:
    a, created = _submit(jobs)
    assert created and a.state == "queued"
    b, created = _submit(jobs)
    assert not created and b.id == a.id
    c, created = _submit(jobs, force=True)
    assert created and c.id != a.id


def test03_claim_is_atomic_across_threads(settings) -> None:
    """20 threads with their own connections race for 10 jobs: each job is claimed once."""
    setup = JobStore(settings.db_path)
    for i in range(10):
        _submit(setup, h=f"h{i}")
    claimed: list[str] = []
    lock = threading.Lock()

    def grab(n: int) -> None:
        js = JobStore(settings.db_path)
        while (job := js.claim(f"w:{n}", 30)) is not None:
            with lock:
                claimed.append(job.id)
        js.close()

    threads = [threading.Thread(target=grab, args=(n,)) for n in range(20)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(claimed) == 10 and len(set(claimed)) == 10


def test04_claim_order_and_lease(jobs: JobStore) -> None:
    first, _ = _submit(jobs, "a")
    _submit(jobs, "b")
    job = jobs.claim("w:1", 5)
    assert job is not None and job.id == first.id
    assert job.state == "running" and job.attempts == 1 and job.worker == "w:1"
    assert job.lease_expires is not None and job.lease_expires > time.time()


def test05_fencing(tmp_path: Path) -> None:
    """A worker whose lease was reaped and re-claimed cannot complete the job."""
    clock = FakeClock()
    jobs = JobStore(tmp_path / "jobs.db", clock=clock)
    _submit(jobs)
    old = jobs.claim("w:old", 5)
    clock.advance(6)  # past the 5 s lease, without sleeping
    requeued, failed = jobs.reap(max_attempts=3)
    assert requeued == [old.id] and failed == []
    new = jobs.claim("w:new", 30)
    assert new.id == old.id and new.attempts == 2
    art = [ArtifactRecord("x.json", "0" * 64, 1, "application/json")]
    assert jobs.heartbeat(old.id, old.lease_token, 30) == "lost"
    assert not jobs.complete(old.id, old.lease_token, art, "1" * 64)
    assert not jobs.fail(old.id, old.lease_token, "stale")
    assert jobs.complete(new.id, new.lease_token, art, "1" * 64)
    done = jobs.get(new.id)
    assert done.state == "succeeded" and done.worker == "w:new"
    assert [a.name for a in done.artifacts] == ["x.json"]


def test06_reaper_gives_up_after_max_attempts(tmp_path: Path) -> None:
    clock = FakeClock()
    jobs = JobStore(tmp_path / "jobs.db", clock=clock)
    job, _ = _submit(jobs)
    for _ in range(2):
        assert jobs.claim("w:x", 5) is not None
        clock.advance(6)
        jobs.reap(max_attempts=2)
    final = jobs.get(job.id)
    assert final.state == "failed" and final.attempts == 2
    assert "lease expired" in final.error and "2 of 2" in final.error


def test07_cancel_reaches_running_job(jobs: JobStore) -> None:
    _submit(jobs)
    job = jobs.claim("w:1", 30)
    assert jobs.heartbeat(job.id, job.lease_token, 30, 0.5, "half") == "ok"
    assert jobs.get(job.id).progress == 0.5
    assert jobs.cancel(job.id).state == "cancelled"
    assert jobs.heartbeat(job.id, job.lease_token, 30) == "cancelled"
    assert not jobs.complete(job.id, job.lease_token, [], "1" * 64)
    assert jobs.get(job.id).state == "cancelled"


def test08_cancel_finished_is_noop(jobs: JobStore) -> None:
    _submit(jobs)
    job = jobs.claim("w:1", 30)
    jobs.fail(job.id, job.lease_token, "boom\nwith   lines")
    after = jobs.cancel(job.id)
    assert after.state == "failed" and after.error == "boom with lines"
    with pytest.raises(NotFoundError):
        jobs.cancel("f" * 32)


def test09_list_filters_newest_first(jobs: JobStore) -> None:
    ids = [_submit(jobs, f"h{i}")[0].id for i in range(3)]
    assert [j.id for j in jobs.list_jobs()] == ids[::-1]
    jobs.claim("w", 30)
    assert [j.id for j in jobs.list_jobs(state="running")] == [ids[0]]
    assert jobs.list_jobs(kind="other") == []
    assert jobs.counts()["queued"] == 2


def test10_shards_recorded(jobs: JobStore) -> None:
    job, _ = _submit(jobs)
    jobs.record_shard(job.id, "s-0", "a" * 64)
    assert jobs.shards(job.id) == {"s-0": "a" * 64}
    assert "a" * 64 in jobs.referenced_digests()


def test11_finished_jobs_shards_are_not_gc_roots(jobs: JobStore) -> None:
    job, _ = _submit(jobs)
    claimed = jobs.claim("w:1", 30)
    jobs.record_shard(job.id, "s-0", "b" * 64)
    assert "b" * 64 in jobs.referenced_digests()
    jobs.complete(job.id, claimed.lease_token, [], "1" * 64)
    assert "b" * 64 not in jobs.referenced_digests()


def test12_succeeded_with_hash_finds_the_newest_succeeded(jobs: JobStore) -> None:
    """What resubmitting a spec would return, if it succeeded: a batch's step, found again."""
    assert jobs.succeeded_with_hash("h1") is None
    first, _ = _submit(jobs)
    assert jobs.succeeded_with_hash("h1") is None  # queued: not a result yet
    claimed = jobs.claim("w:1", 30)
    jobs.complete(first.id, claimed.lease_token, [], "1" * 64)
    forced, _ = _submit(jobs, force=True)  # queued again: the succeeded one still answers
    found = jobs.succeeded_with_hash("h1")
    assert found is not None and found.id == first.id and found.state == "succeeded"
    claimed = jobs.claim("w:1", 30)
    jobs.complete(forced.id, claimed.lease_token, [], "1" * 64)
    assert jobs.succeeded_with_hash("h1").id == forced.id  # type: ignore[union-attr]
    assert jobs.succeeded_with_hash("h2") is None
