"""Costs that do not depend on the machine (:mod:`models.counts`): multiply-adds and bytes
read per evaluation of every model, and the rows and cost documents that carry them.

Oracles: the closed form ``I W + (D - 1) W^2 + W O`` of a ``W x D`` MLP; for a built-in
model, a second path to the same count that does not use the function under test (a
``train.brdf`` material converted to the JSON MLP format and counted by its layers; the
torch network's own ``nn.Linear`` shapes and texture channels for BTF and fabric models).
Counts are integers: compared exactly.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any

import pytest
import torch

from models.brdf.fused import brdf_counts
from models.btf.counts import btf_counts
from models.counts import dense_counts, merl_table_counts, mlp_macs, mlp_params


def test01_closed_forms() -> None:
    """``I W + (D - 1) W^2 + W O`` multiply-adds and that plus ``D W + O`` parameters;
    no network, no cost."""
    assert mlp_macs(6, 32, 3, 6) == 6 * 32 + 2 * 32 * 32 + 32 * 6 == 2432
    assert mlp_params(6, 32, 3, 6) == 2432 + 3 * 32 + 6
    assert dense_counts([(6, 32), (32, 32), (32, 32), (32, 6)]) == (2432, 4 * (2432 + 102))
    assert mlp_macs(6, 0, 0, 3) == 0 and mlp_params(6, 16, 0, 3) == 0
    assert merl_table_counts() == {"macs_per_eval": 0, "bytes_per_eval": 8 * 3 * 4}


@pytest.mark.parametrize("kind", ["hybrid", "neural", "analytic"])
def test02_train_brdf_counts_equal_its_json_mlp(kind: str) -> None:
    """A ``train.brdf`` material's counts from the architecture equal those of the same
    material converted to ``matforge.mlp-brdf/1`` (the latent folded into the bias, the
    neural frames into the first layer), counted layer by layer."""
    from models.external.convert import brdf_material_as_mlp
    from models.external.mlp import mlp_from_document
    from tests.helpers.brdf_models import make_model

    width, depth = (16, 2) if kind != "analytic" else (0, 0)
    doc = make_model(kind, 16, 2, 4)
    name = doc["materials"][0]["name"]
    mlp = mlp_from_document(json.loads(json.dumps(brdf_material_as_mlp(doc, name))))
    counted = brdf_counts(kind, width, depth)
    assert counted == {"macs_per_eval": mlp.macs_per_eval, "bytes_per_eval": mlp.bytes_per_eval}
    if kind == "hybrid":
        assert counted["macs_per_eval"] == 6 * 16 + 16 * 16 + 16 * 6


def _linear_shapes(module: torch.nn.Module) -> dict[str, tuple[int, int]]:
    return {n.split(".")[-1]: (m.in_features, m.out_features)
            for n, m in module.named_modules() if isinstance(m, torch.nn.Linear)}  # fmt: skip


@pytest.mark.parametrize("model", ["neumip", "c2f", "lafortune"])
def test03_train_btf_counts_from_the_torch_network(model: str) -> None:
    """``btf_counts`` of ``model.json`` against the torch network it was written from: its
    ``nn.Linear`` shapes and its textures' channels (bilinear: 4 texels per channel; the
    student's coarse texture at one texel; Lafortune's 55 parameters at one texel)."""
    from materials.btf.lafortune import PARAMS_PER_TEXEL
    from models.btf.networks import Architecture, build_network
    from models.btf.portable import model_document, network_layers, network_textures

    if model == "lafortune":
        import numpy as np

        tex = {"params": np.zeros((4, 4, PARAMS_PER_TEXEL), np.float32)}
        doc = model_document("lafortune", {"model": "lafortune"}, {}, tex, {})
        assert btf_counts(doc) == {"macs_per_eval": 0, "bytes_per_eval": 4 * PARAMS_PER_TEXEL}
        return
    net = build_network(Architecture(model=model, width=16, resolution=(8, 6)), 0)
    tex = network_textures(net)
    doc = json.loads(json.dumps(model_document(model, net.arch.as_dict(), network_layers(net),
                                               tex, {})))  # fmt: skip
    shapes = _linear_shapes(net)
    macs = sum(i * o for i, o in shapes.values())
    params = sum(p.numel() for n, p in net.named_parameters() if p.dim() == 2 or
                 (p.dim() == 1 and "texture" not in n))  # fmt: skip
    if model == "neumip":
        texels = 4 * tex["texture"].shape[0]
    else:
        texels = tex["coarse_texture"].shape[0] + 4 * tex["fine_texture"].shape[0]
    assert btf_counts(doc) == {"macs_per_eval": macs, "bytes_per_eval": 4 * (params + texels)}
    assert btf_counts({"architecture": {}}) == {"macs_per_eval": None, "bytes_per_eval": None}


def test04_train_fabric_counts_from_the_torch_decoder(tmp_path: Any) -> None:
    """``fabric_counts`` of ``model.json`` against the torch decoder: every layer's
    ``in * out``, less ``spatial1``'s latent columns (folded into its bias per material)."""
    from models.fabric.counts import fabric_counts
    from models.fabric.networks import build_network
    from tests.helpers.fabric_models import TINY, write_model

    js, _, _ = write_model(tmp_path)
    doc = json.loads(js.read_text())
    net = build_network(TINY, 11)
    shapes = _linear_shapes(net.decoder)
    live = {**shapes, "spatial1": (shapes["spatial1"][0] - TINY.latent_dim, shapes["spatial1"][1])}
    macs = sum(i * o for i, o in live.values())
    params = macs + sum(o for _, o in live.values())
    assert fabric_counts(doc) == {"macs_per_eval": macs, "bytes_per_eval": 4 * params}


class _Source:
    def __init__(self, kind: str, params: Mapping[str, Any], artifacts: Mapping[str, Any],
                 measured: Mapping[str, Any] | None = None) -> None:  # fmt: skip
        from jobapi.rows import JobFacts

        self.job = JobFacts(id="a" * 32, kind=kind, seed=0, params=params, run_seconds=1.0,
                            measured=measured or {})  # fmt: skip
        self._artifacts = artifacts

    def read(self, name: str) -> Any:
        return self._artifacts.get(name)

    def source(self, ref: str) -> Any:
        return None


def _rows(src: _Source) -> list[Any]:
    from service import kinds

    hook = kinds.get_kind(src.job.kind).rows
    assert hook is not None
    return hook(src)  # type: ignore[arg-type]


def test05_rows_carry_the_counts() -> None:
    """``train.brdf`` rows carry the architecture's counts; a score's external candidate
    the counts of its cost document; a MERL table candidate a table lookup's."""
    from tests.helpers.job_documents import brdf_materials, brdf_metrics, brdf_scores

    gold = brdf_scores("gold", "metal", smape=0.4, smape_floor=0.3, mae=0.1, smape_analytic=0.5)
    arts = {"metrics.json": brdf_metrics([gold], smape=0.4, mae=0.1, smape_analytic=0.5),
            "materials.json": brdf_materials([("gold", "metal", "train")], width=32, depth=3,
                                             latent_dim=4)}  # fmt: skip
    rows = _rows(_Source("train.brdf", {"dataset": "job:" + "b" * 32}, arts))
    assert rows and all(r.macs_per_eval == mlp_macs(6, 32, 3, 6) for r in rows)
    assert all(r.bytes_per_eval == 4 * (mlp_params(6, 32, 3, 6) + 7) for r in rows)
    cost = {"format": "matforge.cost/1", "candidates": {"mine": {
        "ns_per_eval": 5.0, "runtime": "drjit-fused", "bytes_per_network": 100,
        "macs_per_eval": 2336, "bytes_per_eval": 9740}}}  # fmt: skip
    table = "job:" + "c" * 32 + "/gold.binary"
    params = {"reference": "job:" + "d" * 32,
              "candidates": {"mine": {"external": {"model": "sha256:" + "0" * 64,
                                                   "kind": "brdf"}}, "table": table}}  # fmt: skip
    metrics = {"metrics": {"mine": {"smape": 0.1}, "table": {"smape": 0.2}}}
    scored = {r.candidate: r for r in _rows(_Source("score", params, {"metrics.json": metrics},
                                                   {"cost": cost}))}  # fmt: skip
    assert (scored["mine"].macs_per_eval, scored["mine"].bytes_per_eval) == (2336, 9740)
    assert (scored["table"].macs_per_eval, scored["table"].bytes_per_eval) == (0, 96)


def test06_charts_and_choices_take_either_axis() -> None:
    """``report.pareto`` accepts ``costs: [macs_per_eval, bytes_per_eval]`` and draws panels
    on them (labelled as counts of any machine); ``select`` chooses by them; time stays the
    default (not asked for, the counts are not charted)."""
    from evaluators.report.fronts import cost_columns, panels
    from evaluators.report.kind import ReportParetoParams
    from evaluators.report.select_params import SelectParams
    from jobapi.rows import ResultRow

    rows = [
        ResultRow(
            job=j * 32,
            kind="train.brdf",
            metric="smape",
            value=v,
            candidate=c,
            ns_per_eval=ns,
            macs_per_eval=m,
            bytes_per_eval=4.0 * m,
        )  # fmt: skip
        for j, c, v, ns, m in (
            ("a", "hybrid 16x3", 0.11, 10.0, 704.0),
            ("b", "hybrid 32x3", 0.07, 30.0, 2432.0),
        )  # fmt: skip
    ]
    counts = ["macs_per_eval", "bytes_per_eval"]
    ReportParetoParams.model_validate({"runs": ["job:" + "a" * 32], "costs": counts})
    SelectParams.model_validate({"runs": ["job:" + "a" * 32], "metric": "smape", "target": 0.1,
                                 "cost": "macs_per_eval"})  # fmt: skip
    (panel,) = panels(rows, ["smape"], ["macs_per_eval"])
    assert [p["cost"] for p in panel["points"]] == [704.0, 2432.0]
    assert panel["cost_label"].startswith("macs_per_eval: multiply-adds per evaluation")
    assert "macs_per_eval" not in cost_columns(rows, None)
