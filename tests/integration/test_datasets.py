"""``matforge.datasets`` over a local data directory: every dataset family generated with the
project's own small settings, opened through the readers, and checked against the raw
artifacts read independently (the store's bytes, ``np.load`` and a numpy decode of the MERL
layout), then iterated with a torch ``DataLoader``.

Oracles: the documented layouts (``docs/artifacts.md``), read here without any reader code;
the readers must return exactly those values (equal arrays, not close ones: nothing is
recomputed, only read).
"""

from __future__ import annotations

import io
import json
import struct
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

import matforge
from materials.halfdiff import lookup
from matforge import datasets
from service.settings import Settings
from service.submission import import_file
from storage.artifacts import ArtifactStore
from storage.errors import IntegrityError, NotFoundError
from storage.formats.btf_folder import pack_folder
from storage.formats.exr import exr_bytes, read_exr
from storage.jobs import JobStore

SPECS: dict[str, dict[str, Any]] = {
    "merl": {"kind": "generate.merl", "seed": 5,
             "params": {"collection": {"families": {"metal": 1, "paint": 1}}}},
    "glint": {"kind": "generate.glint", "seed": 3,
              "params": {"example": {"procedural": "isotropic_noise", "size": 8},
                         "ndf_resolution": 16}},
    "btf": {"kind": "generate.btf", "seed": 4,
            "params": {"surface": {"procedural": "wood", "size": 8}, "resolution": 8, "spp": 2,
                       "directions": [[0, 0, 0, 0], [30, 40, 60, 200], [60, 200, 30, 40],
                                      [75, 90, 10, 0]],
                       "shard_slices": 3}},
    "fabric": {"kind": "generate.fabric", "seed": 5,
               "params": {"patterns": ["plain"], "texture_sets": 1, "shading_sets": 2,
                          "queries_per_material": 64, "shard_queries": 32, "samples": 64,
                          "map_resolution": 16, "backend": "numpy"}},
}  # fmt: skip


@pytest.fixture(scope="module")
def data(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, dict[str, Any]]]:
    """One data directory with a job of each family (about 30 s on 2 cores)."""
    root = tmp_path_factory.mktemp("datasets") / "data"
    return root, {k: matforge.run(spec, root) for k, spec in SPECS.items()}


def raw(root: Path, job: dict[str, Any], name: str) -> bytes:
    """An artifact's bytes straight from the store (no reader code)."""
    (digest,) = [a["digest"] for a in job["artifacts"] if a["name"] == name]
    return ArtifactStore(Settings.from_env({}).with_(data_dir=root).store_dir).read(digest)


def raw_npz(root: Path, job: dict[str, Any], name: str) -> dict[str, np.ndarray]:
    with np.load(io.BytesIO(raw(root, job, name))) as z:
        return {k: z[k] for k in z.files}


def test01_open_dispatches_on_kind(data) -> None:
    root, jobs = data
    kinds = {"merl": datasets.MerlCollection, "glint": datasets.GlintExample,
             "btf": datasets.BtfSlices, "fabric": datasets.FabricQueries}  # fmt: skip
    for key, cls in kinds.items():
        job_id = jobs[key]["id"]
        for ref in (job_id, f"job:{job_id}", job_id[:10], f"job:{job_id}/materials.json"):
            reader = datasets.open(ref, data_dir=root)
            assert type(reader) is cls and reader.job_id == job_id


def test02_fabric_queries(data) -> None:
    root, jobs = data
    job = jobs["fabric"]
    fq = datasets.open(job["id"], data_dir=root)
    doc = json.loads(raw(root, job, "materials.json"))
    assert fq.names == [m["name"] for m in doc["materials"]] and len(fq.names) == 2
    assert fq.components == ["C_warp", "C_weft", "S_warp", "S_weft"]
    shards = sorted(n for n in (a["name"] for a in job["artifacts"]) if n.startswith("shard-"))
    expect = [raw_npz(root, job, s) for s in shards]
    got = fq.numpy()
    assert len(fq) == 128
    for key in ("material", "center", "size", "wi", "wo", "value", "stderr"):
        np.testing.assert_array_equal(got[key], np.concatenate([e[key] for e in expect]))
    for i, m in enumerate(doc["materials"]):
        assert fq.params(m["name"]) == m["params"]
        mine = fq.material(m["name"])
        theirs = [raw_npz(root, job, s) for s in m["shards"]]
        np.testing.assert_array_equal(mine["value"], np.concatenate([t["value"] for t in theirs]))
        assert (mine["material"] == i).all()
    ds = fq.torch_dataset(materials=[fq.names[1]])
    assert len(ds) == 64
    loader = DataLoader(ds, batch_size=16, shuffle=False)
    batches = list(loader)
    assert len(batches) == 4 and batches[0]["value"].shape == (16, 4)
    second = fq.material(fq.names[1])
    np.testing.assert_array_equal(
        torch.cat([b["stderr"] for b in batches]).numpy(), second["stderr"]
    )
    assert batches[0]["material"].dtype == torch.int64 and (batches[0]["material"] == 1).all()
    everything = fq.torch_dataset()
    assert len(everything) == 128
    seen = torch.cat([b["value"] for b in DataLoader(everything, batch_size=40, num_workers=1)])
    np.testing.assert_array_equal(seen.numpy(), got["value"])  # a worker re-opens the maps


def test03_btf_slices(data) -> None:
    root, jobs = data
    job = jobs["btf"]
    btf = datasets.open(job["id"], data_dir=root)
    index = json.loads(raw(root, job, "btf.json"))
    parts = [raw_npz(root, job, s["name"]) for s in index["shards"]]
    rgb = np.concatenate([p["rgb"] for p in parts])
    wi = np.concatenate([p["wi"] for p in parts])
    wo = np.concatenate([p["wo"] for p in parts])
    assert len(btf) == 4 and btf.resolution == (8, 8) and len(index["shards"]) == 2
    np.testing.assert_array_equal(btf.wi, wi)
    np.testing.assert_array_equal(btf.wo, wo)
    for k in range(4):
        s = btf.slice(k)
        assert isinstance(s.base, np.memmap) or isinstance(s, np.memmap)  # mapped, not loaded
        np.testing.assert_array_equal(s, rgb[k])
        np.testing.assert_array_equal(btf.lookup(wi[k], wo[k]), rgb[k])
        # a pair a little off a measured one still finds it (nearest, no interpolation)
        assert btf.nearest(wi[k] + [0.01, -0.01, 0.0], wo[k] * 2.0) == k
    np.testing.assert_array_equal(btf.numpy()["rgb"], rgb)
    uv = np.array([[0.0, 0.0], [0.99, 0.51], [0.3, 0.7]])
    x, y = np.floor(uv[:, 0] * 8).astype(int), np.floor(uv[:, 1] * 8).astype(int)
    np.testing.assert_array_equal(btf.texels(uv, slices=[3, 1]), rgb[[3, 1]][:, y, x])
    with pytest.raises(IndexError, match="4 slices"):
        btf.slice(4)
    ds = btf.torch_dataset(length=200, seed=7)
    again = btf.torch_dataset(length=200, seed=7)
    other = btf.torch_dataset(length=200, seed=8)
    items = [ds[i] for i in range(200)]
    assert all(torch.equal(a["rgb"], again[i]["rgb"]) for i, a in enumerate(items))
    assert any(not torch.equal(a["uv"], other[i]["uv"]) for i, a in enumerate(items))
    for it in items:
        k = int(it["slice"])
        xx, yy = (it["uv"].numpy() * 8 - 0.5).round().astype(int)
        np.testing.assert_array_equal(it["rgb"].numpy(), rgb[k, yy, xx])
        np.testing.assert_array_equal(it["wi"].numpy(), wi[k])
    assert {int(it["slice"]) for it in items} == {0, 1, 2, 3}
    loader = DataLoader(ds, batch_size=50, shuffle=True, num_workers=1)
    total = sum(b["rgb"].shape[0] for b in loader)  # a worker process re-opens the maps
    assert total == 200


def test04_merl_collection(data) -> None:
    root, jobs = data
    job = jobs["merl"]
    coll = datasets.open(job["id"], data_dir=root)
    doc = json.loads(raw(root, job, "materials.json"))
    assert coll.names == [m["name"] for m in doc["materials"]] and len(coll) == 2
    assert {coll.family(n) for n in coll} == {"metal", "paint"}
    scales = np.array([1 / 1500, 1.15 / 1500, 1.66 / 1500])
    for m in doc["materials"]:
        mat = coll[m["name"]]
        assert mat.family == m["family"] and mat.source == m["source"]
        assert mat.params == m["params"] and mat.truth is None
        data_bytes = raw(root, job, f"{m['name']}.binary")
        dims = struct.unpack("<3i", data_bytes[:12])
        planes = np.frombuffer(data_bytes[12:], "<f8").reshape(3, *dims)
        expect = np.moveaxis(planes, 0, -1) * scales  # Matusik et al.'s layout, decoded here
        np.testing.assert_array_equal(mat.rgb, expect)
        assert m["name"] in coll and coll.numpy()[m["name"]] is mat.rgb
    with pytest.raises(KeyError, match="no material 'gold'"):
        coll["gold"]
    ds = coll.torch_dataset(pairs=256, seed=1)
    assert len(ds) == 512
    for i in (0, 300, 511):
        it = ds[i]
        rgb = coll[coll.names[int(it["material"])]].rgb
        expect = lookup(rgb, it["wi"].double().numpy()[None], it["wo"].double().numpy()[None],
                        interpolate=True)[0]  # fmt: skip
        # float32 directions and targets: agreement to float32 rounding of both
        np.testing.assert_allclose(it["rgb"].numpy(), expect, rtol=1e-4, atol=1e-6)
        assert it["wi"][2] > 0 and it["wo"][2] > 0
    batch = next(iter(DataLoader(ds, batch_size=64, shuffle=True)))
    assert batch["rgb"].shape == (64, 3) and batch["wi"].shape == (64, 3)


def test05_glint_example(data) -> None:
    root, jobs = data
    job = jobs["glint"]
    g = datasets.open(job["id"], data_dir=root)
    nd = raw_npz(root, job, "ndf.npz")
    lobes = raw_npz(root, job, "lobes.npz")
    tmp = root.parent / "example.exr"
    tmp.write_bytes(raw(root, job, "example.exr"))
    np.testing.assert_array_equal(g.example, read_exr(tmp))
    assert g.size == 8 and len(g.levels) == 3  # log2(8) levels
    for i, level in enumerate(g.levels):
        np.testing.assert_array_equal(level, nd[f"level_{i}"])
        assert level.shape == (8 // 2 ** (i + 1),) * 2 + (16, 16)
    assert g.sigma_r == float(nd["sigma_r"]) and g.extent == float(nd["extent"])
    assert set(g.lobes) == set(lobes)
    np.testing.assert_array_equal(g.lobes["u"], lobes["u"])
    ds = g.torch_dataset()
    assert len(ds) == sum(x.size for x in g.levels)
    first_l1 = g.levels[0].size
    it = ds[first_l1 + 5]  # level 1, flat index 5 in [ty, tx, iy, ix] order
    ty, tx, iy, ix = np.unravel_index(5, g.levels[1].shape)
    assert int(it["level"]) == 1 and float(it["density"]) == pytest.approx(
        float(g.levels[1][ty, tx, iy, ix]), rel=1e-7
    )
    edges = g.edges(1)
    assert float(it["s"][0]) == pytest.approx((edges[ix] + edges[ix + 1]) / 2, abs=1e-6)
    assert float(it["s"][1]) == pytest.approx((edges[iy] + edges[iy + 1]) / 2, abs=1e-6)
    assert float(it["footprint"]) == pytest.approx(0.5)  # level 1 of n = 8: 2 x 2 tiles
    n = sum(b["density"].shape[0] for b in DataLoader(ds, batch_size=1024))
    assert n == len(ds)


def test06_import_btf_reads_as_btf(data, tmp_path: Path) -> None:
    root, jobs = data
    btf = datasets.open(jobs["btf"]["id"], data_dir=root)
    angles = btf.index["directions"]
    folder = tmp_path / "scan"
    (folder / "images").mkdir(parents=True)
    lines = ["file,theta_i,phi_i,theta_o,phi_o"]
    for k, a in enumerate(angles):
        (folder / f"images/s{k}.exr").write_bytes(exr_bytes(np.array(btf.slice(k))))
        lines.append(",".join([f"images/s{k}.exr", *map(str, a)]))
    (folder / "angles.csv").write_text("\n".join(lines) + "\n")
    settings = Settings.from_env({}).with_(data_dir=root)
    jobs_db = JobStore(settings.db_path)
    try:
        rec = import_file(pack_folder(folder, tmp_path / "scan.btf.zip"), jobs_db,
                          ArtifactStore(settings.store_dir))  # fmt: skip
    finally:
        jobs_db.close()
    doc = matforge.run({"kind": "import.btf", "params": {"archive": f"sha256:{rec.digest}"}}, root)
    imported = datasets.open(doc["id"], data_dir=root)
    assert isinstance(imported, datasets.BtfSlices) and imported.kind == "import.btf"
    np.testing.assert_array_equal(imported.numpy()["rgb"], btf.numpy()["rgb"])
    assert np.isnan(imported.stderr).all()  # measured slices: unknown error


def test07_errors_name_what_is_wrong(data, tmp_path: Path) -> None:
    root, jobs = data
    with pytest.raises(NotFoundError):
        datasets.open("0" * 32, data_dir=root)
    with pytest.raises(ValueError, match="not a job"):
        datasets.open("sha256:" + "0" * 64, data_dir=root)
    with pytest.raises(FileNotFoundError, match="not a matforge data directory"):
        datasets.open(jobs["btf"]["id"], data_dir=tmp_path / "empty")
    with pytest.raises(ValueError, match="data_dir or client"):
        datasets.open(jobs["btf"]["id"], data_dir=root, client=object())
    with pytest.raises(ValueError, match="FabricQueries reads generate.fabric"):
        datasets.FabricQueries(datasets.open(jobs["btf"]["id"], data_dir=root).source)
    # a damaged object in the store is refused, never read
    job = jobs["glint"]
    (digest,) = [a["digest"] for a in job["artifacts"] if a["name"] == "ndf.npz"]
    path = ArtifactStore(Settings.from_env({}).with_(data_dir=root).store_dir).path(digest)
    good = path.read_bytes()
    path.chmod(0o644)
    try:
        path.write_bytes(good[:-1] + bytes([good[-1] ^ 1]))
        with pytest.raises(IntegrityError):
            datasets.open(job["id"], data_dir=root)
    finally:
        path.write_bytes(good)
        path.chmod(0o444)


EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def load_example(name: str) -> Any:
    """An ``examples/`` script as a module (they import their ``common`` sibling)."""
    import importlib.util
    import sys

    sys.path.insert(0, str(EXAMPLES))
    try:
        spec = importlib.util.spec_from_file_location(f"example_{name}", EXAMPLES / f"{name}.py")
        assert spec and spec.loader
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
    finally:
        sys.path.remove(str(EXAMPLES))
    return mod


@pytest.mark.parametrize("family", ["merl", "btf", "fabric", "glint"])
def test08_examples_train_from_the_datasets(data, family: str) -> None:
    """The proof of issue 22: each example trains a small torch model from
    ``matforge.datasets`` alone, on the dataset its own spec makes, and its loss falls."""
    root, jobs = data
    example = load_example(f"train_{family}")
    assert example.SPEC == SPECS[family]  # the fixture ran the example's own spec
    torch.manual_seed(0)
    first, last = example.train(datasets.open(jobs[family]["id"], data_dir=root), steps=150)
    # training works: the loss of the last 20 steps is well below that of the first 20
    assert last < 0.7 * first, (first, last)
