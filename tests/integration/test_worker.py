"""Workers through the registry: running, failing, cancelling, shard resumption, recycling."""

from __future__ import annotations

import json
import os
import pickle
import signal
import threading
import time

import pytest

from service.specs import validate_spec
from service.submission import submit
from service.workers.execution import execute
from service.workers.worker import Supervisor, run_worker
from storage.artifacts import ArtifactStore
from storage.jobs import JobStore


def _queue(jobs: JobStore, store: ArtifactStore, **params) -> str:
    job, created = submit({"kind": "toy", "params": params}, jobs, store)
    assert created
    return job.id


def test01_worker_runs_job_and_writes_manifest(toy_kind, settings, jobs, store) -> None:
    job_id = _queue(jobs, store, n=3)
    assert run_worker(settings, max_jobs=1) == 1
    job = jobs.get(job_id)
    assert job.state == "succeeded" and job.progress == 1.0 and job.attempts == 1
    # The runner's last progress line stays after success (the toy's shard count).
    assert job.message == "done: toys: 3/3"
    result = json.loads(store.read(job.artifacts[0].digest))
    assert result["squares"] == [0, 1, 4]
    manifest = json.loads(store.read(job.manifest_digest))
    assert manifest["spec"] == job.spec and manifest["seed"] == 0
    assert manifest["artifacts"][0]["name"] == "result.json"
    assert {"mitsuba", "drjit", "torch", "numpy"} <= set(manifest["packages"])
    assert manifest["code_version"]
    assert (manifest["executor"], manifest["executor_nodes"]) == ("process", 1)
    # MATFORGE_VARIANT as the worker resolved it at start-up (auto: no CUDA here, so LLVM
    # where libLLVM-19 is installed); no device: the toy kind trains nothing.
    assert manifest["variant"] in ("llvm_ad_rgb", "cuda_ad_rgb", "scalar_rgb")
    assert manifest["device"] is None


def test02_same_seed_same_bytes_other_seed_differs(toy_kind, settings, jobs, store) -> None:
    digests = []
    for seed, force in ((5, False), (5, True), (6, False)):
        job, _ = submit(
            {"kind": "toy", "seed": seed, "force": force, "params": {"n": 1}}, jobs, store
        )
        run_worker(settings, max_jobs=1)
        digests.append(jobs.get(job.id).artifacts[0].digest)
    assert digests[0] == digests[1] != digests[2]


def test03_job_failed_gives_one_line_error(toy_kind, settings, jobs, store) -> None:
    job_id = _queue(jobs, store, fail=True)
    run_worker(settings, max_jobs=1)
    job = jobs.get(job_id)
    assert job.state == "failed" and job.error == "toy failure requested by params.fail"
    assert job.artifacts == []


def test04_finished_shards_are_not_redone(toy_kind, settings, jobs, store) -> None:
    """A re-run after a crash loads recorded shards: the sentinel values prove it."""
    job_id = _queue(jobs, store, n=4)
    for key in ("toy-00000", "toy-00002"):
        jobs.record_shard(job_id, key, store.put_bytes(pickle.dumps(-7)).digest)
    run_worker(settings, max_jobs=1)
    job = jobs.get(job_id)
    assert json.loads(store.read(job.artifacts[0].digest))["squares"] == [-7, 1, -7, 9]


def test05_cancel_reaches_running_job(toy_kind, settings, jobs, store) -> None:
    job_id = _queue(jobs, store, n=40, sleep=0.05)
    t = threading.Thread(target=run_worker, args=(settings,), kwargs={"max_jobs": 1})
    t.start()
    deadline = time.time() + 20
    while jobs.get(job_id).state != "running" and time.time() < deadline:
        time.sleep(0.02)
    time.sleep(0.2)
    jobs.cancel(job_id)
    t.join(timeout=20)
    assert not t.is_alive()
    job = jobs.get(job_id)
    assert job.state == "cancelled" and job.artifacts == []
    assert len(jobs.shards(job_id)) < 40  # it stopped early


def test06_lost_lease_cannot_write(toy_kind, settings, jobs, store) -> None:
    job_id = _queue(jobs, store, n=1)
    job = jobs.claim("w:stale", 0.01)
    time.sleep(0.05)
    jobs.reap(settings.max_attempts)
    fresh = jobs.claim("w:fresh", 30)
    assert fresh.id == job_id
    assert execute(job, jobs=jobs, store=store, lease_seconds=0.01) == "lost"
    assert jobs.get(job_id).state == "running" and jobs.get(job_id).worker == "w:fresh"
    assert execute(fresh, jobs=jobs, store=store, lease_seconds=30) == "succeeded"


def test07_spec_validated_before_queueing(toy_kind, jobs, store) -> None:
    import pytest

    from jobapi.errors import SpecError

    with pytest.raises(SpecError, match="params.n"):
        submit({"kind": "toy", "params": {"n": -1}}, jobs, store)
    with pytest.raises(SpecError, match="no job"):
        submit(
            {
                "kind": "score",
                "params": {
                    "reference": "job:" + "0" * 32 + "/image.exr",
                    "candidates": {"a": "sha256:" + "1" * 64},
                },
            },
            jobs,
            store,
        )
    assert jobs.list_jobs() == []
    validate_spec({"kind": "toy"})


def test08_supervisor_replaces_dead_and_recycled_workers(settings) -> None:
    sup = Supervisor(settings.with_(recycle_after_jobs=0), n=2, check_seconds=0.1)
    sup.start()
    try:
        deadline = time.time() + 30
        while len(sup.worker_pids()) < 2 and time.time() < deadline:
            time.sleep(0.05)
        first = sup.worker_pids()
        assert len(first) == 2
        os.kill(first[0], signal.SIGKILL)
        while (
            first[0] in sup.worker_pids() or len(sup.worker_pids()) < 2
        ) and time.time() < deadline:
            time.sleep(0.05)
        now = sup.worker_pids()
        assert len(now) == 2 and first[0] not in now and first[1] in now
        assert sup.started_total == 3
    finally:
        sup.stop()
    assert sup.worker_pids() == []


def test09_run_in_process_resumes_a_job_whose_process_died(toy_kind, settings, jobs, store) -> None:
    """``matforge run`` after a killed ``matforge run``: the job left ``running`` under an
    expired lease is re-queued (as the server's reaper does) and resumes from its shards,
    rather than being returned as a job that is still running."""
    from service.submission import run_in_process

    job_id = _queue(jobs, store, n=3)
    claimed = jobs.claim("dead-worker", lease_seconds=0.01, job_id=job_id)
    assert claimed is not None and claimed.state == "running"
    jobs.record_shard(job_id, "toy-00001", store.put_bytes(pickle.dumps(-7)).digest)
    time.sleep(0.05)
    job = run_in_process({"kind": "toy", "params": {"n": 3}}, settings)
    assert job.id == job_id and job.state == "succeeded" and job.attempts == 2
    assert json.loads(store.read(job.artifacts[0].digest))["squares"] == [0, -7, 4]


def test10_unreachable_executor_leaves_the_queue_alone(
    toy_kind, settings, jobs, store, monkeypatch
) -> None:
    """``MATFORGE_EXECUTOR=ray`` with no cluster: the worker exits 3 and ``matforge run``
    raises before claiming, so the job stays queued for a worker that can reach it."""
    from jobapi.errors import ExecutorUnavailable
    from jobapi.executor import InlineExecutor
    from service import submission
    from service.workers import worker

    class Unreachable(InlineExecutor):
        def start(self) -> None:
            raise ExecutorUnavailable("cannot start or reach 10.9.9.9:6379: refused")

    monkeypatch.setattr(worker, "executor_for", lambda s: Unreachable())
    monkeypatch.setattr(submission, "executor_for", lambda s: Unreachable())
    monkeypatch.setenv("MATFORGE_DATA", str(settings.data_dir))
    monkeypatch.setattr(worker.signal, "signal", lambda *a: None)  # keep pytest's SIGTERM
    job_id = _queue(jobs, store, n=2)
    assert worker.main(["--data-dir", str(settings.data_dir), "--max-jobs", "1"]) == 3
    with pytest.raises(ExecutorUnavailable, match="10.9.9.9"):
        submission.run_in_process({"kind": "toy", "params": {"n": 2}}, settings)
    job = jobs.get(job_id)
    assert job.state == "queued" and job.attempts == 0
