"""``scripts/glint_eval.yaml`` run through the job machinery at tiny sizes.

The batch file is loaded and validated as ``matforge batch`` does, then two of its example
types (scratches, structured) run through :func:`service.submission.run_in_process` with
their ``step:`` refs resolved, after shrinking: NDF images of 16 cells, renders of 32x24 at
4 (tiny) and 16 (reference) spp, 128 texels per uv.

Oracles: every metric is finite and in its range, the documented artifacts exist, and the
tiny-example render is closer to its own reference than to the other type's reference
(PSNR and SSIM), i.e. the scores see the microstructure.
"""

from __future__ import annotations

import json
import math
import types
from pathlib import Path
from typing import Any

import pytest

from service.cli.batch import load_batch, substitute_refs
from service.settings import Settings
from service.specs import STEP_REF
from service.submission import run_in_process
from storage.artifacts import ArtifactStore
from storage.jobs import Job

RECIPE = Path(__file__).resolve().parents[2] / "scripts" / "glint_eval.yaml"
TYPES = ("scratches", "structured")


def shrink(spec: dict[str, Any]) -> dict[str, Any]:
    params = dict(spec["params"])
    if spec["kind"] == "generate.glint":
        params["ndf_resolution"] = 16
    if spec["kind"] == "render":
        params.update(resolution=[32, 24], spp=4 if params["spp"] <= 64 else 16)
        material = dict(params["material"]["glint"])
        material["texels_per_uv"] = 128
        params["material"] = {"glint": material}
    return {**spec, "params": params}


@pytest.fixture(scope="module")
def chain(
    tmp_path_factory: pytest.TempPathFactory, mi: types.ModuleType
) -> tuple[Settings, dict[str, Job]]:
    settings = Settings.from_env({}).with_(
        data_dir=tmp_path_factory.mktemp("glint_eval") / "data", pool_processes=1
    )
    jobs: dict[str, Job] = {}
    batch = load_batch(RECIPE)
    assert [s.name for s in batch.steps][:4] == [
        "scratches", "scratches_tiny", "scratches_yan", "scratches_score",
    ]  # fmt: skip
    for step in batch.steps:
        if not step.name.startswith(TYPES):
            continue

        def resolve(ref: str) -> str:
            m = STEP_REF.match(ref)
            assert m is not None
            job = jobs[m["step"]]
            return f"job:{job.id}" if m["name"] is None else f"job:{job.id}/{m['name']}"

        job = run_in_process(shrink(substitute_refs(step.spec, resolve)), settings)
        assert job.state == "succeeded", (step.name, job.error)
        jobs[step.name] = job
    return settings, jobs


def _metrics(settings: Settings, job: Job) -> dict[str, float]:
    (digest,) = [a.digest for a in job.artifacts if a.name == "metrics.json"]
    return json.loads(ArtifactStore(settings.store_dir).read(digest))["metrics"]["tiny"]


def test01_recipe_runs_and_scores(chain: tuple[Settings, dict[str, Job]]) -> None:
    settings, jobs = chain
    for kind in TYPES:
        m = _metrics(settings, jobs[f"{kind}_score"])
        assert 0.0 <= m["flip"] <= 1.0 and -1.0 <= m["ssim"] <= 1.0
        assert math.isfinite(m["psnr"]) and m["psnr"] > 0.0
        names = {a.name for a in jobs[f"{kind}_score"].artifacts}
        assert names == {"metrics.json", "flip_tiny.png"}


def test02_scores_see_the_microstructure(chain: tuple[Settings, dict[str, Job]]) -> None:
    """Each tiny render against the other type's reference scores worse than against its
    own."""
    settings, jobs = chain
    own = {k: _metrics(settings, jobs[f"{k}_score"]) for k in TYPES}
    a, b = TYPES
    cross = run_in_process(
        {
            "kind": "score",
            "params": {
                "reference": f"job:{jobs[f'{b}_yan'].id}/image.exr",
                "candidates": {"tiny": f"job:{jobs[f'{a}_tiny'].id}/image.exr"},
                "metrics": ["psnr", "ssim"],
            },
        },
        settings,
    )
    assert cross.state == "succeeded", cross.error
    c = _metrics(settings, cross)
    # PSNR and SSIM; HDR-FLIP on 32x24 frames of 4 spp is dominated by noise and
    # the reference's exposure range, so it is only range-checked here.
    assert c["psnr"] < own[a]["psnr"] - 3.0 and c["ssim"] < own[a]["ssim"], (c, own[a])
