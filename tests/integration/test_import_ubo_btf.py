"""``import.btf`` of a Bonn ``.btf`` (DFMF) written by our own writer: through the upload
check and the kind, into shards whose slices equal the closed-form Lambertian plane
(albedo / pi * cos(theta_i)) and whose directions are the file's; malformed and
unsupported files are refused at upload (422, naming the file and the variant).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from fastapi.testclient import TestClient

from materials.btf.directions import to_vector
from matforge import datasets
from service.api import create_app
from service.settings import Settings
from service.submission import run_in_process
from storage.artifacts import ArtifactStore
from storage.formats.btf import parse_index, read_shard
from storage.formats.ubo_btf_write import encode_slices, factorize, write_dfmf

LIGHTS_DEG = np.array([[0.0, 0.0], [30.0, 45.0], [60.0, -120.0]])
VIEWS_DEG = np.array([[11.0, 15.0], [45.0, 180.0]])
H = W = 4


def lambert_file(path: Path) -> tuple[Path, np.ndarray]:
    count = len(LIGHTS_DEG) * len(VIEWS_DEG)
    theta_i = np.radians(np.tile(LIGHTS_DEG[:, 0], len(VIEWS_DEG)))
    alb = 0.1 + 0.6 * np.arange(H * W * 3).reshape(H, W, 3) / (H * W * 3)
    rgb = alb[None] / math.pi * np.cos(theta_i)[:, None, None, None]
    mats = encode_slices(rgb, theta_i, cosine_flag=False, color_model=11)
    write_dfmf(path, lights=np.radians(LIGHTS_DEG), views=np.radians(VIEWS_DEG), width=W,
               height=H, factors=[factorize(m) for m in mats], color_model=11,
               cosine_flag=False, scalar=4)  # fmt: skip
    assert rgb.shape[0] == count
    return path, rgb


def test01_dfmf_file_imports_into_shards(tmp_path: Path) -> None:
    settings = Settings.from_env({}).with_(data_dir=tmp_path / "data", pool_processes=1)
    path, rgb = lambert_file(tmp_path / "plane.btf")
    with TestClient(create_app(settings)) as client:
        r = client.post("/api/artifacts?name=plane.btf", content=path.read_bytes())
        assert r.status_code == 201, r.text
        ref = r.json()["ref"]
        bad = client.post("/api/artifacts?name=cut.btf", content=path.read_bytes()[:-5])
        assert bad.status_code == 422 and "cut.btf: truncated" in bad.json()["error"]
        bdi = b"!BDIF06R2!" + path.read_bytes()[10:]
        r = client.post("/api/artifacts?name=raw.btf", content=bdi)
        assert r.status_code == 422 and "raw.btf" in r.json()["error"]
        assert "BDI" in r.json()["error"]
    job = run_in_process({"kind": "import.btf", "params": {"archive": ref, "shard_slices": 4}},
                         settings)  # fmt: skip
    assert job.state == "succeeded", job.error
    store = ArtifactStore(settings.store_dir)
    arts = {a.name: a.digest for a in job.artifacts}
    index = parse_index(store.read(arts["btf.json"]))
    assert index.count == 6 and index.resolution == (H, W)
    assert [c for _, c in index.shards] == [4, 2]
    assert index.doc["ubo"]["variant"] == "DFMF" and index.doc["ubo"]["color_model"] == 11
    got = []
    for name, _ in index.shards:
        (tmp_path / name).write_bytes(store.read(arts[name]))
        got.append(read_shard(tmp_path / name, name))
    out = np.concatenate([s.rgb for s in got])
    np.testing.assert_allclose(out, rgb, rtol=2e-5, atol=1e-7)  # float32 factors
    li = np.tile(np.arange(3), 2)
    vi = np.repeat(np.arange(2), 3)
    wi = np.concatenate([s.wi for s in got])
    wo = np.concatenate([s.wo for s in got])
    np.testing.assert_allclose(wi, to_vector(LIGHTS_DEG[li, 0], LIGHTS_DEG[li, 1]), atol=1e-6)
    np.testing.assert_allclose(wo, to_vector(VIEWS_DEG[vi, 0], VIEWS_DEG[vi, 1]), atol=1e-6)
    opened = datasets.open(job.id, data_dir=settings.data_dir)  # the public reader
    assert isinstance(opened, datasets.BtfSlices) and opened.kind == "import.btf"
    np.testing.assert_array_equal(opened.numpy()["rgb"], out)
    # The job checks the decoded size itself, whatever way the file reached the store.
    capped = settings.with_(archive_max_pixels=95)
    spec = {"kind": "import.btf", "params": {"archive": ref, "shard_slices": 3}}
    refused = run_in_process(spec, capped)
    assert refused.state == "failed"
    assert "plane.btf: 6 slices of 4x4 decode to 96 pixels" in refused.error, refused.error
