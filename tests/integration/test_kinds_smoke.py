"""Every registered job kind runs its own tiny smoke params end to end through the registry
(in the style of nerfstudio's test_train.py): validation, queue, runner, artifacts, manifest.
"""

from __future__ import annotations

import fnmatch
import json

import pytest

from service import registry
from service.settings import Settings
from service.submission import run_in_process

KINDS = sorted(registry.kinds().values(), key=lambda k: k.name)


def test00_every_kind_documents_itself() -> None:
    for kind in KINDS:
        assert kind.summary, kind.name
        schema = kind.params.model_json_schema()
        assert schema.get("additionalProperties") is False, f"{kind.name} params are not strict"
        for name, prop in schema.get("properties", {}).items():
            assert prop.get("description"), f"{kind.name}.params.{name} has no description"


@pytest.mark.parametrize("kind", [k for k in KINDS if k.smoke], ids=lambda k: k.name)
def test01_smoke(kind: registry.Kind, settings: Settings) -> None:
    job = run_in_process({"kind": kind.name, "seed": 0, "params": kind.smoke}, settings)
    assert job.state == "succeeded", job.error
    names = [a.name for a in job.artifacts]
    for pattern in kind.artifacts:
        assert any(fnmatch.fnmatch(n, pattern) for n in names), (pattern, names)
    from storage.artifacts import ArtifactStore

    store = ArtifactStore(settings.store_dir)
    manifest = json.loads(store.read(job.manifest_digest))
    assert [a["name"] for a in manifest["artifacts"]] == sorted(names)
    for art in job.artifacts:
        assert store.verify(art.digest)
