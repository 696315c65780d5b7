"""Checking a user's model ref at submission (in the web process): a JSON file's ``format``
is read from at most its first ``MODEL_HEAD_BYTES``, never decoded whole; a stored object
whose bytes no longer match its digest is reported as corrupt on disk.

References: stored objects written here byte by byte (``put_bytes``: as a job's artifact or
an object stored before uploads were checked), whose bytes past the head are invalid JSON,
so a check that decoded them would fail; the store's own digest for corruption.
"""

from __future__ import annotations

import tracemalloc
from pathlib import Path
from typing import Any

import pytest

from jobapi.errors import SpecError
from service import kinds
from service.specs import validate_spec
from service.submission import MODEL_HEAD_BYTES, check_refs
from storage.artifacts import ArtifactStore
from storage.jobs import JobStore
from tests.helpers.onnx_models import lambert_model

JUNK = b"[" * 10 + b"not json" * (MODEL_HEAD_BYTES // 4)


@pytest.fixture
def stores(tmp_path: Path) -> tuple[JobStore, ArtifactStore]:
    kinds.load_builtin()
    return JobStore(tmp_path / "jobs.sqlite3"), ArtifactStore(tmp_path / "store")


def _check(stores: tuple[JobStore, ArtifactStore], data: bytes, kind: str) -> list[Any]:
    """The errors of a render spec naming ``data`` (stored) as a ``kind`` model."""
    jobs, store = stores
    ref = f"sha256:{store.put_bytes(data).digest}"
    spec = validate_spec(
        {"kind": "render", "params": {"material": {"external": {"model": ref, "kind": kind}}}}
    )
    try:
        check_refs(spec, jobs, store)
    except SpecError as exc:
        return list(exc.errors)
    return []


def test01_a_json_model_is_told_by_its_head(stores: tuple[JobStore, ArtifactStore]) -> None:
    big = b'{"format": "matforge.mlp-brdf/1", "x": ' + JUNK * 4
    assert _check(stores, big, "brdf") == []  # the kind matches; the job reads the rest
    ((field, message),) = _check(stores, big, "btf")
    assert field == "params.material.external.kind"
    assert "is a brdf model (matforge.mlp-brdf/1), not btf" in message
    ((field, message),) = _check(stores, b'{"format": "other", "x": ' + JUNK, "brdf")
    assert field == "params.material.external.model"
    assert "is a 'other' document, not a model of your own" in message
    # format past the head: not decided here (the job checks the file when it starts)
    assert _check(stores, b'{"x": ' + JUNK + b', "format": "nope"}', "brdf") == []


def test02_a_large_json_costs_the_web_process_little_memory(
    stores: tuple[JobStore, ArtifactStore],
) -> None:
    """A 6 MB ``{"x": [[], [], ...], "format": ...}`` decoded whole is 2 million lists (over
    100 MB of Python objects); read through its head, the check allocates a few MB."""
    data = b'{"x": [' + b"[]," * 2_000_000 + b'[]], "format": "matforge.mlp-brdf/1"}'
    tracemalloc.start()
    try:
        assert _check(stores, data, "brdf") == []
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 16 * 2**20, peak


def test03_a_corrupt_stored_onnx_is_corrupt_on_disk(
    stores: tuple[JobStore, ArtifactStore],
) -> None:
    """An ONNX model whose stored bytes were damaged after it was stored (half of the
    file overwritten with zeros): the store's verification speaks, not the protobuf
    decoder's complaint."""
    jobs, store = stores
    data = lambert_model("brdf").SerializeToString()
    digest = store.put_bytes(data).digest
    path = store.path(digest)
    path.chmod(0o644)
    path.write_bytes(data[: len(data) // 2] + b"\0" * (len(data) - len(data) // 2))
    ref = f"sha256:{digest}"
    spec = validate_spec(
        {"kind": "render", "params": {"material": {"external": {"model": ref, "kind": "brdf"}}}}
    )
    with pytest.raises(SpecError) as info:
        check_refs(spec, jobs, store)
    ((field, message),) = info.value.errors
    assert field == "params.material.external.model"
    assert "corrupt on disk" in message and digest in message, message
    assert "protobuf" not in message, message


def test04_at_most_two_model_files_are_checked_at_once(
    stores: tuple[JobStore, ArtifactStore], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Submissions naming ONNX models (each parsed whole) in many request threads: two
    checks run, a third waits for one of them (the semaphore is taken), and all finish."""
    import threading

    import service.submission as submission
    import storage.formats.onnx as onnx_format

    inside, release = threading.Semaphore(0), threading.Event()

    def held_check(path: Path, name: str, kind: str) -> None:
        inside.release()
        assert release.wait(timeout=30)

    monkeypatch.setattr(onnx_format, "check_onnx_file", held_check)
    data = lambert_model("brdf").SerializeToString()
    results: list[list[Any]] = []
    threads = [
        threading.Thread(target=lambda: results.append(_check(stores, data, "brdf")))
        for _ in range(3)
    ]
    for t in threads:
        t.start()
    assert inside.acquire(timeout=30) and inside.acquire(timeout=30)  # two are checking
    assert submission.MODEL_CHECKS == 2
    assert not submission._MODEL_CHECKS.acquire(blocking=False)  # the third one waits
    release.set()
    for t in threads:
        t.join(timeout=30)
    assert results == [[], [], []]
