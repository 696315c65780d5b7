"""Hostile and odd input through the REST API (issue 15, B4 and B6).

Each of these was a 500 (or was accepted) before: now a 4xx whose message names the field,
and the ``OPTIONS`` / ``HEAD`` answers agree with the routes.
"""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from service import kinds
from service.api import create_app
from service.settings import Settings
from storage.jobs import JobStore

from .harness import base_env, run_cli

YAML = {"content-type": "application/yaml"}
JSON = {"content-type": "application/json"}
DIGEST = "a" * 64


@pytest.fixture
def client(tmp_path: Path) -> Iterator[TestClient]:
    kinds.load_builtin()
    settings = Settings.from_env({}).with_(data_dir=tmp_path)
    with TestClient(create_app(settings), raise_server_exceptions=False) as c:
        yield c


def _error(r: Any) -> str:
    return str(r.json()["error"])


# -- B4: 500s that must be 4xx with the field named ------------------------------------------
@pytest.mark.parametrize(
    ("body", "headers", "field"),
    [
        ('{"kind": "render", "seed": ' + "9" * 5000 + "}", JSON, "seed"),
        ("kind: render\nseed: " + "9" * 5000 + "\n", YAML, "seed"),
        ('{"kind": "render", "params": {"spp": -' + "1" * 4400 + "}}", JSON, "params.spp"),
    ],
)
def test01_huge_integers(
    client: TestClient, body: str, headers: dict[str, str], field: str
) -> None:
    r = client.post("/api/jobs", content=body, headers=headers)
    assert r.status_code == 422, r.text
    assert _error(r).startswith(f"{field}: an integer of") and "too large" in _error(r)


@pytest.mark.parametrize("depth", [150, 5000, 200_000])
@pytest.mark.parametrize("headers", [JSON, YAML])
def test02_deep_nesting(client: TestClient, depth: int, headers: dict[str, str]) -> None:
    body = '{"kind": "render", "params": {"scene": ' + "[" * depth + "]" * depth + "}}"
    r = client.post("/api/jobs", content=body, headers=headers)
    assert r.status_code in (413, 422), r.text
    if r.status_code == 422:
        assert "nested deeper than" in _error(r)


@pytest.mark.parametrize(
    ("value", "needle"),
    [
        ("2024-01-01", "YAML date (2024-01-01)"),
        ("2024-01-01T10:00:00Z", "YAML date"),
        ("!!binary aGVsbG8=", "!!binary"),
        ("!!set {a, b}", "!!set"),
    ],
)
def test03_yaml_only_types(client: TestClient, value: str, needle: str) -> None:
    r = client.post(
        "/api/jobs", content=f"kind: render\nparams: {{scene: {value}}}\n", headers=YAML
    )
    assert r.status_code == 422, r.text
    assert _error(r).startswith("params.scene: ") and needle in _error(r)


def test04_huge_offset(client: TestClient) -> None:
    for offset in ("9223372036854775808", "1" + "0" * 40):
        r = client.get(f"/api/jobs?offset={offset}")
        assert r.status_code == 422, r.text
        assert "offset" in _error(r)
    assert client.get("/api/jobs?offset=9223372036854775807").json() == []


@pytest.mark.parametrize(
    "text",
    [
        "kind: render\nparams: {scene: 2024-01-01}\n",
        "kind: render\nparams: {scene: !!binary aGVsbG8=}\n",
        "kind: render\nparams: {scene: !!set {a}}\n",
        "kind: render\nseed: " + "7" * 4400 + "\n",
    ],
)
def test04b_cli_exits_2_on_such_specs(tmp_path: Path, text: str) -> None:
    spec = tmp_path / "spec.yaml"
    spec.write_text(text)
    res = run_cli("run", str(spec), "--data-dir", str(tmp_path / "d"), env=base_env())
    assert res.returncode == 2, res
    assert "params.scene" in res.stderr or "seed" in res.stderr, res
    assert "internal error" not in res.stderr


# -- B3: YAML aliases -------------------------------------------------------------------------
def test05_yaml_aliases_refused(client: TestClient) -> None:
    lines = ["a0: &a0 [x, x, x, x, x, x, x, x, x]"]
    lines += [f"a{i}: &a{i} [*a{i - 1}, *a{i - 1}, *a{i - 1}, *a{i - 1}]" for i in range(1, 9)]
    body = "kind: render\nname: laughs\nparams:\n" + "\n".join(f"  {ln}" for ln in lines) + "\n"
    assert len(body) < 1000
    r = client.post("/api/jobs", content=body, headers=YAML)
    assert r.status_code == 422, r.text
    assert "YAML aliases" in _error(r)


# -- B6: messages and strictness --------------------------------------------------------------
@pytest.mark.parametrize("value", ["yes", 0, 1, "true", None])
def test06_force_is_a_strict_boolean(client: TestClient, value: Any) -> None:
    r = client.post("/api/jobs", json={"kind": "render", "force": value})
    assert r.status_code == 422, r.text
    assert _error(r).startswith("force: ")


def test07_ref_with_a_trailing_newline_is_refused(client: TestClient) -> None:
    spec = {"kind": "score", "params": {"reference": f"sha256:{DIGEST}\n", "candidates": {}}}
    r = client.post("/api/jobs", json=spec)
    assert r.status_code == 422, r.text
    assert "params.reference" in _error(r) and "must be an artifact reference" in _error(r)


def test08_union_fields_give_one_message_without_pydantic_internals(client: TestClient) -> None:
    spec = {"kind": "score", "params": {"reference": "nope", "candidates": {"a": "nope"}}}
    r = client.post("/api/jobs", json=spec)
    assert r.status_code == 422, r.text
    fields = [".".join(str(p) for p in d["loc"]) for d in r.json()["detail"]]
    assert fields.count("body.params.reference") == 1, fields
    assert fields.count("body.params.candidates.a") == 1, fields
    for text in (r.text, *fields):
        assert "function-after" not in text and "_check_ref" not in text


def test09_corrupt_upload_names_the_upload_not_a_temp_path(client: TestClient) -> None:
    r = client.post(
        "/api/artifacts?name=photo.exr",
        content=b"\x76\x2f\x31\x01" + b"\x00" * 200,
        headers={"content-type": "application/octet-stream"},
    )
    assert r.status_code == 422, r.text
    assert _error(r).startswith("photo.exr: ")
    assert "/tmp" not in r.text and "upload-" not in r.text and "store" not in r.text


def test10_manifest_of_an_unfinished_job(client: TestClient) -> None:
    job = client.post("/api/jobs", json={"kind": "render"}).json()
    r = client.get(f"/api/jobs/{job['id']}/manifest")
    assert r.status_code == 409, r.text
    assert "queued" in _error(r) and "written when the job succeeds" in _error(r)
    assert client.get(f"/api/jobs/{'0' * 32}/manifest").status_code == 404


def test11_options_and_head_agree_with_the_routes(client: TestClient) -> None:
    r = client.options("/api/jobs")
    assert r.status_code == 204
    assert set(r.headers["allow"].split(", ")) == {"GET", "HEAD", "OPTIONS", "POST"}
    r = client.options(f"/api/jobs/{'0' * 32}/cancel")
    assert set(r.headers["allow"].split(", ")) == {"OPTIONS", "POST"}
    assert client.options("/no/such/route").status_code == 404
    for path in ("/api/health", "/api/jobs", "/"):
        get, head = client.get(path), client.head(path)
        assert head.status_code == get.status_code == 200, (path, head.status_code)
        assert head.content == b"" and head.headers["content-type"] == get.headers["content-type"]
    r = client.put("/api/jobs")
    assert r.status_code == 405 and "POST" in r.headers["allow"]


def test12_failed_after_attempts_says_what_to_do(tmp_path: Path) -> None:
    jobs = JobStore(tmp_path / "jobs.db")
    job, _ = jobs.submit(kind="render", name=None, seed=0, spec_hash="h", spec={})
    jobs.claim("host:1", lease_seconds=0.0)
    _, failed = jobs.reap(max_attempts=1)
    assert failed == [job.id]
    error = jobs.get(job.id).error or ""
    assert "force" not in error.replace("no force is needed", "")
    assert "submit the spec again" in error


# -- B7: what schemathesis found ---------------------------------------------------------
@pytest.mark.parametrize(
    ("method", "url", "body"),
    [
        ("GET", "/api/jobs?kind=no-such-kind", None),
        ("POST", "/api/jobs", '{"kind": "no-such-kind"}'),
        ("POST", "/api/jobs", '{"kind": "render", "params": {"spp": "many"}}'),
    ],
)
def test13_422_details_match_the_documented_validation_error(
    client: TestClient, method: str, url: str, body: str | None
) -> None:
    """Every 422 ``detail`` item has the ``loc``, ``msg`` and ``type`` that ``/openapi.json``
    (``ValidationError``) requires; the spec errors lacked ``type``."""
    r = client.request(method, url, content=body, headers=JSON)
    assert r.status_code == 422, r.text
    required = client.get("/openapi.json").json()["components"]["schemas"]["ValidationError"]
    detail = r.json()["detail"]
    assert isinstance(detail, list) and detail
    for item in detail:
        assert set(required["required"]) <= set(item), item
        assert isinstance(item["type"], str) and isinstance(item["msg"], str)


# -- B8: nothing slow left for the first submissions -------------------------------------
def test14_kinds_are_imported_before_the_first_request(tmp_path: Path) -> None:
    """The app's startup imports the kind modules: lazily, on the first ``POST /api/jobs``,
    it made every submission in flight wait ~1.5 s (the p99 of bench_submit.py). And what
    startup left alive is frozen out of the collector's sight (``gc.freeze``): full
    collections over it stalled the server ~100 ms every few hundred submissions."""
    code = (
        "import gc\n"
        "from pathlib import Path\n"
        "from fastapi.testclient import TestClient\n"
        "from service import kinds\n"
        "from service.api import create_app\n"
        "from service.settings import Settings\n"
        f"app = create_app(Settings.from_env({{}}).with_(data_dir=Path({str(tmp_path)!r})))\n"
        "assert not kinds._loaded\n"
        "with TestClient(app):\n"
        "    print('loaded' if kinds._loaded else 'lazy', gc.get_freeze_count() > 10_000)\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True
    )
    assert out.stdout.strip() == "loaded True", out.stderr
