"""A job that does not move is stopped, and its worker freed (issue 21, item 6).

A worker's heartbeat proved only that the worker was alive: with both of its pool processes
stopped (SIGSTOP), a job stayed ``running`` at 0 % for good, and cancelling it left the
worker blocked. Now a run that reports no progress for its kind's ``stall_seconds``
(``MATFORGE_STALL_SECONDS`` here) or runs past its ``timeout_seconds`` is failed with a
message that says so, and a stop of any kind (cancel included) kills the shard processes
the runner waits on, so the worker returns at once and takes the next job.

The toy kind's shards sleep 20 s each in the process pool; every test ends in seconds.
"""

from __future__ import annotations

import threading
import time

import pytest

from jobapi.errors import SpecError
from service.specs import validate_spec
from service.submission import run_in_process, submit
from service.workers.worker import run_worker

SLOW = {"kind": "toy", "params": {"n": 4, "sleep": 20.0}}


def test01_timeout_seconds_fails_the_job_in_time(toy_kind, settings) -> None:
    t0 = time.monotonic()
    job = run_in_process({**SLOW, "timeout_seconds": 1.5}, settings)
    took = time.monotonic() - t0
    assert job.state == "failed", job
    assert job.error is not None and job.error.startswith("timed out: still running after")
    assert "time limit of 1.5 s" in job.error, job.error
    assert took < 15, f"the job took {took:.1f} s: its shards were not stopped"


def test02_no_progress_for_the_stall_limit_fails_the_job(toy_kind, settings) -> None:
    t0 = time.monotonic()
    job = run_in_process(SLOW, settings.with_(stall_seconds=1.0))
    took = time.monotonic() - t0
    assert job.state == "failed", job
    assert job.error is not None and job.error.startswith("stuck: no progress for"), job.error
    assert "the limit for toy is 1 s" in job.error, job.error
    assert took < 15, f"the job took {took:.1f} s: its shards were not stopped"


def test03_timeout_seconds_is_validated_and_not_part_of_the_identity(toy_kind) -> None:
    plain = validate_spec({"kind": "toy", "params": {"n": 2}})
    timed = validate_spec({"kind": "toy", "params": {"n": 2}, "timeout_seconds": 60})
    assert timed.spec_hash == plain.spec_hash
    assert timed.document()["timeout_seconds"] == 60 and "timeout_seconds" not in plain.document()
    for bad in (0, -1, "soon", float("inf"), 1e9, True):
        with pytest.raises(SpecError, match="timeout_seconds"):
            validate_spec({"kind": "toy", "params": {}, "timeout_seconds": bad})


def test04_cancel_frees_the_worker_for_the_next_job(toy_kind, settings, jobs, store) -> None:
    slow, _ = submit(SLOW, jobs, store)
    quick, _ = submit({"kind": "toy", "params": {"n": 2}}, jobs, store)
    stop = threading.Event()
    worker = threading.Thread(target=run_worker, args=(settings,), kwargs={"stop": stop})
    worker.start()
    try:
        deadline = time.monotonic() + 30
        while jobs.get(slow.id).state != "running":
            assert time.monotonic() < deadline, "the slow job never started"
            time.sleep(0.05)
        time.sleep(1.0)  # its shards are sleeping in the pool now
        jobs.cancel(slow.id)
        t0 = time.monotonic()
        while jobs.get(quick.id).state != "succeeded":
            assert time.monotonic() - t0 < 15, (
                f"the worker did not take the next job: {jobs.get(quick.id).state}"
            )
            time.sleep(0.05)
    finally:
        stop.set()
        worker.join(timeout=60)
    assert jobs.get(slow.id).state == "cancelled"
    assert not worker.is_alive()


def test05_a_runner_that_does_not_return_ends_its_worker(toy_kind, settings, jobs, store) -> None:
    """A single shard runs inline, in the worker's own thread: no process to kill. When the
    job is cancelled and the runner has not returned ``grace`` seconds later, ``on_wedged``
    is called (a worker process ends itself there, and its supervisor starts another)."""
    from service.workers.execution import execute
    from service.workers.executors import LocalPoolExecutor

    job, _ = submit({"kind": "toy", "params": {"n": 1, "sleep": 8.0}}, jobs, store)
    claimed = jobs.claim("test-worker", settings.lease_seconds, job_id=job.id)
    assert claimed is not None
    wedged = threading.Event()
    outcome: list[str] = []
    run = threading.Thread(
        target=lambda: outcome.append(
            execute(claimed, jobs=jobs, store=store, lease_seconds=settings.lease_seconds,
                    executor=LocalPoolExecutor(2), on_wedged=wedged.set)
        )
    )  # fmt: skip
    run.start()
    time.sleep(0.5)
    jobs.cancel(job.id)
    t0 = time.monotonic()
    # The grace is max(5 s, the lease); the heartbeat looks every lease / 3.
    assert wedged.wait(timeout=7.5), "on_wedged was not called"
    assert time.monotonic() - t0 >= 4.5
    run.join(timeout=20)
    assert outcome == ["cancelled"]
