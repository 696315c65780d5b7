"""The browser-facing defences (issue 15, B5): Host and Origin checks, spec content types, a
derived dashboard cookie, and no token in the access log."""

from __future__ import annotations

import logging
import time
from pathlib import Path

import httpx
import pytest
from fastapi.testclient import TestClient

from service import kinds
from service.api import create_app
from service.deps import TOKEN_COOKIE
from service.settings import Settings
from service.web_guard import RedactTokens, allowed_hosts, redact

from .harness import Server

TOKEN = "s3cret-token"
SPEC = {"kind": "render"}


def _client(tmp_path: Path, bind_host: str | None = "127.0.0.1", **changes: object) -> TestClient:
    kinds.load_builtin()
    settings = Settings.from_env({}).with_(data_dir=tmp_path, **changes)
    return TestClient(create_app(settings, bind_host=bind_host), base_url="http://127.0.0.1:8000")


def test01_host_header_checked_against_bound_and_configured_hosts(tmp_path: Path) -> None:
    with _client(tmp_path) as c:
        for host in ("127.0.0.1:8000", "localhost:8000", "[::1]:8000", "LOCALHOST"):
            assert c.get("/api/health", headers={"host": host}).status_code == 200, host
        r = c.get("/api/health", headers={"host": "rebound.example:8000"})
        assert r.status_code == 400 and "MATFORGE_ALLOWED_HOSTS" in r.json()["error"]
    with _client(tmp_path, allowed_hosts=("matforge.lab",)) as c:
        assert c.get("/", headers={"host": "matforge.lab:8000"}).status_code == 200
        assert c.get("/", headers={"host": "other.lab"}).status_code == 400
    assert allowed_hosts("0.0.0.0", ()) is None  # all interfaces, nothing configured
    assert allowed_hosts("0.0.0.0", ("a.lab",)) == {"a.lab", "localhost", "127.0.0.1", "::1"}
    assert allowed_hosts("10.0.0.5", ()) == {"10.0.0.5"}
    assert allowed_hosts("127.0.0.1", ("*",)) is None


def test02_specs_need_a_json_or_yaml_content_type(tmp_path: Path) -> None:
    with _client(tmp_path) as c:
        body = '{"kind": "render"}'
        for ctype in ("text/plain", "application/x-www-form-urlencoded", "multipart/form-data"):
            r = c.post("/api/jobs", content=body, headers={"content-type": ctype})
            assert r.status_code == 415, (ctype, r.text)
            assert ctype in r.json()["error"] and "application/json" in r.json()["error"]
        assert c.post("/api/jobs", content=body).status_code == 415  # no content type
        assert c.get("/api/jobs").json() == []
        ok = c.post("/api/jobs", content=body, headers={"content-type": "application/json"})
        assert ok.status_code == 201
        yaml_type = {"content-type": "text/yaml"}
        yml = c.post("/api/jobs", content="kind: render\nseed: 2\n", headers=yaml_type)
        assert yml.status_code == 201


def test03_cross_origin_writes_are_refused(tmp_path: Path) -> None:
    with _client(tmp_path) as c:
        for origin in ("http://evil.example", "null", "http://127.0.0.1:9999"):
            r = c.post("/api/jobs", json=SPEC, headers={"origin": origin})
            assert r.status_code == 403 and "cross-origin" in r.json()["error"], origin
        assert c.get("/api/jobs").json() == []
        job = c.post("/api/jobs", json=SPEC, headers={"origin": "http://127.0.0.1:8000"}).json()
        r = c.post(f"/api/jobs/{job['id']}/cancel", headers={"origin": "http://evil.example"})
        assert r.status_code == 403
        assert c.get(f"/api/jobs/{job['id']}").json()["state"] == "queued"
        # reads from other origins are left to the browser's CORS (no ACAO header is sent)
        r = c.get("/api/jobs", headers={"origin": "http://evil.example"})
        assert r.status_code == 200 and "access-control-allow-origin" not in r.headers


@pytest.mark.parametrize("scheme", ["http", "https"])
def test04_dashboard_cookie_is_derived_not_the_token(tmp_path: Path, scheme: str) -> None:
    kinds.load_builtin()
    settings = Settings.from_env({}).with_(data_dir=tmp_path, token=TOKEN)
    app = create_app(settings, bind_host="127.0.0.1")
    with TestClient(app, base_url=f"{scheme}://127.0.0.1:8000") as c:
        r = c.get("/", params={"token": TOKEN})
        assert r.status_code == 200
        header = r.headers["set-cookie"]
        assert TOKEN not in header and f"{TOKEN_COOKIE}=" in header
        assert ("secure" in header.lower()) == (scheme == "https")
        assert c.get("/api/jobs").status_code == 200  # the derived cookie authorizes
        c.cookies.clear()
        c.cookies.set(TOKEN_COOKIE, TOKEN)  # the raw token as a cookie does not
        assert c.get("/api/jobs").status_code == 401


def test05_access_log_redacts_tokens(token_server: Server) -> None:
    httpx.get(f"{token_server.url}/?token={token_server.token}&x=1", timeout=10)
    httpx.get(f"{token_server.url}/jobs/{'0' * 32}?token={token_server.token}", timeout=10)
    deadline = time.monotonic() + 5
    log = ""
    while time.monotonic() < deadline:
        log = token_server.log_path.read_text(errors="replace")
        if log.count("token=***") >= 2:
            break
        time.sleep(0.1)
    assert log.count("token=***") >= 2, log[-2000:]
    assert str(token_server.token) not in log


def test06_redact_filter() -> None:
    record = logging.LogRecord(
        "uvicorn.access", logging.INFO, "", 0, '%s - "%s %s HTTP/%s" %d',
        ("1.2.3.4:5", "GET", "/?a=1&token=abc&TOKEN=def", "1.1", 200), None,
    )  # fmt: skip
    assert RedactTokens().filter(record)
    assert record.getMessage() == '1.2.3.4:5 - "GET /?a=1&token=***&TOKEN=*** HTTP/1.1" 200'


@pytest.mark.parametrize(
    "name", ["%74oken", "T%4FKEN", "%54%6f%4B%65%6E", "%2574oken", "tok%65n", "+token"]
)
def test07_redact_decodes_parameter_names(name: str) -> None:
    """Issue 21, item 8: ``?%74oken=`` reaches the dashboard as ``token``; its value is
    redacted like the plain name's, and other parameters are left alone."""
    line = f"GET /?a=1&{name}=SECRET&b=token HTTP/1.1"
    assert redact(line) == f"GET /?a=1&{name}=***&b=token HTTP/1.1"
    assert redact("/?tokens=keep&atoken=keep") == "/?tokens=keep&atoken=keep"


def test08_access_log_redacts_percent_encoded_names(token_server: Server) -> None:
    token = str(token_server.token)
    r = httpx.get(f"{token_server.url}/?%74oken={token}", timeout=10)
    assert r.status_code == 200, r.text  # the server reads it as the token
    httpx.get(f"{token_server.url}/?TO%4BEN={token}", timeout=10)  # 401, still logged
    deadline = time.monotonic() + 5
    log = ""
    while time.monotonic() < deadline:
        log = token_server.log_path.read_text(errors="replace")
        if "%74oken=***" in log and "TO%4BEN=***" in log:
            break
        time.sleep(0.1)
    assert "%74oken=***" in log and "TO%4BEN=***" in log, log[-2000:]
    assert token not in log
