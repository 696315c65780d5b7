"""``render`` with ``{"fabric": {...}}``: a woven fabric renders end to end through the runner.

Through :func:`service.submission.run_in_process` (spec validation, worker code, store) at
a tiny size. Oracles: the job succeeds with the fixed artifacts; ``render.json`` records the
footprint integrator and the fully validated material; the image is finite and lit, and
shows the weave (pixel-to-pixel contrast far above what the Monte Carlo noise of a flat
material gives); rendering again with ``"force": true`` gives the same bytes; bad specs
are refused before queueing with a message naming the field.
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import pytest

from jobapi.errors import SpecError
from service.settings import Settings
from service.submission import import_file, run_in_process
from storage.artifacts import ArtifactStore
from storage.formats.exr import read_exr
from storage.jobs import JobStore
from tests.helpers.fabric_models import TRAINED, record_of, write_model

FABRIC = {
    "pattern": "twill_3x3",
    "alpha": 0.3,
    "beta": 0.8,
    "kd_warp": [0.7, 0.2, 0.15],
    "kd_weft": [0.2, 0.3, 0.6],
    "ks_warp": 0.6,
    "ks_weft": 0.6,
    "tiles_per_uv": 4,
}


def spec(material: dict[str, Any], **extra: Any) -> dict[str, Any]:
    params = {
        "scene": "cloth_plane",
        "material": material,
        "resolution": [48, 48],
        "spp": 4,
        "max_depth": 3,
    }
    return {"kind": "render", "seed": 3, "params": params, **extra}


def artifacts(settings: Settings, job: Any) -> dict[str, bytes]:
    store = ArtifactStore(settings.store_dir)
    return {a.name: store.path(a.digest).read_bytes() for a in job.artifacts}


def test01_fabric_renders(settings: Settings, mitsuba_llvm: None) -> None:
    job = run_in_process(spec({"fabric": FABRIC}), settings)
    assert job.state == "succeeded", job.error
    files = artifacts(settings, job)
    assert {"image.exr", "preview.png", "render.json"} <= set(files)
    meta = json.loads(files["render.json"])
    assert meta["integrator"] == "fabric_path"
    assert meta["material"]["fabric"]["visibility"] is True  # defaults filled in
    assert meta["environment"] == "matforge studio_envmap"
    store = ArtifactStore(settings.store_dir)
    (exr,) = [a for a in job.artifacts if a.name == "image.exr"]
    img = read_exr(store.path(exr.digest)).astype(np.float64)
    assert img.shape == (48, 48, 3) and np.all(np.isfinite(img))
    cloth = img[24:, :, :]  # the lower half of the frame is cloth (the far edge is higher)
    assert cloth.mean() > 0.05
    # The weave shows: warp (reddish) and weft (bluish) yarns alternate across the cloth.
    red_minus_blue = cloth[..., 0] - cloth[..., 2]
    assert red_minus_blue.max() > 0.1 and red_minus_blue.min() < -0.02

    again = run_in_process(spec({"fabric": FABRIC}, force=True), settings)
    assert again.state == "succeeded" and again.id != job.id
    assert artifacts(settings, again)["image.exr"] == files["image.exr"]


def test02_bad_specs_are_refused(settings: Settings) -> None:
    with pytest.raises(SpecError, match="unknown pattern 'twill9'; allowed: plain"):
        run_in_process(spec({"fabric": {"pattern": "twill9"}}), settings)
    with pytest.raises(SpecError, match=r"alpha must lie in \[0.02, 1.0\], got -0.5"):
        run_in_process(spec({"fabric": {"alpha": -0.5}}), settings)


def test03_network_renders(settings: Settings, tmp_path: Any, mitsuba_llvm: None) -> None:
    model_json, _, _ = write_model(tmp_path)
    jobs = JobStore(settings.db_path)
    try:
        ref = f"sha256:{import_file(model_json, jobs, ArtifactStore(settings.store_dir)).digest}"
    finally:
        jobs.close()
    record = record_of(TRAINED)
    fabric = {**record, "kd_warp": [0.7, 0.2, 0.15], "tiles_per_uv": 4}
    job = run_in_process(spec({"model": ref, "fabric": fabric}), settings)
    assert job.state == "succeeded", job.error
    files = artifacts(settings, job)
    assert json.loads(files["render.json"])["integrator"] == "fabric_path"
    store = ArtifactStore(settings.store_dir)
    (exr,) = [a for a in job.artifacts if a.name == "image.exr"]
    img = read_exr(store.path(exr.digest)).astype(np.float64)
    assert np.all(np.isfinite(img)) and img[24:].mean() > 0.01

    unknown = {**fabric, "alpha": 0.77}
    failed = run_in_process(spec({"model": ref, "fabric": unknown}), settings)
    assert failed.state == "failed"
    assert "carries no encoder" in str(failed.error) and "model.pt" in str(failed.error)
