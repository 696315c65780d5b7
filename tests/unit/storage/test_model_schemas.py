"""The published JSON schemas of the model formats (``storage/formats/schemas/``) describe
what matforge writes and what it accepts.

Oracles: the documents written by the real writers (``models.brdf.portable.to_portable``
of ``train.brdf`` models of each type, ``models.btf.portable.model_document`` of
``train.btf`` networks and the Lafortune fit's document, ``matforge.export``), checked
with :mod:`tests.helpers.json_schema` (a keyword-by-keyword JSON Schema checker written
for these tests); and documents the schema must reject.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from storage.formats import mlp_model
from tests.helpers.brdf_models import make_model
from tests.helpers.json_schema import errors

SCHEMAS = Path(mlp_model.__file__).parent / "schemas"


def schema(name: str) -> dict[str, Any]:
    return json.loads((SCHEMAS / f"{name}.schema.json").read_text(encoding="utf-8"))


def roundtrip(doc: dict[str, Any]) -> Any:
    return json.loads(json.dumps(doc))


@pytest.mark.parametrize("kind", ["hybrid", "neural", "analytic"])
def test01_brdf_model_documents_follow_their_schema(kind: str) -> None:
    doc = roundtrip(make_model(kind, 8, 2, 3))
    assert errors(schema("matforge.brdf-model-1"), doc) == []
    doc["materials"][0]["kd"] = [0.1, 0.2]
    doc["surprise"] = 1
    found = errors(schema("matforge.brdf-model-1"), doc)
    assert any("kd" in e for e in found) and any("surprise" in e for e in found)


@pytest.mark.parametrize("model", ["neumip", "c2f", "lafortune"])
def test02_btf_model_documents_follow_their_schema(model: str) -> None:
    from models.btf.networks import Architecture, build_network
    from models.btf.portable import model_document, network_layers, network_textures

    if model == "lafortune":
        arch = {
            "model": "lafortune",
            "width": 0,
            "resolution": [4, 4],
            "lobes": 4,
            "params_per_texel": 55,
            "fit_slices": 10,
        }
        doc = model_document("lafortune", arch, {}, {"params": np.zeros((4, 4, 55))}, {})
    else:
        a = Architecture(model, 8, (4, 4))
        net = build_network(a, 0)
        doc = model_document(
            model, a.as_dict(), network_layers(net), network_textures(net), {"seed": 0}
        )
    doc = roundtrip(doc)
    assert errors(schema("matforge.btf-model-1"), doc) == []
    doc["storage"].pop("total_bytes")
    assert errors(schema("matforge.btf-model-1"), doc) == ["$.storage: missing 'total_bytes'"]


def test03_exported_mlp_documents_follow_their_schemas(tmp_path: Path) -> None:
    import torch

    import matforge.export as export

    net = torch.nn.Sequential(torch.nn.Linear(9, 8), torch.nn.ReLU(), torch.nn.Linear(8, 6))
    p = export.brdf_mlp(
        net,
        tmp_path / "a.json",
        inputs=["wi", "wo", "h"],
        output_activation=["exp"] * 3 + ["sigmoid"] * 3,
        analytic={"kd": [0.1] * 3, "alpha": 0.2, "eta": 1.5},
    )
    brdf = json.loads(p.read_text())
    assert errors(schema("matforge.mlp-brdf-1"), brdf) == []
    btf_net = torch.nn.Sequential(torch.nn.Linear(3 + 2 + 2, 3))
    p = export.btf_mlp(
        btf_net,
        tmp_path / "b.json",
        textures=[np.ones((3, 2, 2))],
        inputs=[
            {"type": "texture", "index": 0},
            "uv",
            {"type": "fourier", "input": "cos_i", "frequencies": [1.0]},
        ],
    )
    btf = json.loads(p.read_text())
    assert errors(schema("matforge.mlp-btf-1"), btf) == []
    # What the schema rejects, the parser rejects too.
    for bad in (
        {**brdf, "inputs": ["uv"]},
        {**brdf, "output": {"combine": "product"}},
        {**btf, "foreshortening": "maybe"},
        {**btf, "textures": [{**btf["textures"][0], "dtype": "float16"}]},
    ):
        assert errors(schema(f"matforge.mlp-{'btf' if 'textures' in bad else 'brdf'}-1"), bad)
        with pytest.raises(mlp_model.FormatError):
            mlp_model.parse_mlp_document(bad, "bad.json")


def test04_schemas_are_listed_and_shipped() -> None:
    names = sorted(p.name for p in SCHEMAS.glob("*.schema.json"))
    assert names == [
        "matforge.brdf-model-1.schema.json",
        "matforge.btf-model-1.schema.json",
        "matforge.mlp-brdf-1.schema.json",
        "matforge.mlp-btf-1.schema.json",
    ]
    pyproject = (Path(__file__).resolve().parents[3] / "pyproject.toml").read_text()
    assert 'storage = ["formats/schemas/*.schema.json"]' in pyproject
