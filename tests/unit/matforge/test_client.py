"""``matforge.Client`` over a scripted server (``httpx.MockTransport``): its small surface,
the typed objects it answers with (each ``.raw`` the document sent), and the previous
release's names, which still answer as before but warn.

Oracle: the documents the scripted server sent, validated against the server's own
response models (``service.schemas``).
"""

from __future__ import annotations

import hashlib
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

import matforge
from matforge.objects import Artifact, Job, Kind, ResultRow
from service.schemas import JobPublic

ID = "0123456789abcdef0123456789abcdef"
DATA = b"the bytes of ndf.npz"
DIGEST = hashlib.sha256(DATA).hexdigest()
ART = {"name": "ndf.npz", "digest": DIGEST, "size": len(DATA), "media_type": "application/x-npz"}
JOB = {
    "id": ID, "kind": "generate.glint", "name": None, "batch": None, "state": "succeeded",
    "progress": 1.0, "message": "done", "error": None, "worker": "h:1", "attempts": 1,
    "seed": 3, "spec_hash": "ab" * 32, "created_at": "2026-01-01T00:00:00Z",
    "started_at": None, "finished_at": None,
    "timings": {"queued_seconds": 0.1, "run_seconds": 1.0}, "spec": {"kind": "generate.glint"},
    "manifest": None, "artifacts": [ART], "tags": [], "a_future_field": 7,
}  # fmt: skip
ROW = {"job": ID, "kind": "score", "metric": "smape", "value": 0.25, "lower_is_better": True,
       "config": {}, "ns_per_eval": 12.5}  # fmt: skip
KIND = {"name": "generate.glint", "summary": "glints", "artifacts": ["ndf.npz"],
        "params_schema": {"type": "object"}, "plugin": None}  # fmt: skip


def answer(request: httpx.Request) -> httpx.Response:
    path = request.url.path
    if path == "/api/jobs" and request.method == "POST":
        return httpx.Response(201, json=JOB)
    if path == "/api/jobs":
        return httpx.Response(200, json=[JOB], headers={"x-total-count": "1"})
    if path in (f"/api/jobs/{ID}", f"/api/jobs/{ID[:8]}", f"/api/jobs/{ID}/cancel"):
        return httpx.Response(200, json=JOB)
    if path == f"/api/jobs/{ID}/artifacts":
        return httpx.Response(200, json=[ART])
    if path == f"/api/artifacts/{DIGEST}":
        return httpx.Response(200, content=DATA)
    if path == "/api/results":
        assert request.url.params.get_list("job") in ([], [ID])
        return httpx.Response(200, json=[ROW])
    if path == "/api/kinds":
        return httpx.Response(200, json=[KIND])
    if path == f"/api/jobs/{ID}/logs":
        return httpx.Response(200, text="line 1\nline 2\n")
    return httpx.Response(404, json={"error": f"no route {path}"})


@pytest.fixture
def mf() -> Iterator[matforge.Client]:
    client = matforge.Client("http://matforge.test")
    client._rest._http = httpx.Client(
        base_url="http://matforge.test", transport=httpx.MockTransport(answer)
    )
    with client:
        yield client


def test01_the_surface_is_small() -> None:
    public = {n for n in vars(matforge.Client) if not n.startswith("_")}
    assert public == {
        "server", "close",
        "submit", "get", "list", "wait", "cancel", "logs", "manifest", "batch",
        "artifacts", "read", "fetch", "upload",
        "results", "kinds",
    }  # fmt: skip
    assert not issubclass(matforge.Client, matforge.client.RestClient)  # composition


def test02_typed_answers_with_raw(mf: matforge.Client, tmp_path: Path) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the new surface never warns
        job = mf.submit({"kind": "generate.glint"})
        assert isinstance(job, Job) and isinstance(job, JobPublic)
        assert (job.id, job.state, job.attempts, job.ref) == (ID, "succeeded", 1, f"job:{ID}")
        assert job.timings.run_seconds == 1.0 and job.done
        assert job.raw == JOB  # the whole document, the field this model lacks included
        assert job.model_extra == {"a_future_field": 7}
        (art,) = job.artifacts
        assert isinstance(art, Artifact) and art.raw == ART and art.ref == f"sha256:{DIGEST}"
        assert mf.get(ID[:8]) == job and mf.wait(job, poll=0.01).id == ID
        assert [j.id for j in mf.list(kind="generate.glint")] == [ID]
        assert mf.cancel(job).state == "succeeded"
        assert mf.artifacts(job) == [art]
        assert mf.read(f"job:{ID}/ndf.npz") == mf.read(art) == DATA
        assert mf.fetch(art, tmp_path / "ndf.npz") == len(DATA)
        assert (tmp_path / "ndf.npz").read_bytes() == DATA
        (row,) = mf.results(job)
        assert isinstance(row, ResultRow) and (row.metric, row.value) == ("smape", 0.25)
        assert row.ns_per_eval == 12.5 and row.raw == ROW
        assert mf.results() == [row]
        (kind,) = mf.kinds()
        assert isinstance(kind, Kind) and kind.name == "generate.glint" and kind.plugin is None
        assert mf.logs(job, tail=None) == "line 1\nline 2\n"


def test03_a_failed_job_raises_with_its_document(mf: matforge.Client) -> None:
    failed = {**JOB, "state": "failed", "error": "bad normal map"}
    mf._rest._http = httpx.Client(
        base_url="http://matforge.test",
        transport=httpx.MockTransport(lambda r: httpx.Response(200, json=failed)),
    )
    with pytest.raises(matforge.JobFailed, match="bad normal map") as err:
        mf.wait(ID, poll=0.01)
    assert err.value.job == failed
    assert mf.wait(ID, poll=0.01, check=False).error == "bad normal map"


@pytest.mark.parametrize(
    ("call", "expect"),
    [
        (lambda mf: mf.status(ID[:8]), JOB),
        (lambda mf: mf.ls(kind="generate.glint"), [JOB]),
        (lambda mf: mf.list_page(kind="generate.glint"), ([JOB], 1)),
        (lambda mf: mf.fetch(f"sha256:{DIGEST}"), DATA),
        (lambda mf: mf.resolve(f"job:{ID}/ndf.npz"), DIGEST),
        (lambda mf: mf.read_bytes(DIGEST), DATA),
        (lambda mf: mf.artifact(ID, "ndf.npz"), ART),
        (lambda mf: mf.get(ID)["state"], "succeeded"),
        (lambda mf: mf.get(ID).get("attempts"), 1),
        (lambda mf: {**mf.results(ID)[0]}, ROW),
    ],
    ids=[
        "status",
        "ls",
        "list_page",
        "fetch-bytes",
        "resolve",
        "read_bytes",
        "artifact",
        "job[key]",
        "job.get",
        "{**row}",
    ],  # fmt: skip
)
def test04_old_names_answer_as_before_and_warn(mf: matforge.Client, call: Any, expect: Any) -> None:
    with pytest.warns(DeprecationWarning, match="deprecated and goes in the next release"):
        got = call(mf)
    assert got == expect


def test05_an_unknown_name_is_an_attribute_error(mf: matforge.Client) -> None:
    with pytest.raises(AttributeError, match="no attribute 'submitt'"):
        mf.submitt  # type: ignore[attr-defined]  # noqa: B018
