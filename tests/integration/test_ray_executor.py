"""Jobs whose shards run as Ray tasks (``MATFORGE_EXECUTOR=ray``) on one local Ray.

Oracles: the same spec's artifact digests from the local process pool (same bytes on either
backend); the probe kind's marker files (how often, and whether, a shard ran again); the
manifest's ``executor``. The Ray is the session's (``ray_local``: 2 CPUs, token auth, no
dashboard), started once and shut down at the end.
"""

from __future__ import annotations

import pickle
from typing import Any

import pytest

from jobapi import kinds as jobapi_kinds
from service import kinds
from service.submission import run_in_process, submit
from service.workers.worker import run_worker
from storage.artifacts import ArtifactStore
from storage.jobs import JobStore
from tests.helpers.ray_probe import PROBE, calls, digests, manifest, probe_spec

pytestmark = pytest.mark.ray

#: generate.fabric cut down to 2 materials x 128 queries x 32 samples in 4 shards.
FABRIC: dict[str, Any] = {
    "preset": "small",
    "patterns": ["plain", "twill_3x3"],
    "queries_per_material": 128,
    "shard_queries": 64,
    "samples": 32,
    "map_resolution": 8,
}


@pytest.fixture
def probe_kind(monkeypatch: pytest.MonkeyPatch) -> None:
    kinds.load_builtin()
    monkeypatch.setitem(jobapi_kinds._KINDS, "probe", PROBE)


def test01_worker_runs_a_job_on_ray(ray_local, probe_kind, settings, tmp_path) -> None:
    """The worker picks Ray from its settings; shards run there; the manifest says so."""
    settings = settings.with_(executor="ray")
    log_dir = tmp_path / "calls"
    log_dir.mkdir()
    jobs, store = JobStore(settings.db_path), ArtifactStore(settings.store_dir)
    job, _ = submit(probe_spec(log_dir, n=4), jobs, store)
    assert run_worker(settings, max_jobs=1) == 1
    job = jobs.get(job.id)
    assert job.state == "succeeded", job.error
    assert len(job.artifacts) == 4
    ran = calls(log_dir)
    assert sorted(ran) == [0, 1, 2, 3] and all(len(v) == 1 for v in ran.values())
    assert all(node != "local" for v in ran.values() for node in v)  # inside Ray tasks
    m = manifest(settings, job)
    assert (m["executor"], m["executor_nodes"]) == ("ray", 1)
    # Ray was the session's: the worker's executor left it running for the next tests.
    import ray

    assert ray.is_initialized()


def test02_transient_errors_are_retried(ray_local, probe_kind, settings, tmp_path) -> None:
    settings = settings.with_(executor="ray")
    log_dir = tmp_path / "calls"
    log_dir.mkdir()
    job = run_in_process(probe_spec(log_dir, n=3, flaky=True), settings)
    assert job.state == "succeeded", job.error
    assert {i: len(v) for i, v in calls(log_dir).items()} == {0: 2, 1: 2, 2: 2}


def test03_other_errors_fail_at_once(ray_local, probe_kind, settings, tmp_path) -> None:
    """A deterministic error is the shard's own: not retried, and named as the pool would."""
    settings = settings.with_(executor="ray")
    log_dir = tmp_path / "calls"
    log_dir.mkdir()
    job = run_in_process(probe_spec(log_dir, n=2, bad=True), settings)
    assert job.state == "failed"
    assert job.error is not None and "ValueError: probe shard" in job.error
    assert "Traceback" not in job.error and "\n" not in job.error
    assert all(len(v) == 1 for v in calls(log_dir).values())


def test03b_a_shard_that_keeps_crashing_fails_the_job_after_its_retries(
    ray_local, probe_kind, settings, tmp_path
) -> None:
    settings = settings.with_(executor="ray", ray_max_retries=1)
    log_dir = tmp_path / "calls"
    log_dir.mkdir()
    job = run_in_process(probe_spec(log_dir, n=1, crash=True), settings)
    assert job.state == "failed"
    assert job.error is not None and "shard 0 lost after 1 retries on Ray" in job.error
    assert {i: len(v) for i, v in calls(log_dir).items()} == {0: 2}


def test04_finished_shards_are_not_redone(ray_local, probe_kind, settings, tmp_path) -> None:
    """Resume on Ray as on the pool: recorded shards are registered again, not recomputed."""
    settings = settings.with_(executor="ray")
    log_dir = tmp_path / "calls"
    log_dir.mkdir()
    jobs, store = JobStore(settings.db_path), ArtifactStore(settings.store_dir)
    job, _ = submit(probe_spec(log_dir, n=3), jobs, store)
    sentinel = store.put_bytes(pickle.dumps("sentinel")).digest
    jobs.record_shard(job.id, "probe-001.bin", sentinel)
    job = run_in_process(probe_spec(log_dir, n=3), settings)
    assert job.state == "succeeded", job.error
    assert sorted(calls(log_dir)) == [0, 2]
    assert digests(job)["probe-001.bin"] == sentinel


@pytest.mark.parametrize("shared_store", [False, True])
def test05_generate_fabric_same_bytes_as_the_process_pool(
    ray_local, settings, shared_store: bool
) -> None:
    """With ``shared_store`` the Ray tasks write the npz shards into the store themselves
    (``MATFORGE_SHARED_STORE=1``); the pool's job stores the returned bytes."""
    spec = {"kind": "generate.fabric", "seed": 11, "params": FABRIC}
    on_pool = run_in_process(spec, settings.with_(executor="process"))
    on_ray = run_in_process(
        {**spec, "force": True}, settings.with_(executor="ray", shared_store=shared_store)
    )
    assert on_pool.state == on_ray.state == "succeeded", (on_pool.error, on_ray.error)
    assert on_ray.id != on_pool.id
    assert len([n for n in digests(on_ray) if n.startswith("shard-")]) == 4
    assert digests(on_ray) == digests(on_pool)
    assert manifest(settings, on_pool)["executor"] == "process"
    assert manifest(settings, on_ray)["executor"] == "ray"


#: The other sharding kinds, cut down: two shards of Mitsuba-rendered BTF slices (their
#: surface maps are arrays inside the shard items), and a MERL collection of one material
#: (a full 90 x 90 x 180 table per shard, so one is enough) with measurement noise.
OTHER_KINDS = {
    "generate.btf": {
        "surface": {"procedural": "stone", "size": 8},
        "directions": [[0, 0, 0, 0], [45, 0, 30, 180]],
        "resolution": 8,
        "spp": 2,
        "shard_slices": 1,
    },
    "generate.merl": {
        "collection": {"families": {"paint": 1}},
        "measurement": {"noise_sigma": 0.05, "dropout": 0.01},
    },
}


@pytest.mark.parametrize("kind", sorted(OTHER_KINDS))
def test06_other_sharding_kinds_same_bytes(ray_local, settings, kind: str) -> None:
    spec = {"kind": kind, "seed": 7, "params": OTHER_KINDS[kind]}
    on_pool = run_in_process(spec, settings.with_(executor="process"))
    on_ray = run_in_process({**spec, "force": True}, settings.with_(executor="ray"))
    assert on_pool.state == on_ray.state == "succeeded", (on_pool.error, on_ray.error)
    assert digests(on_ray, frozenset()) == digests(on_pool, frozenset())
    assert manifest(settings, on_ray)["executor"] == "ray"


def test07_select_renders_its_rungs_on_ray(ray_local, settings) -> None:
    """``select``'s scene mode fans its rung renders out as shards: on Ray the images (and
    the values, the choice) are the process pool's; only the timings differ."""
    from tests.integration.test_select_scene import SPEC

    on_pool = run_in_process(SPEC, settings.with_(executor="process"))
    on_ray = run_in_process({**SPEC, "force": True}, settings.with_(executor="ray"))
    assert on_pool.state == on_ray.state == "succeeded", (on_pool.error, on_ray.error)
    timed = frozenset({"select.json"})
    assert digests(on_ray, timed) == digests(on_pool, timed)
    assert any(n.startswith("rung_") for n in digests(on_ray))
    assert manifest(settings, on_ray)["executor"] == "ray"
