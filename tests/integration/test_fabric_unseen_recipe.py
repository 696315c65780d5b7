"""``scripts/fabric_unseen.yaml`` at its smallest size: the dataset step on the
``unseen_small`` preset (cut to 128 queries x 16 samples), each of the three training seeds
as a tiny network for a few steps. Oracles: the recipe loads and runs as ``matforge batch``
would; every model reports the three splits with the materials the preset puts in them;
the seeds give different models (different initial weights and batches) on the same
held-out queries (the split is seeded by the material's name, not the job's seed)."""

from __future__ import annotations

import json
from typing import Any

import pytest

from tests.helpers.recipes import artifact, run_recipe

DATASET = {"preset": "unseen_small", "queries_per_material": 128, "shard_queries": 128,
           "samples": 16, "map_resolution": 16, "backend": "numpy"}  # fmt: skip
TRAIN = {"preset": "small", "encoder_width": 16, "decoder_width": 16, "map_resolution": 16,
         "steps": 3, "batch": 32, "materials_per_step": 1, "holdout": 0.25,
         "device": "cpu"}  # fmt: skip


def shrink(spec: dict[str, Any]) -> dict[str, Any]:
    if spec["kind"] == "generate.fabric":
        assert spec["params"] == {"preset": "unseen", "sizes": "log_uniform"}
        return {**spec, "params": {**DATASET, "sizes": "log_uniform"}}
    assert spec["kind"] == "train.fabric"
    return {**spec, "params": {**spec["params"], **TRAIN}}


def test01_recipe_reports_each_split_for_three_seeds(
    tmp_path_factory: pytest.TempPathFactory,
) -> None:
    settings, jobs = run_recipe(tmp_path_factory, "fabric_unseen.yaml", shrink)
    assert list(jobs) == ["dataset", "model_s0", "model_s1", "model_s2"]
    assert all(j.state == "succeeded" for j in jobs.values()), {k: j.error for k, j in jobs.items()}
    seeds = [jobs[f"model_s{i}"].spec["seed"] for i in range(3)]
    assert seeds == [0, 1, 2]
    errors = []
    for i in range(3):
        metrics = json.loads(artifact(settings, jobs[f"model_s{i}"], "metrics.json"))
        sets = {s["split"]: s for s in metrics["sets"]}
        assert {k: v["materials"] for k, v in sets.items()} == {
            "train": 3, "unseen_material": 3, "unseen_pattern": 2,
        }  # fmt: skip
        assert [s["queries"] for s in sets.values()] == [96, 96, 64]  # 25 % of 128 each
        errors.append(sets["unseen_pattern"]["cloth_mean_error"]["mean"])
    assert len(set(errors)) == 3  # three different networks
