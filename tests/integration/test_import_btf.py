"""``import.btf``: a folder of slice images with their angles, made by the project's own code
from a ``generate.btf`` job, round-trips into the same shards (EXR: bit for bit; PNG: to
8-bit sRGB quantisation); malformed folders are refused naming the file, at upload (CLI,
REST) and in the job.
"""

from __future__ import annotations

import csv
import json
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from evaluators.metrics.tonemap import quantize8, srgb_encode
from service.api import create_app
from service.settings import Settings
from service.submission import import_file, run_in_process
from storage.artifacts import ArtifactStore
from storage.errors import FormatError
from storage.formats.btf import parse_index, read_shard
from storage.formats.btf_folder import pack_folder
from storage.formats.exr import exr_bytes
from storage.formats.png import write_png
from storage.jobs import Job, JobStore

GEN = {"kind": "generate.btf", "seed": 4, "params": {
    "surface": {"procedural": "wood", "size": 8}, "resolution": 8, "spp": 2,
    "directions": [[0, 0, 0, 0], [30, 40, 60, 200], [60, 200, 30, 40], [75, 90, 10, 0]],
    "shard_slices": 3}}  # fmt: skip


def art(settings: Settings, job: Job, name: str) -> bytes:
    (digest,) = [a.digest for a in job.artifacts if a.name == name]
    return ArtifactStore(settings.store_dir).read(digest)


def all_slices(settings: Settings, job: Job, tmp: Path) -> tuple[np.ndarray, ...]:
    index = parse_index(art(settings, job, "btf.json"))
    tmp.mkdir(parents=True, exist_ok=True)
    parts = []
    for name, _ in index.shards:
        (tmp / name).write_bytes(art(settings, job, name))
        parts.append(read_shard(tmp / name, name))
    return tuple(np.concatenate([getattr(p, k) for p in parts]) for k in ("wi", "wo", "rgb"))


@pytest.fixture(scope="module")
def generated(tmp_path_factory: pytest.TempPathFactory) -> tuple[Settings, Job, tuple]:
    root = tmp_path_factory.mktemp("gen")
    settings = Settings.from_env({}).with_(data_dir=root / "data", pool_processes=1)
    job = run_in_process(GEN, settings)
    assert job.state == "succeeded", job.error
    return settings, job, all_slices(settings, job, root / "shards")


def write_folder(folder: Path, rgb: np.ndarray, angles: list, fmt: str, listing: str) -> None:
    (folder / "images").mkdir(parents=True)
    rows = []
    for k, (img, a) in enumerate(zip(rgb, angles, strict=True)):
        name = f"images/slice_{k:03d}.{fmt}"
        if fmt == "exr":
            (folder / name).write_bytes(exr_bytes(img))
        else:
            write_png(folder / name, quantize8(srgb_encode(np.clip(img * 4.0, 0, 1))))
        rows.append([name, *a])
    if listing == "csv":
        with open(folder / "angles.csv", "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(["file", "theta_i", "phi_i", "theta_o", "phi_o"])
            w.writerows(rows)
    else:
        keys = ("file", "theta_i", "phi_i", "theta_o", "phi_o")
        doc = {"slices": [dict(zip(keys, r, strict=True)) for r in rows]}
        (folder / "angles.json").write_text(json.dumps(doc))


def cli_import(path: Path, data_dir: Path) -> subprocess.CompletedProcess[str]:
    cli = [sys.executable, "-c", "from service.cli import main; main()"]
    return subprocess.run(
        [*cli, "import", str(path), "--data-dir", str(data_dir)],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip


def test01_exr_folder_round_trip(generated, tmp_path: Path) -> None:
    settings, job, (wi, wo, rgb) = generated
    angles = json.loads(art(settings, job, "btf.json"))["directions"]
    folder = tmp_path / "leather_scan"
    write_folder(folder, rgb, angles, "exr", "csv")
    done = cli_import(folder, settings.data_dir)  # the CLI packs the directory
    assert done.returncode == 0, done.stderr
    ref = done.stdout.strip()
    assert ref.startswith("sha256:")
    spec = {"kind": "import.btf", "params": {"archive": ref, "shard_slices": 3}}
    imported = run_in_process(spec, settings)
    assert imported.state == "succeeded", imported.error
    iwi, iwo, irgb = all_slices(settings, imported, tmp_path / "imported")
    np.testing.assert_array_equal(irgb, rgb)  # EXR float32 is lossless
    np.testing.assert_allclose(iwi, wi, atol=2e-6)  # angles stored to 1e-6 degrees
    np.testing.assert_allclose(iwo, wo, atol=2e-6)
    doc = json.loads(art(settings, imported, "btf.json"))
    assert doc["source"] == "import.btf" and doc["archive_name"] == "leather_scan.btf.zip"
    assert doc["files"][1] == "images/slice_001.exr"
    assert art(settings, imported, "preview.png")[:4] == b"\x89PNG"


def test02_png_folder_with_json_list(generated, tmp_path: Path) -> None:
    settings, job, (_, _, rgb) = generated
    angles = json.loads(art(settings, job, "btf.json"))["directions"]
    folder = tmp_path / "pngs"
    write_folder(folder, rgb, angles, "png", "json")
    packed = pack_folder(folder, tmp_path / "pngs.btf.zip")
    jobs = JobStore(settings.db_path)
    try:
        rec = import_file(packed, jobs, ArtifactStore(settings.store_dir))
    finally:
        jobs.close()
    spec = {"kind": "import.btf", "params": {"archive": f"sha256:{rec.digest}", "scale": 0.25}}
    imported = run_in_process(spec, settings)
    assert imported.state == "succeeded", imported.error
    _, _, irgb = all_slices(settings, imported, tmp_path / "imported")
    clipped = np.clip(rgb * 4.0, 0, 1) / 4.0
    # 8-bit sRGB: a step of 1/255 in the encoded value, at most ~1.3 % of the linear value
    # above 0.05 (and 0.0016 absolute near black, scaled by 1/4).
    np.testing.assert_allclose(irgb, clipped, rtol=0.013, atol=0.0004)


def _bad_folders(tmp_path: Path, rgb: np.ndarray, angles: list) -> list[tuple[Path, str]]:
    cases = []

    def make(tag: str) -> Path:
        f = tmp_path / tag
        write_folder(f, rgb, angles, "exr", "csv")
        return f

    f = make("missing")
    (f / "images/slice_002.exr").unlink()
    cases.append((f, r"images/slice_002.exr: listed in angles.csv but missing"))
    f = make("unlisted")
    (f / "images/extra.exr").write_bytes(exr_bytes(rgb[0]))
    cases.append((f, r"images/extra.exr: an image with no angles"))
    f = make("duplicate")
    lines = (f / "angles.csv").read_text().splitlines()
    # theta 0 at another phi is the same direction: a duplicate of slice_000's pair
    lines[2] = "images/slice_001.exr,0,90,0,45"
    (f / "angles.csv").write_text("\n".join(lines) + "\n")
    cases.append((f, r"images/slice_001.exr: duplicate angles: the same light and view as "
                     r"images/slice_000.exr"))  # fmt: skip
    f = make("size")
    (f / "images/slice_003.exr").write_bytes(exr_bytes(rgb[3][:4]))
    cases.append((f, r"images/slice_003.exr: is 8x4 pixels, but images/slice_000.exr is 8x8"))
    f = make("corrupt")
    (f / "images/slice_001.exr").write_bytes(b"v/1\x01garbage")
    cases.append((f, r"images/slice_001.exr: unreadable OpenEXR"))
    f = make("noangles")
    (f / "angles.csv").unlink()
    cases.append((f, r"needs exactly one angles.csv or angles.json"))
    f = make("range")
    lines = (f / "angles.csv").read_text().splitlines()
    lines[1] = "images/slice_000.exr,95,0,0,0"
    (f / "angles.csv").write_text("\n".join(lines) + "\n")
    cases.append((f, r"images/slice_000.exr: theta_i and theta_o must lie in \[0, 89\]"))
    return cases


def user_zip(folder: Path, zipped: Path) -> Path:
    """Zip ``folder`` as it is (no checks), as a user's own zip tool would."""
    with zipfile.ZipFile(zipped, "w") as zf:
        for p in sorted(folder.rglob("*")):
            if p.is_file():
                zf.write(p, p.relative_to(folder).as_posix())
    return zipped


def test03_malformed_folders_are_refused_naming_the_file(generated, tmp_path: Path) -> None:
    settings, job, (_, _, rgb) = generated
    angles = json.loads(art(settings, job, "btf.json"))["directions"]
    jobs = JobStore(settings.db_path)
    store = ArtifactStore(settings.store_dir)
    try:
        for folder, pattern in _bad_folders(tmp_path, rgb, angles):
            zipped = user_zip(folder, tmp_path / f"{folder.name}.btf.zip")
            with pytest.raises(FormatError, match=rf"{folder.name}\.btf\.zip: .*{pattern}"):
                import_file(zipped, jobs, store)
            done = cli_import(folder, settings.data_dir)  # the CLI packs, then validates
            assert done.returncode == 2 and folder.name in done.stderr, done.stderr
    finally:
        jobs.close()
    bad = tmp_path / "missing.btf.zip"
    with TestClient(create_app(settings)) as client:
        r = client.post("/api/artifacts?name=missing.btf.zip", content=bad.read_bytes())
        assert r.status_code == 422 and "slice_002.exr" in r.json()["error"]
