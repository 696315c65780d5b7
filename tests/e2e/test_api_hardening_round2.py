"""The smaller findings of issue 21 (item 12) through the REST API: ``OPTIONS`` needs the token
like the routes it describes, an oversized chunked body is a 413 (not a 400), and a malformed
job id is a 422 on the compare page as on ``/api/jobs/{id}``."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from service import kinds
from service.api import create_app
from service.settings import Settings

TOKEN = "s3cret-token"
BASE = "http://127.0.0.1:8000"


def _client(tmp_path: Path, **changes: object) -> TestClient:
    kinds.load_builtin()
    settings = Settings.from_env({}).with_(data_dir=tmp_path, **changes)
    app = create_app(settings, bind_host="127.0.0.1")
    return TestClient(app, base_url=BASE, raise_server_exceptions=False)


@pytest.fixture
def token_client(tmp_path: Path) -> Iterator[TestClient]:
    with _client(tmp_path, token=TOKEN) as c:
        yield c


def test01_options_needs_the_token(token_client: TestClient) -> None:
    c = token_client
    for path in ("/api/jobs", f"/api/jobs/{'0' * 32}/cancel", "/", "/openapi.json"):
        r = c.options(path)
        assert r.status_code == 401, (path, r.status_code, r.headers.get("allow"))
        assert "allow" not in r.headers and r.headers["www-authenticate"] == "Bearer"
        r = c.options(path, headers={"Authorization": f"Bearer {TOKEN}"})
        assert r.status_code == 204 and "OPTIONS" in r.headers["allow"], path
    assert c.options("/api/jobs", headers={"Authorization": "Bearer wrong"}).status_code == 401
    assert c.options("/api/health").status_code == 204  # health needs no token, nor its OPTIONS
    # the dashboard's own ways in: the session cookie, and ?token= on a page
    assert c.options("/", params={"token": TOKEN}).status_code == 204
    assert c.options("/api/jobs", params={"token": TOKEN}).status_code == 401  # not on /api


def test02_options_without_a_server_token(tmp_path: Path) -> None:
    with _client(tmp_path) as c:
        assert c.options("/api/jobs").status_code == 204


def _chunks(total: int, size: int = 65536) -> Iterator[bytes]:
    """A JSON body of ``total`` bytes in pieces (no Content-Length: sent chunked)."""
    head, tail = b'{"steps": [{"name": "a", "spec": {"kind": "render", "x": "', b'"}}]}'
    yield head
    left = total - len(head) - len(tail)
    while left > 0:
        n = min(size, left)
        yield b"a" * n
        left -= n
    yield tail


def test03_chunked_body_over_the_limit_is_413(tmp_path: Path) -> None:
    with _client(tmp_path, max_body_bytes=64 * 1024) as c:
        r = c.post(
            "/api/results/batch",
            content=_chunks(200 * 1024),
            headers={"content-type": "application/json"},
        )
        assert r.status_code == 413, r.text
        assert "exceeds the limit of 65536 bytes" in r.json()["error"]
        r = c.post("/api/results/batch", content=_chunks(32 * 1024))  # under it: validated
        assert r.status_code == 422 and "steps.0.spec" in r.text, r.text


def test04_malformed_ids_are_422_on_compare_as_on_the_api(tmp_path: Path) -> None:
    with _client(tmp_path) as c:
        for bad in ("zz", "ABC", "0" * 33, "12 34"):
            api = c.get(f"/api/jobs/{bad}")
            page = c.get("/compare", params={"jobs": bad})
            assert api.status_code == page.status_code == 422, (bad, api.text, page.text)
            assert "jobs" in page.json()["error"], page.text
        # a well-formed id that names no job: 404 in both
        assert c.get(f"/api/jobs/{'a' * 32}").status_code == 404
        assert c.get("/compare", params={"jobs": "a" * 32}).status_code == 404
