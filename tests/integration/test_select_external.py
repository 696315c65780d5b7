"""``select`` in its scene mode with users' models as rungs (``{"external": ...}``): each
rung rendered, scored against a diffuse reference and costed by ``ns_per_eval`` measured
as ``score`` measures it, each rung naming its runtime.

Models: a Lambertian ONNX BRDF of the reference's albedo (:mod:`tests.helpers.onnx_models`,
``onnx.helper``) and a plain-torch MLP exported with ``matforge.export.brdf_mlp`` (a
constant ``albedo / pi`` network: zero weights, bias the albedo). Oracles: both match the
reference (FLIP below the target); each rung's cost is the one its runtime gives; a spec
choosing by ``bytes_per_material`` with an external rung is refused, naming the rung.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from jobapi.errors import SpecError
from service import kinds
from service.settings import Settings
from service.specs import validate_spec
from service.submission import import_file, run_in_process
from storage.artifacts import ArtifactStore
from storage.jobs import JobStore
from tests.helpers import onnx_models

ALBEDO = (0.2, 0.5, 0.8)


def spec(onnx_ref: str, mlp_ref: str, cost: str = "ns_per_eval") -> dict[str, Any]:
    diffuse = {"mitsuba": {"type": "diffuse", "reflectance": {"type": "rgb", "value": ALBEDO}}}
    return {
        "kind": "select",
        "seed": 1,
        "params": {
            "scene": {"scene": "sphere_env", "resolution": [16, 16], "spp": 4, "max_depth": 3},
            "reference": {"material": diffuse, "spp": 64},
            "ladder": [
                {"name": "onnx", "material": {"external": {"model": onnx_ref, "kind": "brdf"}}},
                {"name": "mlp", "material": {"external": {"model": mlp_ref, "kind": "brdf"}}},
            ],
            "metric": "flip",
            "target": 0.5,
            "cost": cost,
        },
    }


def test01_external_rungs_are_rendered_scored_and_costed(tmp_path: Path) -> None:
    import matforge.export

    kinds.load_builtin()
    settings = Settings.from_env({}).with_(data_dir=tmp_path / "data", pool_processes=1)
    jobs, store = JobStore(settings.db_path), ArtifactStore(settings.store_dir)
    onnx_path = onnx_models.save(onnx_models.lambert_model("brdf", ALBEDO), tmp_path / "l.onnx")
    net = torch.nn.Sequential(torch.nn.Linear(6, 4), torch.nn.ReLU(), torch.nn.Linear(4, 3))
    with torch.no_grad():
        for p in net.parameters():
            p.zero_()
        net[2].bias.copy_(torch.tensor(ALBEDO) / math.pi)
    mlp_path = matforge.export.brdf_mlp(net, tmp_path / "mlp.json")
    onnx_ref = f"sha256:{import_file(onnx_path, jobs, store).digest}"
    mlp_ref = f"sha256:{import_file(mlp_path, jobs, store).digest}"

    job = run_in_process(spec(onnx_ref, mlp_ref), settings)
    assert job.state == "succeeded", job.error
    (digest,) = [a.digest for a in job.artifacts if a.name == "select.json"]
    doc = json.loads(store.read(digest))
    (ladder,) = doc["ladders"]
    rungs = {r["candidate"]: r for r in ladder["rungs"]}
    assert rungs["onnx"]["runtime"] == "onnxruntime"
    assert rungs["mlp"]["runtime"] == "drjit-fused"
    assert all(r["cost"] > 0 and r["meets"] for r in rungs.values())
    assert np.isfinite([r["value"] for r in rungs.values()]).all()
    assert ladder["chosen"] == min(rungs.values(), key=lambda r: r["cost"])["candidate"]
    # both rungs and the reference kernel timed in this job's one pass
    timing = doc["timing"]
    assert set(timing["costs"]) == {"onnx", "mlp", "reference"}
    assert timing["costs"]["onnx"]["runtime"] == "onnxruntime"
    for name, r in rungs.items():
        dist = timing["costs"][name]["distribution"]
        assert r["cost"] == dist["median"] and (r["cost_min"], r["cost_max"]) == (
            dist["min"], dist["max"])  # fmt: skip
        assert r["relative"]["median"] > 0
    assert isinstance(ladder["resolved"], bool)


def test02_bytes_per_material_refused_for_external_rungs() -> None:
    kinds.load_builtin()
    ref = "sha256:" + "0" * 64
    with pytest.raises(SpecError, match=r"ladder.0.material: an external model's parameters"):
        validate_spec(spec(ref, ref, cost="bytes_per_material"))
