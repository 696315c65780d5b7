"""Every operation of ``/openapi.json`` under hostile values, bounded in examples and time
(issue 15, B4-B6; tests/e2e/test_schemathesis.py is B7 proper), no 5xx,
and every 4xx is the JSON error body with a one-line ``error``."""

from __future__ import annotations

import time
from collections.abc import Iterator
from itertools import islice
from pathlib import Path
from typing import Any
from urllib.parse import quote

import pytest
from fastapi.testclient import TestClient

from service import kinds
from service.api import create_app
from service.settings import Settings

pytestmark = pytest.mark.slow

BUDGET_SECONDS = 120.0
NASTY_STRINGS = [
    "",
    "x" * 5000,
    "0" * 32,
    "a" * 64 + "\n",
    "sha256:" + "a" * 64 + "\n",
    "../../etc/passwd",
    "%00",
    "\u202e\ud7ff",
    "9" * 5000,
    "-1",
    "9223372036854775808",
    "1e999",
    "NaN",
]
NASTY_VALUES: list[Any] = [
    10**400,
    -(2**63),
    2**64,
    1e308,
    -1,
    0,
    True,
    None,
    "x" * 5000,
    "job:" + "0" * 32 + "/a\n",
    [],
    {},
    [[[[[[[[[[[[[[[[[[[[[[]]]]]]]]]]]]]]]]]]]]]],
    {"a": {"b": {"c": {"d": {}}}}},
]
NASTY_BODIES = [
    b"",
    b"null",
    b"[]",
    b'"kind"',
    b"{" * 3000 + b"}" * 3000,
    b'{"kind": "render", "seed": ' + b"9" * 5000 + b"}",
    b'{"kind": 1e999}',
    b"\xff\xfe",
    b"kind: render\nparams: {scene: !!python/object:os.system [ls]}\n",
    b"kind: render\nname: !!timestamp 2024-01-01\n",
    b"a: &a [1]\nb: *a\n",
]


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    kinds.load_builtin()
    settings = Settings.from_env({}).with_(data_dir=tmp_path_factory.mktemp("fuzz"))
    with TestClient(create_app(settings), raise_server_exceptions=False) as c:
        yield c


def _check(r: Any, what: str) -> None:
    assert r.status_code < 500, f"{what}: {r.status_code} {r.text[:300]}"
    if r.status_code >= 400 and r.request.method != "HEAD":
        body = r.json()
        assert isinstance(body.get("error"), str) and "\n" not in body["error"], (what, body)


def test01_every_parameter_of_every_operation(client: TestClient) -> None:
    doc = client.get("/openapi.json").json()
    deadline = time.monotonic() + BUDGET_SECONDS
    count = 0
    for path, ops in doc["paths"].items():
        for method, op in ops.items():
            for param in op.get("parameters", []):
                for value in NASTY_STRINGS:
                    url, query = path, {}
                    for p in op.get("parameters", []):
                        v = value if p is param else ("0" * 32 if "job" in p["name"] else "a" * 64)
                        if p["in"] == "path":
                            url = url.replace("{" + p["name"] + "}", quote(v, safe=""))
                        elif p is param or p.get("required"):
                            query[p["name"]] = v if p is param else "x.exr"
                    r = client.request(method.upper(), url, params=query)
                    _check(r, f"{method.upper()} {url} {query}")
                    count += 1
            assert time.monotonic() < deadline, f"over {BUDGET_SECONDS} s after {count} cases"
    assert count > 100


@pytest.mark.parametrize("ctype", ["application/json", "application/yaml"])
def test02_spec_bodies(client: TestClient, ctype: str) -> None:
    for body in NASTY_BODIES:
        r = client.post("/api/jobs", content=body, headers={"content-type": ctype})
        _check(r, f"POST /api/jobs {body[:60]!r}")
        assert r.status_code in (413, 415, 422), (body[:60], r.status_code, r.text[:200])


def test03_every_kind_params_field(client: TestClient) -> None:
    deadline = time.monotonic() + BUDGET_SECONDS
    count = 0
    for kind in client.get("/api/kinds").json():
        name = kind["name"]
        props = list((kind.get("params_schema") or {}).get("properties", {}))
        for field in islice(props or ["nope"], 12):
            for value in NASTY_VALUES:
                r = client.post("/api/jobs", json={"kind": name, "params": {field: value}})
                _check(r, f"{name}.{field}={str(value)[:40]}")
                count += 1
        assert time.monotonic() < deadline, f"over {BUDGET_SECONDS} s after {count} cases"
    assert count > 50


def test04_upload_bodies(client: TestClient) -> None:
    for ext in (".exr", ".png", ".npz", ".binary", ".json", ".btf.zip", ".normal.png", ".x"):
        for body in (b"", b"\0" * 100, b"PK\x03\x04" + b"\xff" * 100, b"v/1\x01" + b"\xff" * 64):
            r = client.post(
                f"/api/artifacts?name=f{ext}",
                content=body,
                headers={"content-type": "application/octet-stream"},
            )
            _check(r, f"upload f{ext} {body[:8]!r}")


def test05_documented_kinds_seen(client: TestClient, tmp_path: Path) -> None:
    assert len(client.get("/api/kinds").json()) == len(kinds.all_kinds())
