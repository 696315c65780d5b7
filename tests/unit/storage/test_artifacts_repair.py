"""A corrupt object is replaced by the next write of its bytes (issue 15, B1), and stale work
directories of killed workers are found. Reference: hashlib's sha256 of the bytes."""

from __future__ import annotations

import hashlib
import io
import os
from pathlib import Path

import pytest

from storage.artifacts import ArtifactStore
from storage.errors import IntegrityError
from storage.scratch import collect_scratch, scratch_prefix, stale_dirs


def _damage(store: ArtifactStore, digest: str, data: bytes) -> None:
    p = store.path(digest)
    os.chmod(p, 0o644)
    p.write_bytes(data)
    os.chmod(p, 0o444)


@pytest.mark.parametrize("damage", [b"precious bytez", b"short", b""])
def test01_put_bytes_replaces_a_corrupt_object(store: ArtifactStore, damage: bytes) -> None:
    data = b"precious bytes"
    info = store.put_bytes(data)
    _damage(store, info.digest, damage)
    with pytest.raises(IntegrityError):
        store.read(info.digest)
    assert store.put_bytes(data) == info
    assert store.read(info.digest) == data
    assert not store.path(info.digest).stat().st_mode & 0o222  # read-only again
    assert list(store.tmp.iterdir()) == []


def test02_put_stream_and_file_replace_a_corrupt_object(
    store: ArtifactStore, tmp_path: Path
) -> None:
    data = os.urandom(3 << 20)
    info = store.put_stream(io.BytesIO(data))
    _damage(store, info.digest, data[:-1] + bytes([data[-1] ^ 1]))  # same size, one bit
    assert not store.verify(info.digest)
    store.put_stream(io.BytesIO(data))
    assert store.verify(info.digest)
    _damage(store, info.digest, b"x")
    src = tmp_path / "good.bin"
    src.write_bytes(data)
    assert store.put_file(src).digest == hashlib.sha256(data).hexdigest()
    assert store.read(info.digest) == data


def test03_intact_object_is_not_rewritten(store: ArtifactStore) -> None:
    info = store.put_bytes(b"abc")
    before = store.path(info.digest).stat()
    store.put_bytes(b"abc")
    store.put_stream([b"a", b"bc"])
    after = store.path(info.digest).stat()
    assert (after.st_ino, after.st_mtime_ns) == (before.st_ino, before.st_mtime_ns)


def test04_stale_scratch_dirs(tmp_path: Path) -> None:
    scratch = tmp_path / "scratch"
    live_job, dead_job, requeued_job = "a" * 32, "b" * 32, "c" * 32
    mine = scratch / (scratch_prefix(live_job) + "x1")  # this process, job running
    killed = scratch / f"job-{dead_job[:8]}-999999-x2"  # its job is no longer running
    old_worker = scratch / f"job-{requeued_job[:8]}-999998-x3"  # job now runs elsewhere
    legacy = scratch / f"job-{live_job[:8]}-abcd"  # old naming, job running: kept
    other = scratch / "not-a-job-dir"
    for d in (mine, killed, old_worker, legacy, other):
        (d / "sub").mkdir(parents=True)
        (d / "sub" / "f.bin").write_bytes(b"0" * 100)
    running = [(live_job, f"host:{os.getpid()}"), (requeued_job, "host:4242")]
    stale, kept = stale_dirs(scratch, lambda: running)
    assert sorted(p.name for p in stale) == sorted([killed.name, old_worker.name])
    assert kept == 2
    dry = collect_scratch(scratch, lambda: running, dry_run=True)
    assert dry.bytes_freed == 200 and killed.exists()
    done = collect_scratch(scratch, lambda: running, dry_run=False)
    assert sorted(done.removed) == sorted([killed.name, old_worker.name])
    assert not killed.exists() and not old_worker.exists()
    assert mine.exists() and legacy.exists() and other.exists()
    assert stale_dirs(tmp_path / "missing", lambda: running) == ([], 0)
