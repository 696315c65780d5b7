"""No request builds a pydantic validator: a typed document's ``TypeAdapter`` is built when its
kind is defined (:func:`jobapi.documents.prepare`), so that concurrent requests never run
pydantic's docstring extraction (``inspect`` + ``ast``), which CPython 3.11's ``ast`` cannot
do in two threads at once (``SystemError: AST constructor recursion depth mismatch``; a
summary request of the demo batch answered 500 with it).

The job is a test-only kind that writes ``train.brdf``'s ``metrics.json`` and whose summary
hook is ``train.brdf``'s own (it reads the document with ``read_typed``). Each test starts
from an empty validator cache, as a fresh server process does before its kinds are defined.
"""

from __future__ import annotations

import ast
import threading
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Literal

import pydantic
import pytest
from fastapi.testclient import TestClient
from pydantic import Field

from jobapi import documents
from jobapi import kinds as jobapi_kinds
from jobapi.context import JobContext
from jobapi.kinds import Kind
from jobapi.params import StrictModel
from models.brdf.document import TrainBrdfMetrics
from models.brdf.kind import summarize as brdf_summary
from service import kinds
from service.api import create_app
from service.settings import Settings
from service.submission import submit
from service.workers.worker import run_worker
from storage.artifacts import ArtifactStore
from storage.jobs import JobStore
from tests.helpers.job_documents import brdf_metrics, brdf_scores

METRICS = brdf_metrics(
    [brdf_scores("gold", "metal", smape=0.11, mae=0.02)], smape=0.11, smape_floor=0.1, mae=0.02
)


class MetricsParams(StrictModel):
    """Params of the test-only kind."""

    what: Literal["metrics"] = Field("metrics", description="what it writes")


def run_metrics(params: MetricsParams, ctx: JobContext) -> None:
    ctx.put_json("metrics.json", METRICS)


@pytest.fixture
def job(settings: Settings, monkeypatch: pytest.MonkeyPatch) -> Iterator[tuple[TestClient, str]]:
    """A finished job of the test-only kind, defined over an empty validator cache, and a
    client of the app (server errors answered as 500, not raised)."""
    kinds.load_builtin()
    monkeypatch.setattr(documents, "_ADAPTERS", {})
    kind = Kind(
        "test_validators",
        MetricsParams,
        run_metrics,
        "test-only kind",
        summary=brdf_summary,
        documents={"metrics.json": TrainBrdfMetrics},
    )
    defined = dict(documents._ADAPTERS)  # what defining the kind built
    monkeypatch.setitem(jobapi_kinds._KINDS, kind.name, kind)
    jobs = JobStore(settings.db_path)
    try:
        made, _ = submit({"kind": kind.name, "params": {}}, jobs, ArtifactStore(settings.store_dir))
    finally:
        jobs.close()
    assert run_worker(settings, max_jobs=1) == 1
    # the worker validated the document it wrote: the requests start from what the kind's
    # definition built, as in a server process that has run no job
    monkeypatch.setattr(documents, "_ADAPTERS", defined)
    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        yield client, made.id


def test01_no_type_adapter_built_during_a_request(
    job: tuple[TestClient, str], monkeypatch: pytest.MonkeyPatch
) -> None:
    client, job_id = job
    built: list[Any] = []
    original = pydantic.TypeAdapter.__init__

    def counting(self: Any, *args: Any, **kwargs: Any) -> None:
        built.append(args[0] if args else kwargs.get("type"))
        original(self, *args, **kwargs)

    monkeypatch.setattr(pydantic.TypeAdapter, "__init__", counting)
    urls = (f"/api/jobs/{job_id}/summary", f"/jobs/{job_id}", f"/api/jobs/{job_id}",
            "/api/jobs", "/api/results", "/api/kinds", "/", "/api/health")  # fmt: skip
    for url in urls:
        r = client.get(url)
        assert r.status_code == 200, (url, r.text)
    assert client.get(f"/api/jobs/{job_id}/summary").json()["rows"]["gold"]["smape"] == 0.11
    r = client.post("/api/jobs", json={"kind": "test_validators", "params": {"whta": "x"}})
    assert r.status_code == 422 and "did you mean 'what'?" in r.json()["error"], r.text
    assert built == [], [str(b) for b in built]


def test02_concurrent_requests_never_error(
    job: tuple[TestClient, str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """``ast.parse`` entered by a second thread while a first is inside it raises the
    ``SystemError`` CPython 3.11 may raise then (the real one depends on the interpreter's
    thread switches and does not come on demand); 16 concurrent first requests must all
    answer 200 with the table."""
    client, job_id = job
    inside = threading.Semaphore(1)
    parse = ast.parse

    def one_thread_only(*args: Any, **kwargs: Any) -> Any:
        if not inside.acquire(blocking=False):
            raise SystemError("AST constructor recursion depth mismatch (simulated)")
        try:
            time.sleep(0.05)  # long enough for the other threads to arrive
            return parse(*args, **kwargs)
        finally:
            inside.release()

    monkeypatch.setattr(ast, "parse", one_thread_only)
    barrier = threading.Barrier(16)

    def get(_: int) -> tuple[int, Any]:
        barrier.wait()
        r = client.get(f"/api/jobs/{job_id}/summary")
        return r.status_code, r.json() if r.status_code == 200 else r.text

    with ThreadPoolExecutor(16) as pool:
        answers = list(pool.map(get, range(16)))
    assert [code for code, _ in answers] == [200] * 16, answers
    assert all(body["rows"]["gold"]["smape"] == 0.11 for _, body in answers)
