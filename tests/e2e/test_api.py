"""The REST API through FastAPI's TestClient over a temporary data directory.

A test-only kind, ``test_echo``, is registered for each test; finished jobs are run
in-process with ``run_worker(settings, max_jobs=1)``. Routes are exercised as in the
contract's REST table, plus the compatible extras (kinds, stats, manifest, preview, docs).
"""

from __future__ import annotations

import hashlib
import json
import os
import stat
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from pydantic import Field

from evaluators.metrics.tonemap import tonemap
from evaluators.score.kind import summarize as score_summary
from jobapi import kinds as jobapi_kinds
from jobapi.context import JobContext
from jobapi.kinds import Kind
from jobapi.params import StrictModel
from service import kinds
from service.api import create_app
from service.settings import Settings
from service.workers.worker import run_worker
from storage.artifacts import ArtifactStore
from storage.formats.exr import exr_bytes
from storage.formats.png import write_png

KIND = "test_echo"
TOKEN = "s3cret-token"


class EchoParams(StrictModel):
    """Params of the test-only kind."""

    n: int = Field(default=1, ge=1, le=100, description="a number to echo")
    text: str = Field(default="hi", max_length=50, description="a text to echo")


def echo_image(n: int) -> np.ndarray:
    """A small (6, 8, 3) float32 linear gradient."""
    return np.linspace(0.0, 2.0 * n, 6 * 8 * 3, dtype=np.float32).reshape(6, 8, 3)


def run_echo(params: EchoParams, ctx: JobContext) -> None:
    """Writes an EXR, its PNG preview, a metrics table and the echoed params."""
    ctx.progress(0.5, "echoing")
    rgb = echo_image(params.n)
    ctx.put_bytes("image.exr", exr_bytes(rgb))
    ctx.put_bytes("preview.png", write_png(None, tonemap(rgb)))
    ctx.put_json(
        "metrics.json",
        {
            "reference": "sha256:" + "0" * 64,
            "metrics": {
                "a": {"psnr": 30.0 + params.n, "mae": 0.01},
                "b": {"psnr": 20.0, "mae": 0.04},
            },
            "settings": {},
        },
    )
    ctx.put_json("result.json", {"n": params.n, "text": params.text})


@pytest.fixture(autouse=True)
def echo_kind(monkeypatch: pytest.MonkeyPatch) -> Kind:
    """Register ``test_echo`` for one test (beside the built-in kinds)."""
    kinds.load_builtin()
    kind = Kind(
        name=KIND,
        params=EchoParams,
        runner=run_echo,
        description="test-only echo kind",
        artifacts=("result.json",),
        summary=score_summary,  # it writes metrics.json as score does
    )
    monkeypatch.setitem(jobapi_kinds._KINDS, KIND, kind)
    return kind


@pytest.fixture
def settings(tmp_path: Path) -> Settings:
    (tmp_path / "scratch").mkdir()  # workers make their job directories in it
    return Settings.from_env({}).with_(data_dir=tmp_path, pool_processes=1)


@pytest.fixture
def client(settings: Settings) -> Iterator[TestClient]:
    with TestClient(create_app(settings)) as c:
        yield c


def spec(**params: Any) -> dict[str, Any]:
    return {"kind": KIND, "params": params}


def finished_job(client: TestClient, settings: Settings, **params: Any) -> dict[str, Any]:
    """Submit an echo job, run it in-process, return its final document."""
    r = client.post("/api/jobs", json=spec(**params))
    assert r.status_code in (200, 201), r.text
    assert run_worker(settings, max_jobs=1) == 1
    doc = client.get(f"/api/jobs/{r.json()['id']}").json()
    assert doc["state"] == "succeeded", doc
    return doc


def artifact(doc: dict[str, Any], name: str) -> dict[str, Any]:
    return next(a for a in doc["artifacts"] if a["name"] == name)


# -- health, submit, list, get ----------------------------------------------------------
def test01_health(client: TestClient) -> None:
    r = client.get("/api/health")
    assert r.status_code == 200 and r.json() == {"status": "ok"}


def test02_submit_get_list(client: TestClient) -> None:
    r = client.post("/api/jobs", json={**spec(n=3), "name": "first", "seed": 7})
    assert r.status_code == 201, r.text
    job = r.json()
    assert len(job["id"]) == 32 and job["state"] == "queued" and job["kind"] == KIND
    assert job["name"] == "first" and job["seed"] == 7 and job["progress"] == 0.0
    assert job["spec"]["params"] == {"n": 3, "text": "hi"}  # defaults filled in
    assert job["artifacts"] == [] and r.headers["location"] == f"/api/jobs/{job['id']}"
    for key in ("message", "error", "worker", "attempts", "timings", "created_at"):
        assert key in job
    assert client.get(f"/api/jobs/{job['id']}").json()["id"] == job["id"]
    second = client.post("/api/jobs", json=spec(n=4)).json()
    listed = client.get("/api/jobs").json()
    assert [j["id"] for j in listed] == [second["id"], job["id"]]  # newest first
    assert [j["id"] for j in client.get("/api/jobs", params={"limit": 1}).json()] == [second["id"]]
    assert [j["id"] for j in client.get("/api/jobs?limit=1&offset=1").json()] == [job["id"]]
    assert len(client.get("/api/jobs", params={"state": "queued", "kind": KIND}).json()) == 2
    assert client.get("/api/jobs", params={"state": "running"}).json() == []
    assert client.get("/api/jobs", params={"kind": "render"}).json() == []


def test03_yaml_spec(client: TestClient) -> None:
    body = f"kind: {KIND}\nparams:\n  n: 5\n"
    r = client.post("/api/jobs", content=body, headers={"Content-Type": "application/yaml"})
    assert r.status_code == 201 and r.json()["spec"]["params"]["n"] == 5


def test04_dedupe_and_force(client: TestClient, settings: Settings) -> None:
    first = client.post("/api/jobs", json=spec(n=2))
    again = client.post("/api/jobs", json={**spec(n=2), "name": "another label"})
    assert first.status_code == 201 and again.status_code == 200
    assert again.json()["id"] == first.json()["id"]
    forced = client.post("/api/jobs", json={**spec(n=2), "force": True})
    assert forced.status_code == 201 and forced.json()["id"] != first.json()["id"]
    # an identical spec that already succeeded is returned too
    run_worker(settings, max_jobs=2)
    done = client.post("/api/jobs", json=spec(n=2))
    assert done.status_code == 200 and done.json()["state"] == "succeeded"


@pytest.mark.parametrize(
    ("body", "field"),
    [
        ({"kind": "no_such_kind"}, "kind"),
        ({**spec(), "colour": "red"}, "colour"),
        (spec(bogus=1), "params.bogus"),
        (spec(n="3"), "params.n"),
        (spec(n=0), "params.n"),
        (spec(n=101), "params.n"),
        ({**spec(), "seed": -1}, "seed"),
        ({**spec(), "seed": "1"}, "seed"),
        ({"params": {}}, "kind"),
        ({"kind": KIND, "params": {"text": "x" * 51}}, "params.text"),
    ],
)
def test05_bad_specs_name_the_field(client: TestClient, body: Any, field: str) -> None:
    r = client.post("/api/jobs", json=body)
    assert r.status_code == 422, r.text
    out = r.json()
    assert field in out["error"] and "\n" not in out["error"]
    assert isinstance(out["detail"], list) and out["detail"][0]["msg"]
    locs = [".".join(str(p) for p in d["loc"] if p != "body") for d in out["detail"]]
    assert field in locs
    assert client.get("/api/jobs").json() == []  # nothing was queued


@pytest.mark.parametrize(
    ("content", "needle"),
    [(b"{not json", "JSON"), (b"[1, 2]", "object"), (b"", "empty"), (b'"x"', "object")],
)
def test06_malformed_bodies(client: TestClient, content: bytes, needle: str) -> None:
    r = client.post("/api/jobs", content=content, headers={"Content-Type": "application/json"})
    assert r.status_code == 422 and needle in r.json()["error"], r.text


def test07_query_and_path_validation(client: TestClient) -> None:
    r = client.get("/api/jobs", params={"state": "bogus"})
    assert r.status_code == 422 and "state" in r.json()["error"]
    assert r.json()["detail"][0]["loc"] == ["query", "state"]
    assert client.get("/api/jobs", params={"limit": 0}).status_code == 422
    assert client.get("/api/jobs", params={"offset": -1}).status_code == 422
    r = client.get("/api/jobs/not-a-job-id")
    assert r.status_code == 422 and "job_id" in r.json()["error"]
    r = client.get("/api/jobs/" + "a" * 32)
    assert r.status_code == 404 and "a" * 32 in r.json()["error"]
    assert client.get("/api/jobs/" + "A" * 32).status_code == 422
    assert client.post("/api/jobs/" + "b" * 32 + "/cancel").status_code == 404
    assert client.get("/api/jobs/" + "b" * 32 + "/artifacts").status_code == 404
    assert client.get("/api/nothing-here").status_code == 404


# -- cancel, artifacts, manifest ----------------------------------------------------------
def test08_cancel_queued_job(client: TestClient, settings: Settings) -> None:
    job = client.post("/api/jobs", json=spec(n=9)).json()
    r = client.post(f"/api/jobs/{job['id']}/cancel")
    assert r.status_code == 200 and r.json()["state"] == "cancelled"
    assert client.post(f"/api/jobs/{job['id']}/cancel").json()["state"] == "cancelled"
    assert run_worker(settings, max_jobs=1, idle_exit_seconds=0.2) == 0  # nothing to run
    done = finished_job(client, settings, n=10)
    r = client.post(f"/api/jobs/{done['id']}/cancel")
    assert r.status_code == 200 and r.json()["state"] == "succeeded"  # unchanged
    # a cancelled spec can be submitted again: it is queued anew
    again = client.post("/api/jobs", json=spec(n=9))
    assert again.status_code == 201 and again.json()["id"] != job["id"]


def test09_artifacts_download_verified(client: TestClient, settings: Settings) -> None:
    doc = finished_job(client, settings, n=2, text="hello")
    listed = client.get(f"/api/jobs/{doc['id']}/artifacts").json()
    assert listed == doc["artifacts"]
    assert {a["name"] for a in listed} == {
        "image.exr",
        "preview.png",
        "metrics.json",
        "result.json",
    }
    assert set(listed[0]) == {"name", "digest", "size", "media_type"}
    res = artifact(doc, "result.json")
    r = client.get(f"/api/artifacts/{res['digest']}")
    assert r.status_code == 200 and json.loads(r.content) == {"n": 2, "text": "hello"}
    assert hashlib.sha256(r.content).hexdigest() == res["digest"]
    assert r.headers["content-type"].startswith("application/json")
    assert 'filename="result.json"' in r.headers["content-disposition"]
    assert r.headers["etag"] == f'"{res["digest"]}"'
    assert "immutable" in r.headers["cache-control"]
    exr = artifact(doc, "image.exr")
    r = client.get(f"/api/artifacts/sha256:{exr['digest']}")
    assert r.status_code == 200 and r.content == exr_bytes(echo_image(2))
    assert r.headers["content-type"] == "image/x-exr"
    assert r.headers["content-disposition"].startswith("attachment")
    r = client.get(
        f"/api/artifacts/{res['digest']}", headers={"If-None-Match": f'"{res["digest"]}"'}
    )
    assert r.status_code == 304 and r.content == b""
    # queued jobs have no artifacts yet
    queued = client.post("/api/jobs", json=spec(n=50)).json()
    assert client.get(f"/api/jobs/{queued['id']}/artifacts").json() == []


def test10_manifest(client: TestClient, settings: Settings) -> None:
    doc = finished_job(client, settings, n=3)
    r = client.get(f"/api/jobs/{doc['id']}/manifest")
    assert r.status_code == 200
    manifest = r.json()
    assert manifest["job"] == doc["id"] and manifest["spec"] == doc["spec"]
    assert "numpy" in manifest["packages"] and manifest["code_version"]
    assert (
        doc["manifest"]
        == "sha256:"
        + hashlib.sha256(client.get(f"/api/artifacts/{doc['manifest']}").content).hexdigest()
    )
    queued = client.post("/api/jobs", json=spec(n=60)).json()
    r = client.get(f"/api/jobs/{queued['id']}/manifest")
    assert r.status_code == 409 and "queued" in r.json()["error"]


def test11_preview_of_exr(client: TestClient, settings: Settings) -> None:
    doc = finished_job(client, settings, n=1)
    exr = artifact(doc, "image.exr")
    r = client.get(f"/api/artifacts/{exr['digest']}/preview.png")
    assert r.status_code == 200 and r.headers["content-type"] == "image/png"
    assert r.content == write_png(None, tonemap(echo_image(1)))
    assert client.get(f"/api/artifacts/{exr['digest']}/preview.png").content == r.content
    r = client.get(f"/api/artifacts/{artifact(doc, 'result.json')['digest']}/preview.png")
    assert r.status_code == 422 and "result.json" in r.json()["error"]
    assert client.get(f"/api/artifacts/{'c' * 64}/preview.png").status_code == 404


@pytest.mark.parametrize(
    "path",
    [
        "/api/artifacts/../../etc/passwd",
        "/api/artifacts/..%2F..%2Fetc%2Fpasswd",
        "/api/artifacts/%2e%2e/%2e%2e/etc/passwd",
        "/api/artifacts/" + "%2e%2e%2f" * 8 + "etc%2fpasswd",
        "/api/artifacts/" + "A" * 64,
        "/api/artifacts/" + "a" * 63,
        "/api/artifacts/" + "a" * 65,
        "/api/artifacts/" + "g" * 64,
        "/api/artifacts/sha256:" + "a" * 63,
        "/api/artifacts/sha1:" + "a" * 64,
        "/api/artifacts/ab/" + "c" * 62,
        "/api/artifacts/" + "a" * 64 + "%00",
    ],
)
def test12_digest_pattern_never_reaches_files(client: TestClient, path: str) -> None:
    r = client.get(path)
    assert r.status_code in (404, 422), (path, r.status_code)
    assert b"root:" not in r.content and r.headers["content-type"].startswith("application/json")


def test13_unknown_digest_is_404(client: TestClient) -> None:
    r = client.get("/api/artifacts/" + "d" * 64)
    assert r.status_code == 404 and "d" * 64 in r.json()["error"]


def test14_corrupt_object_is_500_not_bytes(client: TestClient, settings: Settings) -> None:
    doc = finished_job(client, settings, n=4)
    res = artifact(doc, "result.json")
    obj = ArtifactStore(settings.store_dir).path(res["digest"])
    os.chmod(obj, stat.S_IRUSR | stat.S_IWUSR)
    obj.write_bytes(b'{"n": 666, "text": "tampered"}\n')
    r = client.get(f"/api/artifacts/{res['digest']}")
    assert r.status_code == 500
    out = r.json()
    assert "corrupt" in out["error"] and "Traceback" not in r.text and b"tampered" not in r.content


# -- uploads -------------------------------------------------------------------------------
def test15_upload_valid_exr_roundtrip(client: TestClient, tmp_path: Path) -> None:
    data = exr_bytes(echo_image(3))
    r = client.post("/api/artifacts", params={"name": "env.exr"}, content=data)
    assert r.status_code == 201, r.text
    out = r.json()
    digest = hashlib.sha256(data).hexdigest()
    assert out == {
        "digest": digest,
        "ref": f"sha256:{digest}",
        "size": len(data),
        "media_type": "image/x-exr",
        "name": "env.exr",
    }
    r = client.get(f"/api/artifacts/{digest}")
    assert r.status_code == 200 and r.content == data
    assert 'filename="env.exr"' in r.headers["content-disposition"]
    # the ref is usable in specs (existence is checked) ...
    assert (
        client.post("/api/artifacts", params={"name": "again.exr"}, content=data).status_code == 201
    )
    leftovers = list((tmp_path / "store" / "tmp").iterdir())
    assert leftovers == []  # temp files are removed


@pytest.mark.parametrize(
    ("name", "content", "needle"),
    [
        ("bad.exr", b"this is not an EXR file at all", "bad.exr"),
        ("empty.exr", b"", "empty.exr"),
        ("notes.xyz", b"whatever", "notes.xyz"),
        ("broken.json", b"{nope", "broken.json"),
        ("image.png", b"\x89PNG\r\n\x1a\nnot really", "image.png"),
    ],
)
def test16_upload_malformed_is_422_naming_the_file(
    client: TestClient, name: str, content: bytes, needle: str
) -> None:
    r = client.post("/api/artifacts", params={"name": name}, content=content)
    assert r.status_code == 422, r.text
    assert needle in r.json()["error"]


def test17_upload_name_required_and_plain(client: TestClient) -> None:
    r = client.post("/api/artifacts", content=b"x")
    assert r.status_code == 422 and "name" in r.json()["error"]
    for bad in ("../x.exr", "a/b.exr", "..", "a\\b.exr"):
        r = client.post("/api/artifacts", params={"name": bad}, content=b"x")
        assert r.status_code == 422 and "name" in r.json()["error"], bad


def test18_size_limits(tmp_path: Path) -> None:
    settings = Settings.from_env({}).with_(
        data_dir=tmp_path, max_body_bytes=2048, max_upload_bytes=4096
    )
    with TestClient(create_app(settings)) as client:
        big = {"kind": KIND, "name": "x" * 4000}
        r = client.post("/api/jobs", json=big)
        assert r.status_code == 413 and "2048" in r.json()["error"]
        chunks = (json.dumps(big).encode()[i : i + 512] for i in range(0, 4100, 512))
        r = client.post("/api/jobs", content=chunks, headers={"Content-Type": "application/json"})
        assert r.status_code == 413, r.text
        assert client.post("/api/jobs", json=spec()).status_code == 201
        data = exr_bytes(echo_image(1))
        assert len(data) < 4096
        assert client.post("/api/artifacts?name=ok.exr", content=data).status_code == 201
        r = client.post("/api/artifacts?name=big.exr", content=b"\0" * 5000)
        assert r.status_code == 413 and "4096" in r.json()["error"]
        r = client.post("/api/artifacts?name=big.exr", content=(b"\0" * 1000 for _ in range(6)))
        assert r.status_code == 413
        assert list((tmp_path / "store" / "tmp").iterdir()) == []


# -- auth ----------------------------------------------------------------------------------
def test19_auth(tmp_path: Path) -> None:
    settings = Settings.from_env({}).with_(data_dir=tmp_path, token=TOKEN)
    with TestClient(create_app(settings)) as client:
        assert client.get("/api/health").status_code == 200
        for method, path in [
            ("GET", "/api/jobs"),
            ("POST", "/api/jobs"),
            ("GET", "/api/jobs/" + "a" * 32),
            ("GET", "/api/kinds"),
            ("GET", "/api/stats"),
            ("GET", "/api/artifacts/" + "a" * 64),
            ("POST", "/api/artifacts?name=x.exr"),
            ("GET", "/"),
            ("GET", "/jobs/" + "a" * 32),
            ("GET", "/openapi.json"),
            ("GET", "/docs"),
            ("GET", "/static/css/app.css"),
        ]:
            r = client.request(method, path)
            assert r.status_code == 401, (method, path, r.status_code)
            assert r.headers["www-authenticate"] == "Bearer"
            assert "token" in r.json()["error"]
        wrong = {"Authorization": "Bearer nope"}
        assert client.get("/api/jobs", headers=wrong).status_code == 401
        assert client.get("/api/jobs", params={"token": TOKEN}).status_code == 401  # API: no
        good = {"Authorization": f"Bearer {TOKEN}"}
        assert client.get("/api/jobs", headers=good).json() == []
        assert client.post("/api/jobs", json=spec(), headers=good).status_code == 201
        assert client.get("/openapi.json", headers=good).status_code == 200
        # the browser: ?token= on a page sets an HttpOnly SameSite=Strict cookie ...
        r = client.get("/", params={"token": TOKEN})
        assert r.status_code == 200 and "text/html" in r.headers["content-type"]
        cookie = r.headers["set-cookie"].lower()
        assert "matforge_token=" in cookie and "httponly" in cookie and "samesite=strict" in cookie
        # ... that then carries the page's fetches and static files
        assert client.get("/api/jobs").status_code == 200
        assert client.get("/static/js/common.js").status_code == 200
        client.cookies.clear()
        assert client.get("/api/jobs").status_code == 401


def test20_no_auth_when_no_token(client: TestClient) -> None:
    for path in ("/api/jobs", "/", "/openapi.json", "/static/css/app.css", "/api/kinds"):
        assert client.get(path).status_code == 200, path


# -- service routes, OpenAPI, dashboard ------------------------------------------------------
def test21_kinds_and_stats(client: TestClient, settings: Settings) -> None:
    listed = {k["name"]: k for k in client.get("/api/kinds").json()}
    assert set(listed) == set(kinds.all_kinds())
    assert listed[KIND]["params_schema"]["properties"]["n"]["maximum"] == 100
    assert listed[KIND]["artifacts"] == ["result.json"]
    finished_job(client, settings, n=5)
    client.post("/api/jobs", json=spec(n=6))
    stats = client.get("/api/stats").json()
    assert stats["total"] == 2 and stats["counts"]["succeeded"] == 1
    assert stats["counts"]["queued"] == 1 and set(stats["counts"]) == {
        "queued",
        "running",
        "succeeded",
        "failed",
        "cancelled",
    }


def test22_openapi_documents_every_kind(client: TestClient) -> None:
    doc = client.get("/openapi.json").json()
    assert doc["info"]["title"] == "matforge" and doc["info"]["version"]
    schemas = doc["components"]["schemas"]
    for name, kind in kinds.all_kinds().items():
        assert f"params.{name}" in schemas, name
        assert set(schemas[f"params.{name}"].get("properties", {})) == set(
            kind.params.model_json_schema().get("properties", {})
        )
        assert f"JobCreate.{name}" in schemas
    assert schemas[f"params.{KIND}"]["properties"]["n"]["minimum"] == 1
    mapping = schemas["JobCreate"]["discriminator"]["mapping"]
    assert mapping[KIND] == f"#/components/schemas/JobCreate.{KIND}"
    post = doc["paths"]["/api/jobs"]["post"]
    body_ref = post["requestBody"]["content"]["application/json"]["schema"]["$ref"]
    assert body_ref == "#/components/schemas/JobCreate"
    assert {"200", "201", "422"} <= set(post["responses"])
    for path in (
        "/api/health",
        "/api/jobs/{job_id}",
        "/api/jobs/{job_id}/cancel",
        "/api/jobs/{job_id}/artifacts",
        "/api/artifacts/{digest}",
        "/api/artifacts",
    ):
        assert path in doc["paths"], path
    # every $ref resolves
    text = json.dumps(doc)
    for ref in {part.split('"')[0] for part in text.split('"$ref": "#/components/schemas/')[1:]}:
        assert ref in schemas, ref


def test23_dashboard_pages(client: TestClient, settings: Settings) -> None:
    doc = finished_job(client, settings, n=7)
    r = client.get("/")
    assert r.status_code == 200 and "text/html" in r.headers["content-type"]
    assert "/static/js/jobs.js" in r.text and KIND in r.text
    r = client.get(f"/jobs/{doc['id']}")
    assert r.status_code == 200
    page = r.text
    for a in doc["artifacts"]:
        assert a["name"] in page and f"/api/artifacts/{a['digest']}" in page
    exr = artifact(doc, "image.exr")
    assert f"/api/artifacts/{exr['digest']}/preview.png" in page
    assert "psnr" in page and "37" in page  # metrics table (30 + n)
    assert "chart.umd.min.js" in page and "code_version" not in page.split("<pre")[0]
    assert client.get("/static/vendor/chart.umd.min.js").status_code == 200
    assert client.get("/static/css/app.css").status_code == 200
    r = client.get("/jobs/" + "e" * 32, headers={"Accept": "text/html"})
    assert r.status_code == 404 and "text/html" in r.headers["content-type"]
    assert client.get("/jobs/" + "e" * 32).json()["error"]


def test24_docs_page(client: TestClient) -> None:
    r = client.get("/docs")
    assert r.status_code == 200 and "/openapi.json" in r.text
