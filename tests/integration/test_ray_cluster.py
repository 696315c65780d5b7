"""A job on a simulated two-node Ray cluster (``ray.cluster_utils.Cluster``, one machine).

Oracles: the marker files of the probe kind (which node ran each shard, and how often); the
digests of the same spec run on the local process pool; the manifest's node count. The
cluster replaces the session's local Ray for this module and is shut down after it.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from jobapi import kinds as jobapi_kinds
from service import kinds
from service.settings import Settings
from service.submission import run_in_process
from storage.jobs import Job
from tests.helpers.ray_probe import PROBE, calls, digests, manifest, probe_spec

pytestmark = pytest.mark.ray


@pytest.fixture
def probe_kind(monkeypatch: pytest.MonkeyPatch) -> None:
    kinds.load_builtin()
    monkeypatch.setitem(jobapi_kinds._KINDS, "probe", PROBE)


@pytest.fixture
def cluster(ray_session: Any) -> Iterator[Any]:
    """A head and one worker node, one CPU each; torn down after the test."""
    c = ray_session.start_cluster(nodes=2)
    try:
        yield c
    finally:
        ray_session.shutdown(keep_env=True)


def wait_for(check: Any, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not check():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.05)


def test01_two_nodes_then_one_lost_mid_job(
    cluster, probe_kind, settings: Settings, tmp_path: Path
) -> None:
    on_ray = settings.with_(executor="ray")
    (worker_node,) = cluster.worker_nodes
    head_id, worker_id = cluster.head_node.node_id, worker_node.node_id

    # Both nodes take shards, and the manifest counts them.
    spread = tmp_path / "spread"
    spread.mkdir()
    job = run_in_process(probe_spec(spread, n=4, sleep=0.5), on_ray)
    assert job.state == "succeeded", job.error
    assert {node for v in calls(spread).values() for node in v} == {head_id, worker_id}
    assert (manifest(on_ray, job)["executor"], manifest(on_ray, job)["executor_nodes"]) == (
        "ray",
        2,
    )

    # The worker node dies while it runs a shard: Ray runs that shard again on the head.
    # (The job above left a warm Ray worker process on each node, so both take shards.)
    lost = tmp_path / "lost"
    lost.mkdir()
    result: dict[str, Job] = {}
    thread = threading.Thread(
        target=lambda: result.update(job=run_in_process(probe_spec(lost, n=6, sleep=0.8), on_ray))
    )
    thread.start()
    wait_for(
        lambda: any(worker_id in v for v in calls(lost).values()), 60, "a shard on the worker node"
    )
    cluster.remove_node(worker_node, allow_graceful=False)
    thread.join(timeout=120)
    assert not thread.is_alive(), "the job did not finish after its node was removed"
    job = result["job"]
    assert job.state == "succeeded", job.error
    ran = calls(lost)
    assert sorted(ran) == list(range(6))
    retried = {i: v for i, v in ran.items() if len(v) > 1}
    assert retried, f"no shard ran twice: {ran}"
    assert all(worker_id in v and head_id in v for v in retried.values()), retried

    # The bytes equal the local process pool's for the same spec.
    local = tmp_path / "local"
    local.mkdir()
    on_pool = run_in_process(probe_spec(local, n=6), settings)
    assert on_pool.state == "succeeded", on_pool.error
    assert digests(job) == digests(on_pool) and len(digests(job)) == 6


def test02_shards_stored_by_their_tasks_on_both_nodes(
    cluster, probe_kind, settings: Settings, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``MATFORGE_SHARED_STORE=1``: both nodes' tasks write their shards into the store
    directory both use, the job's process writes none of them, and the digests are the
    process pool's (which stores the returned bytes itself). Then a job interrupted after
    two recorded shards resumes without computing them again."""
    from jobapi.context import JobContext, NullMonitor
    from service.workers.executors import make_executor
    from storage.artifacts import ArtifactStore, ObjectInfo
    from storage.jobs import JobStore
    from tests.helpers.monitors import CrashAfter
    from tests.helpers.ray_probe import ProbeItem, probe_shard

    shared = settings.with_(executor="ray", shared_store=True)
    (worker_node,) = cluster.worker_nodes
    head_id, worker_id = cluster.head_node.node_id, worker_node.node_id
    written: list[str] = []  # objects this (the job's) process wrote itself
    put = ArtifactStore.put_bytes

    def counting_put(self: ArtifactStore, data: bytes) -> ObjectInfo:
        info = put(self, data)
        written.append(info.digest)
        return info

    spread = tmp_path / "spread"
    spread.mkdir()
    with monkeypatch.context() as m:
        m.setattr(ArtifactStore, "put_bytes", counting_put)
        job = run_in_process(probe_spec(spread, n=4, sleep=0.5), shared)
    assert job.state == "succeeded", job.error
    assert {node for v in calls(spread).values() for node in v} == {head_id, worker_id}
    shard_digests = set(digests(job).values())
    assert len(shard_digests) == 4 and not shard_digests & set(written)
    assert manifest(shared, job)["executor_nodes"] == 2

    local = tmp_path / "local"
    local.mkdir()
    on_pool = run_in_process(probe_spec(local, n=4), settings)
    assert on_pool.state == "succeeded", on_pool.error
    assert digests(job) == digests(on_pool)

    # Interrupted after its second recorded shard (the job's thread dies, as a killed
    # worker's would), then run again: the two are registered, not computed again.
    resumed = tmp_path / "resumed"
    resumed.mkdir()
    jobs, store = JobStore(shared.db_path), ArtifactStore(shared.store_dir)
    queued, _ = jobs.submit(kind="probe", name=None, seed=3, spec_hash="1" * 64, spec={})
    items = [ProbeItem(i, 3, 0.2, str(resumed), False, False) for i in range(4)]
    names = [f"probe-{i:03d}.bin" for i in range(4)]
    executor = make_executor("ray", shared_store=True)

    def ctx(monitor: NullMonitor) -> JobContext:
        return JobContext(
            job_id=queued.id, seed=3, spec={}, store=store, jobs=jobs, workdir=tmp_path,
            monitor=monitor, executor=executor,
        )  # fmt: skip

    # KeyboardInterrupt: not an Exception, so nothing on the way catches it.
    with pytest.raises(KeyboardInterrupt):
        ctx(CrashAfter(3, KeyboardInterrupt)).map_artifact_shards(probe_shard, items, names)
    recorded = jobs.shards(queued.id)
    assert len(recorded) == 2
    first = set(calls(resumed))
    records = ctx(NullMonitor()).map_artifact_shards(probe_shard, items, names)
    again = calls(resumed)
    assert all(len(again[int(n[6:9])]) == 1 for n in recorded)  # not run a second time
    assert set(again) == set(range(4)) and first <= set(again)
    assert {r.name: r.digest for r in records} == digests(on_pool)
    jobs.close()
