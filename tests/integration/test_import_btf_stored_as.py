"""``import.btf`` reads only an object that was checked as an archive when it was stored.

A valid 8 x 8 PNG with a zip appended passes the PNG check, and reads as a zip: the job
used to take any stored object as its archive, by sniffing its bytes. Now the store's
record of the upload decides (``archive`` is marked :class:`jobapi.params.StoredAs`):

- at submission (REST 422, ``matforge run``/``submit`` exit 2), naming ``params.archive``
  and what the object was stored as;
- in the job too (a job queued without that check, by an older server), as its error;
- the same bytes uploaded again as a ``.btf.zip`` pass the archive check, and that record
  is kept beside the first (each format an object passed is recorded).

The angle list is read with a bounded size and line count, by the one reader the upload
check and the job share: a deflated list of blank lines (a few hundred bytes that parse
into 64 bytes of Python objects a line) is refused by both, naming it.
"""

from __future__ import annotations

import io
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from jobapi.errors import SpecError
from service.api import create_app
from service.settings import Settings
from service.specs import validate_spec
from service.submission import import_file, queue_spec, run_in_process
from service.workers.execution import execute_configured, worker_id
from service.workers.executors import executor_for
from storage.artifacts import ArtifactStore
from storage.errors import FormatError
from storage.formats.btf_folder import MAX_LIST_LINES
from storage.formats.png import write_png
from storage.jobs import Job, JobStore

OCTETS = {"content-type": "application/octet-stream"}


def slice_zip(extra_lines: int = 0) -> bytes:
    """A valid two-slice ``.btf.zip`` of 8 x 8 PNGs; ``extra_lines`` blank lines end its
    ``angles.csv``."""
    rng = np.random.default_rng(3)
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for k in range(2):
            zf.writestr(f"s{k}.png", write_png(None, rng.integers(0, 256, (8, 8, 3), np.uint8)))
        rows = "file,theta_i,phi_i,theta_o,phi_o\ns0.png,0,0,10,0\ns1.png,30,90,20,180\n"
        zf.writestr("angles.csv", rows + "\n" * extra_lines)
    return buf.getvalue()


def polyglot() -> bytes:
    """A valid 8 x 8 PNG with a valid ``.btf.zip`` appended."""
    png = write_png(None, np.full((8, 8, 3), 128, np.uint8))
    return png + slice_zip()


def _run_unchecked(raw: dict, settings: Settings) -> Job:
    """Queue ``raw`` without the submission's ref checks (as a job queued by an older
    server) and run it here."""
    jobs, store = JobStore(settings.db_path), ArtifactStore(settings.store_dir)
    job, _ = queue_spec(validate_spec(raw), jobs, store)
    executor = executor_for(settings)
    executor.start()
    try:
        claimed = jobs.claim(worker_id(), settings.lease_seconds, job_id=job.id)
        assert claimed is not None
        execute_configured(claimed, settings, jobs=jobs, store=store, executor=executor)
    finally:
        executor.close()
    return jobs.get(job.id)


def _spec(ref: str) -> dict:
    return {"kind": "import.btf", "params": {"archive": ref}}


def test01_a_png_with_a_zip_appended_is_no_archive(settings: Settings) -> None:
    data = polyglot()
    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        up = client.post("/api/artifacts?name=pic.png", content=data, headers=OCTETS)
        assert up.status_code == 201, up.text  # a valid PNG
        ref = up.json()["ref"]
        r = client.post("/api/jobs", json=_spec(ref))
        assert r.status_code == 422, r.text
        body = r.text
        assert "params.archive" in body and "'pic.png' (image/png)" in body, body
        assert "not checked as a '.btf.zip' or '.btf' file" in body, body
        assert client.get("/api/jobs").json() == []  # refused before queueing
    job = _run_unchecked(_spec(ref), settings)
    assert job.state == "failed", job
    assert job.error is not None, job
    assert job.error.startswith(f"archive: {ref} was stored as 'pic.png'"), job.error
    # The same bytes, uploaded as an archive, pass the archive check: now they import.
    with TestClient(create_app(settings)) as client:
        up = client.post("/api/artifacts?name=scan.btf.zip", content=data, headers=OCTETS)
        assert up.status_code == 201, up.text
        assert up.json()["ref"] == ref
    ok = run_in_process(_spec(ref), settings)
    assert ok.state == "succeeded", ok.error


def test02_an_object_no_upload_stored_is_refused(settings: Settings) -> None:
    store = ArtifactStore(settings.store_dir)
    info = store.put_bytes(slice_zip())  # in the store, but never checked
    with pytest.raises(SpecError) as err:
        run_in_process(_spec(f"sha256:{info.digest}"), settings)
    assert "params.archive" in str(err.value) and "is not an uploaded" in str(err.value)


def test03_a_list_of_blank_lines_is_refused_by_the_check_and_by_the_job(
    settings: Settings, tmp_path: Path
) -> None:
    data = slice_zip(extra_lines=MAX_LIST_LINES)
    assert len(data) < 4096  # deflated: a few hundred bytes of newlines
    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        r = client.post("/api/artifacts?name=blank.btf.zip", content=data, headers=OCTETS)
        assert r.status_code == 422, r.text
        err = r.json()["error"]
        assert err.startswith("blank.btf.zip: angles.csv: has "), err
        assert f"over the limit of {MAX_LIST_LINES}" in err, err
    # Stored by a check without this limit (an older version): the job refuses it too.
    path = tmp_path / "blank.btf.zip"
    path.write_bytes(data)
    jobs, store = JobStore(settings.db_path), ArtifactStore(settings.store_dir)
    with pytest.raises(FormatError):
        import_file(path, jobs, store)
    rec = import_file(path, jobs, store, validate=lambda p, n: "application/zip")
    job = run_in_process(_spec(f"sha256:{rec.digest}"), settings)
    assert job.state == "failed", job
    assert job.error is not None
    assert job.error.startswith("archive: blank.btf.zip: angles.csv: has "), job.error
