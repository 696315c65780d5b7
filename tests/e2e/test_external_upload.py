"""Uploading a user's MLP material through ``POST /api/artifacts`` (issue 23, 1.1): a valid
``matforge.mlp-brdf/1`` file is stored; a malformed one is a 422 naming the file and the
problem (checked in the bounded upload checker, :mod:`service.upload_check`); the stored
file is accepted by a ``render`` spec's ``external`` material."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

import matforge.export as export
from service import kinds
from service.api import create_app
from service.settings import Settings

OCTETS = {"content-type": "application/octet-stream"}


@pytest.fixture
def client(tmp_path: Path) -> Iterator[TestClient]:
    kinds.load_builtin()
    settings = Settings.from_env({}).with_(data_dir=tmp_path / "data")
    with TestClient(create_app(settings), raise_server_exceptions=False) as c:
        yield c


def _good(tmp_path: Path) -> dict[str, Any]:
    p = export.brdf_mlp(
        None, tmp_path / "ggx.json", analytic={"kd": [0.2, 0.3, 0.4], "alpha": 0.2, "eta": 1.5}
    )
    return json.loads(p.read_text())


def test01_valid_upload_is_stored_and_renders_in_a_spec(client: TestClient, tmp_path: Path) -> None:
    r = client.post(
        "/api/artifacts?name=ggx.json", content=json.dumps(_good(tmp_path)), headers=OCTETS
    )
    assert r.status_code == 201, r.text
    ref = r.json()["ref"]
    material = {"external": {"model": ref, "kind": "brdf"}}
    spec = {"kind": "render", "params": {"resolution": [8, 8], "spp": 1, "material": material}}
    r = client.post("/api/jobs", json=spec)
    assert r.status_code == 201, r.text
    material = {"external": {"model": ref, "kind": "bsdf"}}
    bad = {**spec, "params": {**spec["params"], "material": material}}
    r = client.post("/api/jobs", json=bad)
    assert r.status_code == 422 and "external.kind" in r.text


@pytest.mark.parametrize(
    ("change", "problem"),
    [
        (lambda d: d["analytic"].update(alpha=3.0), "analytic.alpha: must be a number in"),
        (
            lambda d: d.update(
                layers=[{"weight": [[1.0] * 6] * 3, "bias": [0.0] * 3, "activation": "swish"}]
            ),
            r"layers\[0\].activation",
        ),
        (lambda d: d.update(format="matforge.mlp-btf/1", analytic=None), "unknown key 'analytic'"),
    ],
)
def test02_malformed_upload_is_a_422_naming_file_and_problem(
    client: TestClient, tmp_path: Path, change: Any, problem: str
) -> None:
    doc = _good(tmp_path)
    change(doc)
    r = client.post("/api/artifacts?name=mine.json", content=json.dumps(doc), headers=OCTETS)
    assert r.status_code == 422, r.text
    error = str(r.json()["error"])
    assert error.startswith("mine.json: not a valid MLP model: "), error
    import re

    assert re.search(problem, error), error


def test03_a_json_that_is_no_model_file_is_refused(client: TestClient, tmp_path: Path) -> None:
    """``{"format": "nope"}`` is a 422 naming the file and its format, through the API and
    from ``matforge import`` (exit 2, nothing stored); a JSON file over 64 MiB is a 413."""
    from storage.formats import MAX_JSON_BYTES

    from .harness import base_env, run_cli

    r = client.post("/api/artifacts?name=nope.json", content=b'{"format":"nope"}', headers=OCTETS)
    assert r.status_code == 422, r.text
    error = str(r.json()["error"])
    assert error.startswith("nope.json: not a model file: ") and "'format' 'nope'" in error, error
    path = tmp_path / "nope.json"
    path.write_bytes(b'{"format":"nope"}')
    res = run_cli("import", str(path), "--data-dir", str(tmp_path / "d"), env=base_env())
    assert res.returncode == 2, res
    assert "nope.json: not a model file: " in res.stderr and "Traceback" not in res.stderr, res
    big = b'{"format": "matforge.mlp-brdf/1", "pad": "' + b" " * MAX_JSON_BYTES + b'"}'
    r = client.post("/api/artifacts?name=big.json", content=big, headers=OCTETS)
    assert r.status_code == 413, r.text
    assert r.json()["error"].startswith("big.json: JSON document of "), r.text
