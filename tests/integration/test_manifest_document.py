"""The manifest a job writes is a :class:`jobapi.documents.ManifestDocument`: every key the
type names, no other, each of its declared type; stored as canonical JSON (sorted keys, no
whitespace) and a newline, and read back by ``matforge.Client.manifest`` as that type.

Oracle: the stored bytes, parsed and checked against the type by pydantic (strict).
"""

from __future__ import annotations

import json
from pathlib import Path

import matforge
from jobapi.documents import ManifestDocument, check_typed
from service.specs import canonical_json

GLINT = {"kind": "generate.glint", "seed": 3,
         "params": {"example": {"procedural": "isotropic_noise", "size": 8},
                    "ndf_resolution": 16}}  # fmt: skip


def test01_a_jobs_manifest_is_its_type(tmp_path: Path) -> None:
    doc = matforge.run(GLINT, tmp_path / "data")
    digest = str(doc["manifest"]).removeprefix("sha256:")
    (stored,) = (tmp_path / "data").rglob(digest[2:])
    raw = stored.read_bytes()
    manifest = json.loads(raw)
    check_typed("manifest", manifest, ManifestDocument)  # raises naming the field
    assert raw == (canonical_json(manifest) + "\n").encode()
    assert manifest["job"] == doc["id"] and manifest["seed"] == 3
    assert [a["name"] for a in manifest["artifacts"]] == sorted(a["name"] for a in doc["artifacts"])
    assert manifest["executor_nodes"] >= 1
    assert set(manifest) == set(ManifestDocument.__annotations__)
