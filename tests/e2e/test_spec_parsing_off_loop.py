"""Hostile specs are parsed off the event loop, with limits checked before parsing (issue 21,
item 5).

Four 6 KB nested-YAML specs used to hold ``/api/health`` for 11 s: PyYAML's pure-Python scanner
is quadratic in the nesting depth, and it ran on the event loop. Now YAML nesting, aliases and
size are checked on libyaml's events before anything is built, a spec over
``MAX_SPEC_BYTES`` is refused before it is parsed (413), and parsing and validation run in
worker threads.
"""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from fastapi.testclient import TestClient

from jobapi.errors import SpecError
from service import kinds
from service.api import create_app
from service.routes import jobs as jobs_routes
from service.settings import Settings
from service.spec_text import MAX_DEPTH, parse_json_text, parse_spec_text

from .harness import Server

YAML = {"content-type": "application/yaml"}
JSON = {"content-type": "application/json"}
#: The issue's attack: about 6 KB of YAML flow sequences nested 3,000 deep.
DEEP_YAML = "kind: render\nparams: {x: " + "[" * 3000 + "]" * 3000 + "}\n"


@pytest.fixture
def client(tmp_path: Path) -> Iterator[TestClient]:
    kinds.load_builtin()
    settings = Settings.from_env({}).with_(data_dir=tmp_path)
    with TestClient(create_app(settings), raise_server_exceptions=False) as c:
        yield c


def test01_health_answers_while_hostile_specs_are_parsed(server: Server) -> None:
    """4 clients send the deep YAML spec over and over for 3 s while health is probed.

    Before: each spec held the event loop for about a second (the probes waited up to 8 s).
    The bound, 1 s for the slowest probe, is ten times the goal (p99 < 100 ms; the benchmark,
    benchmarks/bench_hostile_parse.py, measures it): this 2-core machine is shared with other
    work, and the test must fail only for a blocked loop, not for a busy machine."""
    stop = time.monotonic() + 3.0
    refused: list[int] = []

    def attack() -> None:
        with httpx.Client(base_url=server.url, timeout=60.0) as c:
            while time.monotonic() < stop:
                refused.append(c.post("/api/jobs", content=DEEP_YAML, headers=YAML).status_code)

    threads = [threading.Thread(target=attack) for _ in range(4)]
    for t in threads:
        t.start()
    latencies = []
    with httpx.Client(base_url=server.url, timeout=60.0) as c:
        time.sleep(0.2)  # the first hostile specs are in flight
        while time.monotonic() < stop:
            t0 = time.perf_counter()
            assert c.get("/api/health").status_code == 200
            latencies.append(time.perf_counter() - t0)
            time.sleep(0.02)
    for t in threads:
        t.join(60)
    assert refused and set(refused) == {422}, set(refused)
    assert len(latencies) >= 10, latencies
    assert max(latencies) < 1.0, f"slowest health answer {max(latencies):.3f} s"


def test02_spec_parsing_runs_in_a_worker_thread(
    client: TestClient, monkeypatch: pytest.MonkeyPatch
) -> None:
    seen: list[bool] = []
    parse = jobs_routes.parse_spec_body

    def spy(raw: bytes, content_type: str) -> Any:
        try:
            asyncio.get_running_loop()
            seen.append(True)  # on the event loop
        except RuntimeError:
            seen.append(False)
        return parse(raw, content_type)

    monkeypatch.setattr(jobs_routes, "parse_spec_body", spy)
    assert client.post("/api/jobs", json={"kind": "render"}).status_code == 201
    assert client.post("/api/jobs", content=DEEP_YAML, headers=YAML).status_code == 422
    assert seen == [False, False]


def test03_deep_yaml_is_refused_before_it_is_built() -> None:
    t0 = time.perf_counter()
    with pytest.raises(SpecError, match=f"nested deeper than {MAX_DEPTH} levels"):
        parse_spec_text(DEEP_YAML, "spec.yaml", aliases=False)
    # Before: about 1 s (quadratic scan to the recursion limit); now a few ms. 0.5 s leaves
    # room for a loaded machine.
    assert time.perf_counter() - t0 < 0.5
    block = "params:\n" + "".join("  " * i + "a:\n" for i in range(1, 150)) + "  " * 150 + "1\n"
    with pytest.raises(SpecError, match=r"line \d+: nested deeper than"):
        parse_spec_text(block, "spec.yaml", aliases=False)
    ok = "params:\n" + "".join("  " * i + "a:\n" for i in range(1, 90)) + "  " * 90 + "1\n"
    assert isinstance(parse_spec_text(ok, "spec.yaml"), dict)


def test04_yaml_value_count_is_capped_before_it_is_built() -> None:
    text = "kind: render\nparams: {x: [" + ", ".join(["1"] * 2000) + "]}\n"
    with pytest.raises(SpecError, match="more than 1000 values"):
        parse_spec_text(text, "request body", aliases=False, max_values=1000)
    assert len(parse_spec_text(text, "spec.yaml")["params"]["x"]) == 2000  # no cap: parsed


def test05_json_checks_still_name_the_field() -> None:
    """The JSON fast path skips the value walk only for documents that cannot fail it."""
    with pytest.raises(SpecError, match="an integer of 5000 digits"):
        parse_json_text('{"seed": ' + "9" * 5000 + "}")
    with pytest.raises(SpecError) as err:
        parse_json_text('{"params": {"a": [1, NaN]}}')
    assert err.value.errors == [("params.a.1", "nan is not a finite number")]
    deep = "[" * (MAX_DEPTH + 5) + "]" * (MAX_DEPTH + 5)
    with pytest.raises(SpecError, match="nested deeper than"):
        parse_json_text(deep)
    wide = "[" + ", ".join(["[1]"] * 500) + "]"  # many brackets, shallow: walked, passes
    assert len(parse_json_text(wide)) == 500


def test06_large_specs_are_refused_before_parsing(client: TestClient) -> None:
    limit = jobs_routes.MAX_SPEC_BYTES
    body = '{"kind": "render", "params": {"resolution": [' + ",".join(["1"] * limit) + "]}}"
    r = client.post("/api/jobs", content=body, headers=JSON)
    assert r.status_code == 413, r.text
    assert "job spec" in r.json()["error"] and str(limit) in r.json()["error"]

    def chunks() -> Iterator[bytes]:  # no Content-Length: counted as it is read
        for i in range(0, len(body), 65536):
            yield body[i : i + 65536].encode()

    r = client.post("/api/jobs", content=chunks(), headers=JSON)
    assert r.status_code == 413, r.text
    yaml_body = "kind: render\nparams: {x: [" + ", ".join(["1"] * 60_000) + "]}\n"
    assert len(yaml_body) < limit
    r = client.post("/api/jobs", content=yaml_body, headers=YAML)
    assert r.status_code == 422 and "values" in r.json()["error"], r.text
