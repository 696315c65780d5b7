"""ONNX uploads through ``POST /api/artifacts``: a malformed or hostile file is a 4xx naming
the file and the problem, checked in the bounded child of :mod:`service.upload_check`.

Reference: the documented signature and limits (``docs/onnx-models.md``); each bad file is
a valid Lambertian model (``onnx.helper``, :mod:`tests.helpers.onnx_models`) with one thing
changed.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import onnx
import pytest
from fastapi.testclient import TestClient
from onnx import TensorProto, helper, numpy_helper

from service.api import create_app
from service.settings import Settings
from service.upload_check import UploadChecker
from storage.errors import TooLargeError
from tests.helpers.onnx_models import constant_fold_bomb, lambert_model, quadratic_bomb, save

from .harness import base_env, run_cli

OCTETS = {"content-type": "application/octet-stream"}


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    settings = Settings.from_env({}).with_(data_dir=tmp_path_factory.mktemp("onnx-uploads"))
    with TestClient(create_app(settings), raise_server_exceptions=False) as c:
        yield c


def _post(client: TestClient, name: str, body: bytes) -> tuple[int, str]:
    r = client.post(f"/api/artifacts?name={name}", content=body, headers=OCTETS)
    return r.status_code, (r.json().get("error") or r.json().get("media_type") or "")


def _wrong_signature() -> onnx.ModelProto:
    m = lambert_model("btf")
    m.graph.input[1].name = "light"
    return m


def _huge() -> onnx.ModelProto:
    m = lambert_model("btf")
    m.graph.initializer.append(
        TensorProto(name="w", data_type=TensorProto.FLOAT, dims=[2**30, 4], raw_data=b"\0" * 16)
    )
    return m


def _op() -> onnx.ModelProto:
    m = lambert_model("btf")
    m.graph.node.append(helper.make_node("Loop", ["a", "b"], ["c"]))
    return m


def _domain() -> onnx.ModelProto:
    m = lambert_model("btf")
    m.graph.node[0].domain = "com.microsoft"
    m.opset_import.append(helper.make_opsetid("com.microsoft", 1))
    return m


CASES = [
    ("wrong signature", _wrong_signature, 422, "inputs (uv, light, wo) match no signature"),
    ("huge initialiser", _huge, 413, "initialiser 'w' declares 16384.0 MiB"),
    ("unsupported op", _op, 422, "operator Loop is not allowed"),
    ("custom domain", _domain, 422, "custom operator domain 'com.microsoft'"),
    ("truncated", lambda: lambert_model("btf").SerializeToString()[:40], 422, ""),
    (
        "constant-folding bomb",
        constant_fold_bomb,
        413,
        "node 'fold_add' (Add) computes 'square' [16384, 16384] from initialisers and "
        "constants only: 1024.0 MiB",
    ),
    (
        "run-time quadratic",
        quadratic_bomb,
        422,
        "node 'square' (Add) makes 'square' of shape [N, N]: it grows faster than the batch",
    ),
]


def test01_valid_onnx_is_stored(client: TestClient) -> None:
    status, media = _post(client, "lambert.onnx", lambert_model("brdf").SerializeToString())
    assert (status, media) == (201, "application/x-onnx")


@pytest.mark.parametrize(("label", "make", "status", "says"), CASES, ids=[c[0] for c in CASES])
def test02_bad_files_are_refused_naming_the_problem(
    client: TestClient, label: str, make: object, status: int, says: str
) -> None:
    model = make()  # type: ignore[operator]
    body = model if isinstance(model, bytes) else model.SerializeToString()
    got, error = _post(client, "bad.onnx", body)
    assert got == status, error
    assert error.startswith("bad.onnx: ") and says in error, error


def test03_memory_is_bounded_by_the_checker(tmp_path: Path) -> None:
    """Under a 160 MB cap a small model is checked (the cap leaves room for the interpreter
    and onnx), a 57 MiB one (under the file limit) runs out of memory in the child: a 413-type
    error naming the file; the next file is checked by a fresh child."""
    m = lambert_model("btf")
    m.graph.initializer.append(numpy_helper.from_array(np.ones(15_000_000, np.float32), "pad"))
    big = save(m, tmp_path / "big.onnx")
    small = save(lambert_model("btf"), tmp_path / "small.onnx")
    checker = UploadChecker(max_bytes=160 * 1024 * 1024)
    try:
        assert checker.validate(small, "small.onnx") == "application/x-onnx"
        with pytest.raises(TooLargeError, match=r"^big.onnx: decoding it needs more memory"):
            checker.validate(big, "big.onnx")
        assert checker.validate(small, "small.onnx") == "application/x-onnx"
    finally:
        checker.close()


def test04_a_wrong_declared_kind_is_refused_before_queueing(client: TestClient) -> None:
    """An uploaded ONNX BRDF named as a BTF (and the other way round) is a 422 naming the
    field and the signature, and nothing is queued (the reference: the file's own inputs)."""
    r = client.post(
        "/api/artifacts?name=lambert.onnx",
        content=lambert_model("brdf").SerializeToString(),
        headers=OCTETS,
    )
    assert r.status_code == 201, r.text
    ref = r.json()["ref"]
    before = len(client.get("/api/jobs").json())
    spec = {"kind": "render", "params": {"scene": "sphere_env", "spp": 1, "resolution": [8, 8],
            "material": {"external": {"model": ref, "kind": "btf"}}}}  # fmt: skip
    res = client.post("/api/jobs", json=spec)
    assert res.status_code == 422, res.text
    assert "params.material.external.model" in res.text and "declared kind 'btf'" in res.text
    assert len(client.get("/api/jobs").json()) == before
    spec["params"]["material"]["external"]["kind"] = "brdf"  # type: ignore[index]
    assert client.post("/api/jobs", json=spec).status_code == 201


def test05_an_mlp_file_of_the_other_kind_is_refused_before_queueing(
    client: TestClient, tmp_path: Path
) -> None:
    """A ``matforge.mlp-brdf/1`` file declared as a BTF: a 422 naming ``kind`` and the
    file's format (the reference: the format the exporter wrote)."""
    import torch

    from matforge.export import brdf_mlp

    net = torch.nn.Sequential(torch.nn.Linear(6, 8), torch.nn.ReLU(), torch.nn.Linear(8, 3))
    path = brdf_mlp(net, tmp_path / "mine.json")
    r = client.post("/api/artifacts?name=mine.json", content=path.read_bytes(), headers=OCTETS)
    assert r.status_code == 201, r.text
    spec = {"kind": "render", "params": {"scene": "sphere_env", "spp": 1, "resolution": [8, 8],
            "material": {"external": {"model": r.json()["ref"], "kind": "btf"}}}}  # fmt: skip
    res = client.post("/api/jobs", json=spec)
    assert res.status_code == 422, res.text
    assert "params.material.external.kind" in res.text and "matforge.mlp-brdf/1" in res.text


def test06_matforge_import_refuses_both_bombs(tmp_path: Path) -> None:
    """``matforge import`` (a local data directory) refuses the two graphs the upload
    refuses, with the same message on stderr, exit 2 and no traceback."""
    for name, make, says in (
        ("fold.onnx", constant_fold_bomb, "node 'fold_add' (Add) computes 'square'"),
        ("square.onnx", quadratic_bomb, "node 'square' (Add) makes 'square' of shape [N, N]"),
    ):
        path = save(make(), tmp_path / name)
        res = run_cli("import", str(path), "--data-dir", str(tmp_path / "d"), env=base_env())
        assert res.returncode == 2, res
        assert f"{name}: {says}" in res.stderr and "Traceback" not in res.stderr, res
