"""Rules the routes apply are stated in ``/openapi.json``, so that a request the schema
allows is not answered 422 (schemathesis's ``positive_data_acceptance``, ST202) and one it
refuses is refused. Five such requests used to get a 422 while the schema allowed them:

- ``GET /api/jobs?filter=`` (an empty filter): each filter item has a ``pattern``, the one
  rule ``parse_filters`` applies;
- ``PATCH /api/jobs/{id}`` with a tag outside ``[A-Za-z0-9_.:+-]{1,64}``: the tag items have
  that ``pattern`` (and ``"ab\\n"``, which the route took and the schema refuses, is
  refused by both);
- a ``select`` spec with neither ``runs`` nor ``scene``, ``reference`` and ``ladder``: its
  params schema has a ``oneOf`` over the two modes;
- ``POST /api/artifacts?name=`` a name without a known extension: the name has a
  ``pattern`` built from the formats' endings;
- ``POST /api/results/batch`` with a step spec without ``kind``: ``kind`` is required, one
  of the registered kinds.

The schema's patterns are read by the validator schemathesis uses (``jsonschema_rs``,
ECMA-262); values drawn from them (hypothesis, ``fullmatch``) are accepted by the code.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import jsonschema_rs
import pytest
from fastapi.testclient import TestClient
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from service import kinds
from service.api import create_app
from service.job_columns import parse_filters
from service.routes.jobs import TAG
from service.settings import Settings
from storage.formats import format_for


@pytest.fixture(scope="module")
def app_doc(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[TestClient, dict]]:
    kinds.load_builtin()
    settings = Settings.from_env({}).with_(data_dir=tmp_path_factory.mktemp("schema") / "d")
    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        yield client, client.get("/openapi.json").json()


def _param(doc: dict, path: str, method: str, name: str) -> dict[str, Any]:
    (p,) = [p for p in doc["paths"][path][method]["parameters"] if p["name"] == name]
    return p["schema"]


def _valid(doc: dict, schema: dict[str, Any], value: Any) -> bool:
    """Whether ``value`` passes ``schema`` (its ``$ref``s resolved in ``doc``)."""
    return jsonschema_rs.validator_for({**schema, "components": doc["components"]}).is_valid(value)


def _filter_pattern(doc: dict) -> str:
    (array,) = [s for s in _param(doc, "/api/jobs", "get", "filter")["anyOf"] if "items" in s]
    return str(array["items"]["pattern"])


def _tag_pattern(doc: dict) -> str:
    return str(
        doc["components"]["schemas"]["JobPatch"]["properties"]["add_tags"]["items"]["pattern"]
    )


def _name_pattern(doc: dict) -> str:
    return str(_param(doc, "/api/artifacts", "post", "name")["pattern"])


def test01_an_empty_filter_is_outside_the_schema_and_refused(app_doc) -> None:
    client, doc = app_doc
    item = {"type": "string", "pattern": _filter_pattern(doc)}
    assert not _valid(doc, item, "")
    assert client.get("/api/jobs", params={"filter": ""}).status_code == 422
    for ok in (
        "params.model=hybrid",
        " metric.psnr >= 1e999 ",
        "params.scene.name!=\t",
        "params.spp<.5",
    ):
        assert _valid(doc, item, ok), ok
        r = client.get("/api/jobs", params={"filter": ok})
        assert r.status_code == 200, (ok, r.text)
    for bad in ("params.x<high", "x=1", "params.a="):
        if not _valid(doc, item, bad):
            assert client.get("/api/jobs", params={"filter": bad}).status_code == 422, bad


def test02_tags_outside_the_charset_are_outside_the_schema(app_doc) -> None:
    client, doc = app_doc
    item = {"type": "string", "pattern": _tag_pattern(doc)}
    job = client.post("/api/jobs", json={"kind": "render", "params": {"resolution": [8, 8]}})
    assert job.status_code in (200, 201), job.text
    url = f"/api/jobs/{job.json()['id']}"
    for bad in ("a b", "", "x" * 65, "ab\n", "é"):
        assert not _valid(doc, item, bad), bad
        assert client.patch(url, json={"add_tags": [bad]}).status_code == 422, bad
    for ok in ("a:b+c", "v1.2-rc_3", "x" * 64):
        assert _valid(doc, item, ok)
        assert client.patch(url, json={"add_tags": [ok]}).status_code == 200, ok


def test03_a_select_spec_states_its_two_modes(app_doc) -> None:
    _, doc = app_doc
    select = {"$ref": "#/components/schemas/params.select"}
    scene = {"scene": "sphere_env", "resolution": [16, 16], "spp": 4}
    rungs = [{"name": "d", "material": {"mitsuba": {"type": "diffuse"}}}]
    ref = "job:" + "a" * 32 + "/image.exr"
    assert not _valid(doc, select, {"target": 0.1})  # neither mode
    assert not _valid(doc, select, {"target": 0.1, "scene": scene, "ladder": rungs})
    assert not _valid(doc, select, {"target": 0.1, "runs": ["job:" + "a" * 32], "scene": scene})
    assert _valid(doc, select, {"target": 0.1, "runs": ["job:" + "a" * 32]})
    assert _valid(doc, select, {"target": 0.1, "scene": scene, "reference": ref, "ladder": rungs})


def test04_an_upload_name_without_a_format_is_outside_the_schema(app_doc) -> None:
    client, doc = app_doc
    name = _param(doc, "/api/artifacts", "post", "name")
    for bad in ("noext", "x.zip", ".png", "a/b.png", "x.png\n", "x.png."):
        assert not _valid(doc, name, bad), bad
        r = client.post("/api/artifacts", params={"name": bad}, content=b"x")
        assert r.status_code == 422, (bad, r.text)
    for ok in ("a.PNG", "..png", "scan.btf.zip", ".btf.zip", "n.Normal.exr", "m.binary"):
        assert _valid(doc, name, ok), ok


def test05_a_batch_step_spec_needs_a_registered_kind(app_doc) -> None:
    client, doc = app_doc
    body = {"$ref": "#/components/schemas/BatchQuery"}
    for spec in ({}, {"kind": "no-such-kind"}, {"params": {}}):
        value = {"steps": [{"name": "a", "spec": spec}]}
        assert not _valid(doc, body, value), spec
        assert client.post("/api/results/batch", json=value).status_code == 422
    assert _valid(doc, body, {"steps": [{"name": "a", "spec": {"kind": "render"}}]})


_SETTINGS = settings(
    max_examples=200, derandomize=True, deadline=None, suppress_health_check=list(HealthCheck)
)


def _drawn(pattern: str) -> st.SearchStrategy[str]:
    """Strings the schema's ``pattern`` allows, as schemathesis reads it (the closing
    ``$`` as the end of the string; ``\\d``, ``\\w`` over ASCII)."""
    return st.from_regex(re.compile(pattern[:-1] + r"\Z", re.ASCII))


def test06_values_drawn_from_the_patterns_are_accepted_by_the_code(
    app_doc, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The pattern states a filter's syntax; its column is checked against the kinds'
    params and metrics (an unknown one is refused naming the closest, as the parameter's
    description says), which no pattern can state: drawn names pass that check here."""
    import service.job_columns

    monkeypatch.setattr(service.job_columns, "check_key", lambda key, where: key)
    _, doc = app_doc
    filters, tags, names = _filter_pattern(doc), _tag_pattern(doc), _name_pattern(doc)
    bad_chars = set("/\\\x00") | {chr(c) for c in range(32)}

    @_SETTINGS
    @given(st.one_of(_drawn(filters).map(lambda s: ("filter", s)),
                     _drawn(tags).map(lambda s: ("tag", s)),
                     _drawn(names).map(lambda s: ("name", s))))  # fmt: skip
    def accepted(item: tuple[str, str]) -> None:
        what, text = item
        if what == "filter":
            assert len(parse_filters([text])) == 1
        elif what == "tag":
            assert TAG.fullmatch(text), text
        else:
            assert not bad_chars & set(text) and format_for(text) is not None, text

    accepted()


def test07_the_name_pattern_is_the_formats_own(tmp_path: Path) -> None:
    """Names the pattern refuses have no format (a spot check of the other direction)."""
    from storage.formats import upload_name_pattern

    pattern = re.compile(upload_name_pattern())
    for name in ("x.pngx", "x.np", "x.btfzip", "x.normal", "x.tar.gz"):
        assert pattern.fullmatch(name) is None and format_for(name) is None, name


def test08_a_patch_body_that_is_not_utf8_is_a_422(app_doc) -> None:
    """FastAPI answered 400 "There was an error parsing the body", a status the document
    does not list (schemathesis ST103, once tags had a pattern to draw from); a body that
    does not parse is bad input, 422, as a JSON syntax error already was."""
    client, _ = app_doc
    job = client.post("/api/jobs", json={"kind": "render", "params": {"resolution": [8, 8]}})
    r = client.patch(
        f"/api/jobs/{job.json()['id']}",
        content=b"+\xff\xfefy\xc3",
        headers={"content-type": "application/json"},
    )
    assert r.status_code == 422, r.text
    assert r.json()["error"] == "body: not a JSON document (not UTF-8 text)"
