"""``train.brdf`` through the registry: a tiny generate.merl collection, every model type.

Oracles: the portable numpy evaluator against the stored checkpoint; the shape of the
documented artifacts; byte-identical artifacts for the same spec; the divergence guard;
network weights left untouched by ``freeze_network``; held-out families fitted in a second
phase. Steps are few: these tests check plumbing, not quality (the benchmark does that).
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from evaluators.metrics.brdf import direction_pairs
from jobapi.errors import SpecError
from models.brdf.portable import FORMAT, eval_portable, load_checkpoint
from service.settings import Settings
from service.submission import run_in_process
from storage.artifacts import ArtifactStore
from storage.jobs import Job
from tests.helpers.manifests import measured

ARTIFACTS = {"model.pt", "model.json", "materials.json", "curves.json", "curves.png",
             "metrics.json"}  # fmt: skip
TINY = {"steps": 12, "batch_pairs": 64, "eval_pairs": 2048, "width": 16, "depth": 2,
        "speed": "off"}  # fmt: skip
#: The cheapest speed timing: the trained size and analytic, 4096 pairs per measurement.
TIMED = {"speed": "trained", "speed_batch": 4096}


@pytest.fixture(scope="module")
def brdf_env(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Settings, str]]:
    """Settings over one data directory holding a 3-material generate.merl job."""
    data = tmp_path_factory.mktemp("train_brdf")
    settings = Settings.from_env({}).with_(
        data_dir=Path(data) / "data", lease_seconds=30.0, pool_processes=1
    )
    families = {"metal": 1, "plastic": 1, "iridescent": 1}
    job = run_in_process(
        {"kind": "generate.merl", "seed": 1, "params": {"collection": {"families": families}}},
        settings,
    )
    assert job.state == "succeeded", job.error
    yield settings, job.id


def train(settings: Settings, params: dict[str, Any], force: bool = False) -> Job:
    return run_in_process(
        {"kind": "train.brdf", "seed": 3, "params": params, "force": force}, settings
    )


def read(settings: Settings, job: Job, name: str) -> bytes:
    (digest,) = [a.digest for a in job.artifacts if a.name == name]
    return ArtifactStore(settings.store_dir).read(digest)


def read_json(settings: Settings, job: Job, name: str) -> Any:
    return json.loads(read(settings, job, name))


@pytest.mark.parametrize("model", ["hybrid", "neural", "analytic"])
def test01_each_model_trains_and_its_artifacts_agree(
    brdf_env: tuple[Settings, str], model: str
) -> None:
    settings, gen = brdf_env
    params = {**TINY, **TIMED, "model": model, "dataset": f"job:{gen}"}
    if model == "analytic":
        params = {k: v for k, v in params.items() if k not in ("width", "depth")}
    job = train(settings, params)
    assert job.state == "succeeded", job.error
    # Timings are not artifacts (same spec, same bytes): the manifest keeps them.
    assert {a.name for a in job.artifacts} == ARTIFACTS
    speed = measured(settings, job)["speed"]
    assert speed["format"] == "matforge.speed/1" and speed["mode"] == "trained"
    assert speed["batch"] == 4096
    trained, analytic = speed["rows"]  # the trained size, then the analytic baseline
    assert trained["trained"] is True and trained["model"] == model
    assert analytic["model"] == "analytic"
    assert trained["size"] == ("-" if model == "analytic" else "16x2")
    for row in speed["rows"]:
        assert row["fused_ns"] > 0 and row["fused_kernel_ns"] > 0 and row["torch_ns"] > 0
        assert row["fused_cpu_ns"] > 0
    # FLOP per evaluation, counted by hand from the architecture (16x2: 16-wide layers, one
    # 16x16 matrix between them; the 6 direction inputs live, the latent folded into the
    # bias): 2 per multiply-add. The hybrid has 6 outputs, the neural model 3, analytic none.
    outputs = {"hybrid": 6, "neural": 3, "analytic": 0}[model]
    expected = 0 if model == "analytic" else 2 * (6 * 16 + 16 * 16 + 16 * outputs)
    assert trained["flops"] == expected
    assert (trained["gflops_per_core"] is None) == (model == "analytic")
    # Bytes: 4 per float; the per-material count is materials.json's.
    floats = {"hybrid": 11, "neural": 11, "analytic": 7}[model]
    assert trained["bytes_per_material"] == 4 * floats
    assert (trained["bytes_per_network"] > 0) == (model != "analytic")
    doc = read_json(settings, job, "model.json")
    assert doc["format"] == FORMAT and doc["model"] == model
    torch_model, names, _ = load_checkpoint(read(settings, job, "model.pt"))
    assert names == [m["name"] for m in doc["materials"]]
    wi, wo = direction_pairs(500, seed=11)
    for i, name in enumerate(names):
        with torch.no_grad():
            f = torch_model(torch.from_numpy(wi).float()[None], torch.from_numpy(wo).float()[None],
                            torch.tensor([i])).f[0].double().numpy()  # fmt: skip
        np.testing.assert_allclose(eval_portable(doc, name, wi, wo), f, rtol=1e-4, atol=1e-7)
    metrics = read_json(settings, job, "metrics.json")
    assert [r["name"] for r in metrics["materials"]] == names
    for row in metrics["materials"]:
        assert 0.0 <= row["smape"] <= 2.0 and row["mae"] >= 0.0 and row["split"] == "train"
        assert (row["smape_analytic"] is None) == (model == "neural")
        # The floored variant only lowers terms below its floor, never raises one.
        assert 0.0 <= row["smape_floor"] <= row["smape"] + 1e-12
        assert (row["smape_floor_analytic"] is None) == (model == "neural")
    assert set(metrics["families"]) == {"metal", "plastic", "iridescent"}
    assert metrics["mean"]["count"] == 3 and metrics["settings"]["pairs"] == 2048
    mats = read_json(settings, job, "materials.json")
    assert mats["per_material_params"] == {"hybrid": 11, "neural": 11, "analytic": 7}[model]
    curves = read_json(settings, job, "curves.json")
    # one schema (jobapi.documents): series at the top level against step, one phase here
    assert curves["step"][-1] == TINY["steps"] and len(curves["loss"]) == len(curves["step"])
    assert curves["phases"] == [{"name": "train", "first_step": 1, "last_step": TINY["steps"]}]
    # a series no point measures is left out (an analytic model has no network term)
    assert ("loss_hybrid" in curves) == (model != "analytic")
    assert ("loss_analytic" in curves) == (model != "neural")
    assert read(settings, job, "curves.png")[:8] == b"\x89PNG\r\n\x1a\n"


def test02_same_spec_same_bytes(brdf_env: tuple[Settings, str]) -> None:
    settings, gen = brdf_env
    params = {**TINY, **TIMED, "dataset": f"job:{gen}", "latent_dim": 8}
    first = train(settings, params)
    again = train(settings, params, force=True)
    assert first.state == again.state == "succeeded", (first.error, again.error)
    assert first.id != again.id
    # The speed timings (which vary) are in the manifests, so every artifact is the same.
    one, two = ({a.name: a.digest for a in j.artifacts} for j in (first, again))
    assert one == two and set(one) == ARTIFACTS
    assert measured(settings, first)["speed"]["rows"] and measured(settings, again)["speed"]


def test03_divergence_fails_the_job_with_a_clear_error(brdf_env: tuple[Settings, str]) -> None:
    settings, gen = brdf_env
    job = train(settings, {**TINY, "model": "neural", "dataset": f"job:{gen}", "lr": 1e4,
                           "clip": 1e6})  # fmt: skip
    assert job.state == "failed"
    assert job.error is not None and "training diverged at step" in job.error
    assert "Lower lr" in job.error and not job.artifacts


def test04_init_with_frozen_network_fits_only_z_and_p(brdf_env: tuple[Settings, str]) -> None:
    settings, gen = brdf_env
    base = train(settings, {**TINY, "dataset": f"job:{gen}", "holdout_families": ["metal"]})
    assert base.state == "succeeded", base.error
    assert {a.name for a in base.artifacts} == ARTIFACTS
    assert "speed" not in measured(settings, base)  # speed: off
    metrics = read_json(settings, base, "metrics.json")
    assert metrics["splits"]["heldout"]["count"] == 1 and metrics["splits"]["train"]["count"] == 2
    curves = read_json(settings, base, "curves.json")
    # the held-out phase's steps follow the training phase's
    assert [p["name"] for p in curves["phases"]] == ["train", "heldout"]
    assert curves["phases"][1] == {
        "name": "heldout",
        "first_step": TINY["steps"] + 1,
        "last_step": 2 * TINY["steps"],
    }
    assert curves["step"][-1] == 2 * TINY["steps"]
    old = read_json(settings, base, "model.json")
    table = next(m["ref"] for m in old["training"]["materials"] if m["family"] == "plastic")
    for init in ("model.json", "model.pt"):
        job = train(settings, {"dataset": [table], "init": f"job:{base.id}/{init}",
                               "freeze_network": True, "steps": 12, "batch_pairs": 64,
                               "eval_pairs": 2048})  # fmt: skip
        assert job.state == "succeeded", job.error
        new = read_json(settings, job, "model.json")
        assert new["network"] == old["network"]  # bit for bit
        (mat,) = new["materials"]
        before = next(m for m in old["materials"] if m["name"] == mat["name"])
        assert mat["z"] != before["z"]  # started from the init's z and moved


def test05_bad_inputs_are_refused_clearly(brdf_env: tuple[Settings, str]) -> None:
    settings, gen = brdf_env
    with pytest.raises(SpecError, match="freeze_network needs init"):
        train(settings, {"dataset": f"job:{gen}", "freeze_network": True})
    with pytest.raises(SpecError, match="dataset"):
        train(settings, {"dataset": f"job:{gen}/materials"})
    with pytest.raises(SpecError, match="analytic model has no network"):
        train(settings, {"dataset": f"job:{gen}", "model": "analytic", "width": 16})
    job = train(settings, {**TINY, "dataset": "job:" + "0" * 32})
    assert job.state == "failed" and job.error == f"dataset: no job {'0' * 32}"
    job = train(settings, {**TINY, "dataset": f"job:{gen}", "holdout_families": ["velvet"]})
    assert job.state == "failed" and job.error is not None
    assert "no material of family velvet" in job.error


def test06_live_curves_through_both_phases(
    brdf_env: tuple[Settings, str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Issue 26 §1: train.brdf publishes its curves as it trains, as train.fabric and
    train.btf do, in the one curves.json schema (publish checks it), the held-out phase's
    points following the training phase's; the last publication is the artifact's curves."""
    from jobapi.context import JobContext

    published: list[dict[str, Any]] = []
    original = JobContext.publish

    def spy(self: JobContext, name: str, obj: Any, *, min_interval_s: float = 1.0) -> bool:
        if name == "curves.json":
            published.append(json.loads(json.dumps(obj)))
        return original(self, name, obj, min_interval_s=min_interval_s)

    monkeypatch.setattr(JobContext, "publish", spy)
    settings, gen = brdf_env
    params = {**TINY, "dataset": f"job:{gen}", "holdout_families": ["metal"], "lr": 0.004}
    job = train(settings, params)
    assert job.state == "succeeded", job.error
    assert len(published) == 2 * TINY["steps"]  # one per point; every step is a point here
    assert [len(d["step"]) for d in published] == list(range(1, 2 * TINY["steps"] + 1))
    assert [p["name"] for p in published[TINY["steps"]]["phases"]] == ["train", "heldout"]
    assert published[-1] == read_json(settings, job, "curves.json")
