"""``render`` with ``{"model": REF, "material": NAME}``: a trained model's material renders.

End to end through the real runner (:func:`service.submission.run_in_process`): a
``model.json`` with random-but-plausible weights (:func:`make_model`) is imported into the
store (validated as JSON, as ``matforge import`` does) and the sphere is rendered with one
of its materials. Oracles: the image is finite and lit; an analytic model with the same
``kd``, ``eta``, ``alpha`` renders close to it but not identically (the network's
correction is visible); errors name the reference and the missing material.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import evaluators.render.sources.model  # noqa: F401  (registers the "model" source)
from jobapi.errors import SpecError
from service.settings import Settings
from service.submission import import_file, run_in_process
from storage.artifacts import ArtifactStore
from storage.formats.exr import read_exr
from storage.jobs import JobStore
from tests.helpers.brdf_models import make_model
from tests.helpers.renders import assert_same_render

SIZE, SPP, MAX_DEPTH = 32, 16, 4


def put_model(settings: Settings, tmp_path: Path, kind: str) -> str:
    path = tmp_path / f"{kind}.json"
    path.write_text(json.dumps(make_model(kind, 16, 2, 4 if kind == "hybrid" else 0)))
    jobs = JobStore(settings.db_path)
    try:
        record = import_file(path, jobs, ArtifactStore(settings.store_dir))
    finally:
        jobs.close()
    return f"sha256:{record.digest}"


def render(settings: Settings, material: dict[str, Any]) -> tuple[Any, np.ndarray | None]:
    params = {"material": material, "resolution": [SIZE, SIZE], "spp": SPP, "max_depth": MAX_DEPTH}
    job = run_in_process({"kind": "render", "seed": 1, "params": params}, settings)
    if job.state != "succeeded":
        return job, None
    (image,) = [a for a in job.artifacts if a.name == "image.exr"]
    return job, read_exr(ArtifactStore(settings.store_dir).path(image.digest)).astype(np.float64)


def test01_model_material_renders(settings: Settings, tmp_path: Path, mitsuba_llvm: None) -> None:
    hybrid = put_model(settings, tmp_path, "hybrid")
    analytic = put_model(settings, tmp_path, "analytic")
    job, img = render(settings, {"model": hybrid, "material": "gold"})
    assert job.state == "succeeded", job.error
    assert img is not None and np.all(np.isfinite(img)) and img.mean() > 0.01
    _, img_a = render(settings, {"model": analytic, "material": "gold"})
    assert img_a is not None
    rel = np.abs(img.mean() - img_a.mean()) / img_a.mean()
    print(f"\nmean radiance: hybrid {img.mean():.4f}, analytic {img_a.mean():.4f} ({rel:.1%})")
    assert 0.005 < rel < 1.0


def test02_errors_name_the_ref(settings: Settings, tmp_path: Path, mitsuba_llvm: None) -> None:
    hybrid = put_model(settings, tmp_path, "hybrid")
    job, _ = render(settings, {"model": hybrid, "material": "steel"})
    assert job.state == "failed"
    assert job.error == (
        f"material.model: {hybrid}: no material 'steel' in the model; it has gold, plastic, sharp"
    )
    with pytest.raises(SpecError, match="material: this key is required"):
        run_in_process({"kind": "render", "params": {"material": {"model": hybrid}}}, settings)
    with pytest.raises(SpecError, match="no such object in the store"):
        missing = {"model": "sha256:" + "0" * 64, "material": "gold"}
        run_in_process({"kind": "render", "params": {"material": missing}}, settings)
    neural = tmp_path / "neural.json"
    neural.write_text(json.dumps(make_model("neural", 16, 2, 11)))
    jobs = JobStore(settings.db_path)
    try:
        ref = f"sha256:{import_file(neural, jobs, ArtifactStore(settings.store_dir)).digest}"
    finally:
        jobs.close()
    job, _ = render(settings, {"model": ref, "material": "gold", "neural_max_depth": 1})
    assert job.state == "failed" and "neural_max_depth needs a hybrid model" in str(job.error)


def test03_neural_max_depth(settings: Settings, tmp_path: Path, mitsuba_llvm: None) -> None:
    hybrid = put_model(settings, tmp_path, "hybrid")
    _, full = render(settings, {"model": hybrid, "material": "gold"})
    job, first = render(settings, {"model": hybrid, "material": "gold", "neural_max_depth": 1})
    assert job.state == "succeeded", job.error
    # The convex sphere has no second hits: the network at first hits only is the full model.
    assert first is not None and full is not None
    assert_same_render(first, full)  # neural_depth against path: equal to rounding
    job, fa = render(settings, {"model": hybrid, "material": "gold", "neural_max_depth": 0})
    assert job.state == "succeeded" and fa is not None and not np.allclose(fa, full)
