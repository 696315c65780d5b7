"""Shards stored by their own tasks (``MATFORGE_SHARED_STORE=1``), without Ray.

Oracles: the same shards' artifact digests and bytes through the ordinary path, where the
job's thread stores every result (same bytes either way); which process wrote the shard
objects (counted by wrapping the job thread's ``ArtifactStore.put_bytes``); the shards
recorded before an interruption, which a resumed run must not compute again.
"""

from __future__ import annotations

import dataclasses
import hashlib
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import pytest

from jobapi.context import JobContext
from jobapi.errors import JobFailed
from jobapi.executor import InlineExecutor, StoreShard, uses_shared_store
from storage.artifacts import ArtifactStore, ObjectInfo
from storage.errors import IntegrityError, NotFoundError
from storage.jobs import JobStore
from tests.helpers.monitors import CrashAfter

CALLS: list[int] = []


def shard(i: int) -> bytes:
    """Seeded bytes of shard ``i`` (a module-level function, as executors require)."""
    CALLS.append(i)
    return hashlib.sha256(f"shard/{i}".encode()).digest() * 64


class SharedInline(InlineExecutor):
    """The inline executor, declaring that its shards see the job's store."""

    shared_store = True


class ElsewhereStore(InlineExecutor):
    """Declares a shared store, but its shards write into another directory: a node that
    does not in fact see the job's store at its path."""

    shared_store = True

    def __init__(self, root: Path) -> None:
        self.root = root

    def map(self, fn: Callable[[Any], Any], items: Sequence[Any]) -> Iterator[tuple[int, Any]]:
        assert isinstance(fn, StoreShard)
        yield from super().map(dataclasses.replace(fn, root=str(self.root)), items)


class Crash(Exception):
    """The job's thread dies mid-job (as a killed worker would, from the store's view)."""


def context(tmp_path: Path, executor: Any, **kw: Any) -> JobContext:
    """A context over the store and job store in ``tmp_path``, for its one job (queued on
    the first call, the same job on the next: a re-run)."""
    jobs = JobStore(tmp_path / "jobs.sqlite3")
    spec = {"kind": "none", "seed": 0}
    job, _ = jobs.submit(kind="none", name=None, seed=0, spec_hash="0" * 64, spec=spec)
    return JobContext(
        job_id=job.id,
        seed=0,
        spec=spec,
        store=ArtifactStore(tmp_path / "store"),
        jobs=jobs,
        workdir=tmp_path,
        executor=executor,
        **kw,
    )


NAMES = [f"shard-{i:04d}.bin" for i in range(5)]


def test01_same_digests_and_the_job_thread_writes_no_shard(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    plain = context(tmp_path / "plain", InlineExecutor())
    expected = {r.name: r.digest for r in plain.map_artifact_shards(shard, range(5), NAMES)}

    written: list[str] = []
    put = ArtifactStore.put_bytes

    def counting_put(self: ArtifactStore, data: bytes) -> ObjectInfo:
        info = put(self, data)
        written.append(info.digest)
        return info

    ctx = context(tmp_path / "shared", SharedInline())
    assert uses_shared_store(ctx.executor) and not uses_shared_store(InlineExecutor())
    # The job's own storing (JobContext.put_bytes) is never called for a shard; the
    # store's put_bytes is, once per shard, by StoreShard (here in the same process).
    monkeypatch.setattr(JobContext, "put_bytes", lambda *a, **k: pytest.fail("job stored"))
    monkeypatch.setattr(ArtifactStore, "put_bytes", counting_put)
    records = ctx.map_artifact_shards(shard, range(5), NAMES)
    assert {r.name: r.digest for r in records} == expected
    assert sorted(written) == sorted(expected.values())  # each written once, by StoreShard
    for r in records:  # in the job's store, the same bytes, recorded as its shards
        assert ctx.store.read(r.digest) == plain.store.read(r.digest)
    assert ctx.jobs.shards(ctx.job_id) == expected
    assert {n: a.size for n, a in ctx.artifacts.items()} == {n: 2048 for n in NAMES}


def test02_a_crash_mid_job_loses_no_recorded_shard(tmp_path: Path) -> None:
    CALLS.clear()
    with pytest.raises(Crash):
        context(tmp_path, SharedInline(), monitor=CrashAfter(4, Crash)).map_artifact_shards(
            shard, range(5), NAMES
        )
    assert CALLS == [0, 1, 2]  # the third shard was stored and recorded, then the crash
    CALLS.clear()
    ctx = context(tmp_path, SharedInline())
    assert len(ctx.jobs.shards(ctx.job_id)) == 3
    records = ctx.map_artifact_shards(shard, range(5), NAMES)
    assert CALLS == [3, 4]  # the recorded shards were registered, not computed again
    plain = context(tmp_path / "plain", InlineExecutor())
    assert records == plain.map_artifact_shards(shard, range(5), NAMES)


def test03_a_store_that_is_not_shared_fails_the_job_naming_it(tmp_path: Path) -> None:
    """The node has a store of its own at the path (a local directory where the mount
    should be): its shards' objects are not where the job looks."""
    ArtifactStore(tmp_path / "node-local")
    ctx = context(tmp_path, ElsewhereStore(tmp_path / "node-local"))
    with pytest.raises(JobFailed, match="MATFORGE_SHARED_STORE=1 every node must mount"):
        ctx.map_artifact_shards(shard, range(2), NAMES[:2])
    assert ctx.jobs.shards(ctx.job_id) == {}


def test04_check_stored_is_a_stat_not_a_hash(tmp_path: Path) -> None:
    store = ArtifactStore(tmp_path)
    info = store.put_bytes(b"x" * 100)
    store.check_stored(info)
    with pytest.raises(IntegrityError, match="has 100 bytes in the store, expected 99"):
        store.check_stored(ObjectInfo(info.digest, 99))
    with pytest.raises(NotFoundError, match="no object sha256:" + "0" * 64):
        store.check_stored(ObjectInfo("0" * 64, 1))
    # Same size, other bytes: check_stored passes (no hashing); the read catches it.
    path = store.path(info.digest)
    path.chmod(0o644)
    path.write_bytes(b"y" * 100)
    store.check_stored(info)
    with pytest.raises(IntegrityError):
        store.read(info.digest)


def test05_store_shard_refuses_a_result_that_is_not_bytes(tmp_path: Path) -> None:
    with pytest.raises(TypeError, match="returned int, not bytes"):
        StoreShard(len, str(tmp_path))("abc")


def test06_the_process_pool_stores_in_its_processes_too(tmp_path: Path) -> None:
    """``MATFORGE_SHARED_STORE=1`` with the local pool: :class:`StoreShard` pickles into
    spawned processes, which store the shards; the records equal the inline path's."""
    from service.workers.executors import LocalPoolExecutor

    pool = LocalPoolExecutor(2, shared_store=True)
    before = len(CALLS)
    try:
        records = context(tmp_path / "pool", pool).map_artifact_shards(shard, range(4), NAMES[:4])
    finally:
        pool.close()
    assert len(CALLS) == before  # the shards ran in the pool's processes, not here
    plain = context(tmp_path / "plain", InlineExecutor())
    assert records == plain.map_artifact_shards(shard, range(4), NAMES[:4])


def test07_a_node_without_the_store_refuses_to_make_one(tmp_path: Path) -> None:
    """A shard task where the shared store is not mounted fails, naming the path, and
    leaves no store of its own there."""
    root = tmp_path / "not-mounted" / "store"
    with pytest.raises(NotFoundError, match="no artifact store at .*not-mounted.*must mount"):
        StoreShard(shard, str(root))(0)
    assert not root.exists()
