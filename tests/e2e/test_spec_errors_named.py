"""Issue 26 §4 at the edges: a misspelt Mitsuba property or enum value is refused before
queueing with "did you mean" (REST 422 naming the field, CLI exit 2); what only Mitsuba can
refuse fails the job with Mitsuba's whole message, in the JSON and in the job's log; and
``matforge kinds`` shows a nested model's allowed values."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from service.api import create_app
from service.settings import Settings
from tests.e2e.harness import base_env, run_cli

ALPAH = {
    "kind": "render",
    "params": {"material": {"mitsuba": {"type": "roughconductor", "alpah": 0.2}}},
}
SCRATCH = {"kind": "generate.glint", "params": {"example": {"procedural": "scratch", "size": 16}}}


@pytest.fixture
def client(tmp_path: Path) -> Iterator[TestClient]:
    settings = Settings.from_env({}).with_(data_dir=tmp_path)
    with TestClient(create_app(settings)) as c:
        yield c


@pytest.mark.parametrize(
    ("spec", "field", "hint"),
    [
        (ALPAH, "params.material", "did you mean 'alpha'?"),
        (SCRATCH, "params.example.procedural", "did you mean 'scratches'?"),
    ],
)
def test01_rest_refuses_with_the_field_and_a_hint(
    client: TestClient, spec: dict[str, Any], field: str, hint: str
) -> None:
    r = client.post("/api/jobs", json=spec)
    assert r.status_code == 422, r.text
    out = r.json()
    assert hint in out["error"] and field in out["error"], out
    locs = [".".join(str(p) for p in d["loc"] if p != "body") for d in out["detail"]]
    assert locs == [field], out["detail"]
    assert client.get("/api/jobs").json() == []  # nothing was queued


#: Two typos at once: an unknown field and an unknown kind in one batch of errors.
SPPP = {"kind": "render", "seed": -1, "params": {"material": {"mitsuba": {"type": "diffuse"}},
                                                 "sppp": 4}}  # fmt: skip
RENDR = {"kind": "rendr", "nmae": "x", "params": {"spp": 4}}


@pytest.mark.parametrize(
    ("spec", "errors"),
    [
        (SPPP, {"seed": "greater than or equal to 0", "params.sppp": "did you mean 'spp'?"}),
        (RENDR, {"nmae": "did you mean 'name'?", "kind": "did you mean 'render'?"}),
    ],
)
def test05_rest_reports_every_typo_with_its_hint(
    client: TestClient, spec: dict[str, Any], errors: dict[str, str]
) -> None:
    r = client.post("/api/jobs", json=spec)
    assert r.status_code == 422, r.text
    body = r.json()
    detail = {".".join(str(p) for p in d["loc"] if p != "body"): d["msg"] for d in body["detail"]}
    assert list(detail) == list(errors), detail
    for field, hint in errors.items():
        assert hint in detail[field] and hint in body["error"], detail


def spec_file(path: Path, spec: dict[str, Any]) -> Path:
    path.write_text(json.dumps(spec), encoding="utf-8")
    return path


def test02_cli_exits_2_with_the_hint(tmp_path: Path) -> None:
    data = ["--data-dir", str(tmp_path / "d")]
    for spec, words in (
        (ALPAH, ["params.material", "alpah", "did you mean 'alpha'?"]),
        (SCRATCH, ["params.example.procedural", "did you mean 'scratches'?"]),
    ):
        res = run_cli("run", str(spec_file(tmp_path / "s.json", spec)), *data, env=base_env())
        assert res.returncode == 2, res
        for word in words:
            assert word in res.stderr, res


def test06_cli_exits_2_with_every_typo(tmp_path: Path) -> None:
    data = ["--data-dir", str(tmp_path / "d")]
    for spec, words in (
        (SPPP, ["seed", "params.sppp", "did you mean 'spp'?"]),
        (RENDR, ["nmae", "did you mean 'name'?", "did you mean 'render'?"]),
    ):
        res = run_cli("run", str(spec_file(tmp_path / "s.json", spec)), *data, env=base_env())
        assert res.returncode == 2, res
        for word in words:
            assert word in res.stderr, res


def test03_mitsubas_whole_message_in_the_json_and_the_log(tmp_path: Path) -> None:
    # twosided takes nested plugins under any key, so the check lets a texture through;
    # Mitsuba names it on its message's second line
    nested = {"type": "twosided", "bsdf": {"type": "diffuse"}, "extra": {"type": "checkerboard"}}
    spec = {
        "kind": "render",
        "params": {"material": {"mitsuba": nested}, "resolution": [16, 16], "spp": 1},
    }
    data = ["--data-dir", str(tmp_path / "d")]
    res = run_cli("run", str(spec_file(tmp_path / "s.json", spec)), "--json", *data, env=base_env())
    assert res.returncode == 1, res
    doc = res.json()
    assert doc["state"] == "failed" and "\n" not in doc["error"], doc
    assert 'unreferenced property in bsdf plugin of type "twosided"' in doc["error"], doc
    assert 'object "extra"' in doc["error"], doc
    log = run_cli("logs", doc["id"], *data, env=base_env())
    assert log.returncode == 0, log
    assert 'object "extra"' in log.stdout, log


def test04_kinds_shows_nested_allowed_values(tmp_path: Path) -> None:
    res = run_cli("kinds", "generate.glint", env=base_env(COLUMNS="160"))
    assert res.returncode == 0, res
    assert "ProceduralExample" in res.stdout and "scratches" in res.stdout, res
    assert "isotropic_noise" in res.stdout and "normal_map" in res.stdout, res
