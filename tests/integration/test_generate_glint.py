"""``generate.glint`` through the registry: the contract's spec, the artifact layout, the
identities the maps must keep, determinism, and user normal maps (good and malformed).

References: the layout in ``../shared/CONTRACT.md``; the identities of Eq. 2 (each level
the mean of its children, masses at most 1); a user's upload of the very example the
procedural generator made must give the same NDF maps, byte for byte.
"""

from __future__ import annotations

import io
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from service.api import create_app
from service.settings import Settings
from service.submission import import_file, run_in_process
from storage.artifacts import ArtifactStore
from storage.errors import FormatError
from storage.formats.exr import exr_bytes
from storage.jobs import Job, JobStore
from tests.helpers.manifests import measured

SPEC = {
    "kind": "generate.glint",
    "seed": 3,
    "params": {
        "example": {"procedural": "isotropic_noise", "size": 16},
        "sigma_r": 0.02,
        "ndf_resolution": 32,
    },
}


def art(settings: Settings, job: Job, name: str) -> bytes:
    (digest,) = [a.digest for a in job.artifacts if a.name == name]
    return ArtifactStore(settings.store_dir).read(digest)


def npz(settings: Settings, job: Job, name: str) -> dict[str, np.ndarray]:
    with np.load(io.BytesIO(art(settings, job, name))) as z:
        return {k: z[k] for k in z.files}


def test01_contract_spec(settings: Settings) -> None:
    job = run_in_process(SPEC, settings)
    assert job.state == "succeeded", job.error
    names = {a.name for a in job.artifacts}
    assert names == {"example.exr", "ndf.npz", "lobes.npz", "preview.png", "stats.json"}
    nd = npz(settings, job, "ndf.npz")
    e, r = float(nd["extent"]), 32
    assert float(nd["sigma_r"]) == pytest.approx(0.02)
    levels = sorted(k for k in nd if k.startswith("level_"))
    assert levels == [f"level_{i}" for i in range(4)]
    for i, key in enumerate(levels):
        t = 16 >> (i + 1)
        assert nd[key].shape == (t, t, r, r) and nd[key].dtype == np.float32
        mass = nd[key].astype(np.float64).sum(axis=(-1, -2)) * (2 * e / r) ** 2
        assert mass.max() <= 1.0 + 1e-5 and mass.min() > 0.99
    for child, parent in zip(levels[:-1], levels[1:], strict=True):
        c, p = nd[child].astype(np.float64), nd[parent].astype(np.float64)
        t = p.shape[0]
        mean = c.reshape(t, 2, t, 2, r, r).mean(axis=(1, 3))
        assert np.abs(p - mean).max() <= 1e-6 * p.max()  # float32 rounding of both sides
    lob = npz(settings, job, "lobes.npz")
    assert lob["u"].shape == (16 * 16 * 4, 2) and lob["jacobian"].shape == (1024, 2, 2)
    stats = json.loads(art(settings, job, "stats.json"))
    assert stats["bytes"]["total"] == stats["bytes"]["ndf_maps"] + stats["bytes"]["lobes"]
    assert stats["bytes"]["ndf_maps"] == sum(nd[k].nbytes for k in levels)
    assert 0 < stats["memory_ratio"] < 0.05
    # The precompute time is a timing: in the manifest, not in stats.json.
    assert "precompute_seconds" not in stats
    assert measured(settings, job)["precompute_seconds"] > 0
    assert art(settings, job, "preview.png")[:8] == b"\x89PNG\r\n\x1a\n"


def test02_deterministic(settings: Settings) -> None:
    a = run_in_process(SPEC, settings)
    b = run_in_process({**SPEC, "force": True}, settings)
    assert a.id != b.id
    for name in ("example.exr", "ndf.npz", "lobes.npz", "preview.png", "stats.json"):
        assert art(settings, a, name) == art(settings, b, name), name


def test03_uploaded_example_gives_the_same_maps(settings: Settings, tmp_path: Path) -> None:
    """The procedural example, uploaded as a normal map, gives identical NDF maps."""
    job = run_in_process(SPEC, settings)
    extent = json.loads(art(settings, job, "stats.json"))["extent"]  # float64, not the npz f32
    path = tmp_path / "mine.normal.exr"
    path.write_bytes(art(settings, job, "example.exr"))
    jobs = JobStore(settings.db_path)
    try:
        rec = import_file(path, jobs, ArtifactStore(settings.store_dir))
    finally:
        jobs.close()
    params = {
        "example": {"normal_map": f"sha256:{rec.digest}"},
        "sigma_r": 0.02,
        "ndf_resolution": 32,
        "extent": extent,
    }
    mine = run_in_process({"kind": "generate.glint", "params": params}, settings)
    assert mine.state == "succeeded", mine.error
    assert art(settings, mine, "ndf.npz") == art(settings, job, "ndf.npz")


def _bad_map(tmp_path: Path) -> Path:
    normals = np.zeros((8, 8, 3), np.float32)
    normals[..., 2] = 1.0
    normals[3, 5] = (0.5, 0.5, 0.5)  # not unit length
    path = tmp_path / "bad.normal.exr"
    path.write_bytes(exr_bytes(normals))
    return path


def test04_malformed_upload_is_refused(settings: Settings, tmp_path: Path) -> None:
    path = _bad_map(tmp_path)
    jobs = JobStore(settings.db_path)
    try:
        with pytest.raises(FormatError, match=r"bad\.normal\.exr.*unit length.*x=5, y=3"):
            import_file(path, jobs, ArtifactStore(settings.store_dir))
    finally:
        jobs.close()
    with TestClient(create_app(settings)) as client:
        r = client.post("/api/artifacts?name=bad.normal.exr", content=path.read_bytes())
        assert r.status_code == 422 and "bad.normal.exr" in r.json()["error"]
    cli = [sys.executable, "-c", "from service.cli import main; main()"]
    done = subprocess.run(
        [*cli, "import", str(path), "--data-dir", str(settings.data_dir)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 2 and "unit length" in done.stderr, done.stderr


def test05_bad_params_are_refused_before_queueing(settings: Settings) -> None:
    from jobapi.errors import SpecError
    from service.specs import validate_spec

    for params, field in (
        ({"example": {"procedural": "wood", "size": 16}}, "params.example"),
        ({"example": {"procedural": "leather", "size": 12}}, "params.example"),
        ({"example": {"procedural": "leather"}, "sigma_r": 0.0}, "params.sigma_r"),
        ({"example": {"normal_map": "x.exr"}}, "params.example"),
    ):
        with pytest.raises(SpecError) as err:
            validate_spec({"kind": "generate.glint", "params": params})
        assert field in str(err.value), (params, err.value)


def test06_rest_submission_and_summary(settings: Settings) -> None:
    """The contract's spec through REST: 201, a worker runs it, the summary has the memory
    ratio of stats.json."""
    from service.workers.worker import run_worker

    with TestClient(create_app(settings)) as client:
        r = client.post("/api/jobs", json=SPEC)
        assert r.status_code == 201, r.text
        job_id = r.json()["id"]
        assert run_worker(settings, max_jobs=1) == 1
        doc = client.get(f"/api/jobs/{job_id}").json()
        assert doc["state"] == "succeeded", doc.get("error")
        table = client.get(f"/api/jobs/{job_id}/summary").json()
        (row,) = table["rows"].values()
        jobs = JobStore(settings.db_path)
        try:
            stats = json.loads(art(settings, jobs.get(job_id), "stats.json"))
        finally:
            jobs.close()
        assert row["memory_ratio"] == stats["memory_ratio"]  # the same stored value
        assert "precompute_seconds" not in row  # a timing: the manifest's, in the rows
        rows = client.get("/api/results", params={"kind": "generate.glint"}).json()
        (timed,) = [r for r in rows if r["job"] == job_id and r["metric"] == "precompute_seconds"]
        assert timed["value"] > 0


def test05_crop_is_the_examples_own_texels(settings: Settings, tmp_path: Path) -> None:
    """``crop``: the example's top-left texels (read back from both jobs' example.exr), its
    lobes only; a crop larger than the example is refused when the spec is checked."""
    from storage.formats.exr import read_exr

    whole = run_in_process(SPEC, settings)
    spec = {**SPEC, "params": {**SPEC["params"], "crop": 8}}
    part = run_in_process(spec, settings)
    assert part.state == "succeeded", part.error
    arrays = {}
    for name, job in (("whole", whole), ("part", part)):
        path = tmp_path / f"{name}.exr"
        path.write_bytes(art(settings, job, "example.exr"))
        arrays[name] = read_exr(path, name)
    assert arrays["part"].shape == (8, 8, 3)
    assert np.array_equal(arrays["part"], arrays["whole"][:8, :8])
    stats = json.loads(art(settings, part, "stats.json"))
    assert stats["example"] == {"size": 8, "type": "isotropic_noise", "cropped_from": 16}
    assert stats["lobes"] == 8 * 8 * 4 and stats["levels"] == 3
    from jobapi.errors import SpecError

    with pytest.raises(SpecError, match="crop 32 is larger than the example"):
        run_in_process({**SPEC, "params": {**SPEC["params"], "crop": 32}}, settings)
