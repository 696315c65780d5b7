"""The ``model.json`` that real ``train.brdf`` and ``train.btf`` jobs write (their smoke
params, with their dataset jobs first) follows its published schema
(``storage/formats/schemas/``), checked with :mod:`tests.helpers.json_schema`."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import pytest

from service.settings import Settings
from storage.artifacts import ArtifactStore
from storage.formats import mlp_model
from tests.helpers.json_schema import errors
from tests.integration.test_kinds_smoke import SmokeRuns

SCHEMAS = Path(mlp_model.__file__).parent / "schemas"


@pytest.fixture(scope="module")
def smoke(tmp_path_factory: pytest.TempPathFactory) -> Iterator[SmokeRuns]:
    data = Path(tmp_path_factory.mktemp("schemas")) / "data"
    yield SmokeRuns(Settings.from_env({}).with_(data_dir=data, pool_processes=1))


@pytest.mark.slow
@pytest.mark.parametrize(
    ("kind", "schema"),
    [("train.brdf", "matforge.brdf-model-1"), ("train.btf", "matforge.btf-model-1")],
)
def test01_trained_models_follow_their_schemas(smoke: SmokeRuns, kind: str, schema: str) -> None:
    job = smoke.job(kind)
    assert job.state == "succeeded", job.error
    (art,) = [a for a in job.artifacts if a.name == "model.json"]
    doc = json.loads(ArtifactStore(smoke.settings.store_dir).path(art.digest).read_text())
    found = errors(json.loads((SCHEMAS / f"{schema}.schema.json").read_text()), doc)
    assert found == [], found[:5]
