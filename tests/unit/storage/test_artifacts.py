"""Content-addressed store. Reference: hashlib's sha256 of the bytes (not our code)."""

from __future__ import annotations

import hashlib
import os
import stat
import time

import pytest

from storage.artifacts import ArtifactStore, check_digest
from storage.errors import IntegrityError, NotFoundError, TooLargeError


def test01_put_read_roundtrip(store: ArtifactStore) -> None:
    data = b"matforge" * 1000
    info = store.put_bytes(data)
    assert info.digest == hashlib.sha256(data).hexdigest()
    path = store.path(info.digest)
    assert path.parent.name == info.digest[:2] and path.name == info.digest[2:]
    assert store.read(info.digest) == data
    assert store.read("sha256:" + info.digest) == data


def test02_objects_read_only_and_idempotent(store: ArtifactStore) -> None:
    info = store.put_bytes(b"abc")
    mode = store.path(info.digest).stat().st_mode
    assert not mode & (stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH)
    assert store.put_bytes(b"abc") == info
    assert list(store.tmp.iterdir()) == []  # no temp file left behind


def test03_corruption_detected_on_read(store: ArtifactStore) -> None:
    info = store.put_bytes(b"precious bytes")
    p = store.path(info.digest)
    os.chmod(p, 0o644)
    p.write_bytes(b"precious bytez")
    with pytest.raises(IntegrityError, match="corrupt"):
        store.read(info.digest)
    with pytest.raises(IntegrityError):
        store.open_verified(info.digest)
    report = store.verify_all()
    assert report.corrupt == [info.digest] and not report.ok


@pytest.mark.parametrize(
    "bad", ["../../etc/passwd", "ABC", "g" * 64, "a" * 63, "A" * 64, "sha256:" + "a" * 65, ""]
)
def test04_digest_pattern_is_strict(bad: str) -> None:
    with pytest.raises(ValueError):
        check_digest(bad)


def test05_missing_object(store: ArtifactStore) -> None:
    with pytest.raises(NotFoundError):
        store.read("0" * 64)


def test06_stream_with_cap(store: ArtifactStore) -> None:
    chunks = [b"x" * 1000] * 5
    info = store.put_stream(iter(chunks), max_bytes=5000)
    assert info.size == 5000
    with pytest.raises(TooLargeError):
        store.put_stream(iter(chunks + [b"y"]), max_bytes=5000)
    assert list(store.tmp.iterdir()) == []


def test07_gc_respects_references_and_grace(store: ArtifactStore) -> None:
    keep = store.put_bytes(b"referenced").digest
    old = store.put_bytes(b"old unreferenced").digest
    new = store.put_bytes(b"new unreferenced").digest
    past = time.time() - 3 * 3600
    for d in (keep, old):
        os.utime(store.path(d), (past, past))
    dry = store.gc({keep}, grace_seconds=3600, dry_run=True)
    assert dry.removed == [old] and dry.dry_run and store.exists(old)
    real = store.gc({keep}, grace_seconds=3600, dry_run=False)
    assert real.removed == [old]
    assert not store.exists(old) and store.exists(keep) and store.exists(new)
    assert real.kept_recent == 1 and real.kept_referenced == 1
