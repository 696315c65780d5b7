"""Corrupt objects and the jobs on top of them (issue 15, B1): a forced re-run repairs its
artifacts instead of succeeding over damaged bytes, and ``repair`` restores objects from a
good copy or by re-running the producing job, reporting what it cannot repair."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from service.repair import repair
from service.submission import import_file, run_in_process
from storage.artifacts import ArtifactStore
from storage.formats.png import write_png
from storage.jobs import JobStore


def _damage(store: ArtifactStore, digest: str) -> None:
    p = store.path(digest)
    os.chmod(p, 0o644)
    p.write_bytes(p.read_bytes()[:-1] + b"#")


def test01_forced_rerun_repairs_the_artifact(toy_kind, settings, jobs, store) -> None:
    spec = {"kind": "toy", "params": {"n": 2}}
    first = run_in_process(spec, settings)
    digest = first.artifacts[0].digest
    _damage(store, digest)
    again = run_in_process({**spec, "force": True}, settings)
    assert again.state == "succeeded" and again.artifacts[0].digest == digest
    assert store.verify(digest), "the re-run succeeded over the damaged object"


def test02_repair_by_rerun_copy_or_report(
    toy_kind, settings, jobs: JobStore, store: ArtifactStore, tmp_path: Path
) -> None:
    job = run_in_process({"kind": "toy", "params": {"n": 2}}, settings)
    art = job.artifacts[0].digest
    png = tmp_path / "originals" / "pic.png"
    png.parent.mkdir()
    png.write_bytes(write_png(None, np.zeros((4, 4, 3), np.uint8)))
    up = import_file(png, jobs, store).digest
    other = tmp_path / "other.png"
    other.write_bytes(write_png(None, np.ones((4, 4, 3), np.uint8)))
    lost = import_file(other, jobs, store).digest
    for d in (art, up, lost):
        _damage(store, d)
    assert sorted(store.verify_all().corrupt) == sorted([art, up, lost])

    out = {r.digest: r for r in repair([art, up, lost], jobs, store, settings, [png.parent])}
    assert out[art].repaired and f"re-ran job {job.id}" in out[art].how
    assert out[up].repaired and str(png) in out[up].how
    assert not out[lost].repaired and "other.png" in out[lost].how and "import" in out[lost].how
    assert store.verify_all().corrupt == [lost]


def _move_out(store: ArtifactStore, digest: str, to: Path) -> None:
    """What an operator's ``mv`` does: the object leaves ``store/objects``."""
    to.mkdir(parents=True, exist_ok=True)
    store.path(digest).rename(to / digest)


def test03_a_moved_object_is_missing_repaired_and_never_reused(
    toy_kind, settings, jobs: JobStore, store: ArtifactStore, tmp_path: Path
) -> None:
    """Issue 21 item 7: an object moved out of the store is reported missing (verify used
    to say "all intact"), ``repair`` re-runs the job that produced it, and resubmitting the
    spec runs it again instead of returning the job whose artifact is gone."""
    spec = {"kind": "toy", "params": {"n": 2}}
    first = run_in_process(spec, settings)
    digest = first.artifacts[0].digest
    _move_out(store, digest, tmp_path / "moved")
    report = store.verify_all(jobs.referenced_digests())
    assert report.missing == [digest] and report.corrupt == [] and not report.ok

    out = repair([digest], jobs, store, settings)
    assert out[0].repaired and f"re-ran job {first.id}" in out[0].how, out
    assert store.verify(digest) and store.verify_all(jobs.referenced_digests()).ok

    _move_out(store, digest, tmp_path / "moved-again")
    again = run_in_process(spec, settings)  # no force
    assert again.id != first.id and again.state == "succeeded"
    assert again.artifacts[0].digest == digest and store.verify(digest)
    # Intact again: the next resubmission reuses the newest job, as before.
    assert run_in_process(spec, settings).id == again.id


def test04_a_server_submission_does_not_reuse_a_job_that_lost_its_artifact(
    toy_kind, settings, jobs: JobStore, store: ArtifactStore, tmp_path: Path
) -> None:
    """The REST route queues through the same check as ``matforge run``: ``POST /api/jobs``
    of a spec whose succeeded job lost an object queues a new job (201, created), and of one
    whose job is intact returns that job (200)."""
    from fastapi.testclient import TestClient

    from service.api import create_app

    spec = {"kind": "toy", "params": {"n": 2}}
    first = run_in_process(spec, settings)
    with TestClient(create_app(settings)) as client:
        same = client.post("/api/jobs", json=spec)
        assert same.status_code == 200 and same.json()["id"] == first.id, same.text
        _move_out(store, first.artifacts[0].digest, tmp_path / "moved")
        again = client.post("/api/jobs", json=spec)
        assert again.status_code == 201, again.text
        assert again.json()["id"] != first.id and again.json()["state"] == "queued"
