"""Proofs of issue 23 (section 3) with models matforge did not train, through the recipes
``scripts/external_brdf.yaml`` and ``scripts/external_btf.yaml`` at tiny sizes.

BRDF: the recipe's reference table is made by its own ``tables`` step (generate.merl);
a small MLP is trained on it here in plain torch (not with train.brdf), exported with
``matforge.export.brdf_mlp``, uploaded as ``matforge import`` does, and the whole recipe runs
with ``--var model=<ref>``. Oracles: its SMAPE in ``metrics.json`` equals the test's own
computation (the torch module at the documented 10^6 pairs, Eq. 6 written out here,
against the table's lookup); its Pareto point lies in the same panel as the hybrid's, both
costed in ``ns_per_eval`` and named ``drjit-fused``; select and stability ran over it.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from evaluators.metrics.brdf import DEFAULT_PAIRS, PAIRS_SEED, TableSampler, direction_pairs
from service.submission import import_file
from storage.artifacts import ArtifactStore
from storage.jobs import JobStore
from tests.helpers.recipes import artifact, run_recipe, shrink_btf

pytestmark = pytest.mark.slow

MATERIAL = "iridescent-000-Au"


def shrink(spec: dict[str, Any]) -> dict[str, Any]:
    params = dict(spec["params"])
    if spec["kind"] == "train.brdf":
        params.update(steps=40, speed="trained", speed_batch=1024)
    return {**spec, "params": params}


def own_smape(f: np.ndarray, g: np.ndarray) -> float:
    """Eq. 6 of the hybrid-BRDF paper, eps 0, 0/0 = 0, mean over pairs and channels."""
    num, den = np.abs(f - g), np.abs(f) + np.abs(g)
    return float(np.mean(np.where(den > 0, 2.0 * num / np.where(den > 0, den, 1.0), 0.0)))


def cosine_dirs(rng: np.random.Generator, n: int) -> np.ndarray:
    u = rng.random((n, 2))
    r, phi = np.sqrt(u[:, 0]), 2.0 * math.pi * u[:, 1]
    return np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(1.0 - u[:, 0])], axis=1)


def train_mlp(table: Any) -> torch.nn.Sequential:
    """A 6 -> 16 -> 16 -> 3 ReLU MLP with an exp output, fitted in log space to the table
    at random cosine-weighted pairs (plain torch, Adam)."""
    rng = np.random.default_rng(7)
    wi, wo = cosine_dirs(rng, 8192), cosine_dirs(rng, 8192)
    f = TableSampler(table, interpolate=True).eval(wi, wo)
    ok = ~np.any(f < 0, axis=1)
    x = torch.from_numpy(np.concatenate([wi, wo], axis=1)[ok].astype(np.float32))
    y = torch.from_numpy(np.log(np.maximum(f[ok], 1e-4)).astype(np.float32))
    torch.manual_seed(0)
    net = torch.nn.Sequential(
        torch.nn.Linear(6, 16), torch.nn.ReLU(), torch.nn.Linear(16, 16), torch.nn.ReLU(),
        torch.nn.Linear(16, 3),
    )  # fmt: skip
    opt = torch.optim.Adam(net.parameters(), lr=3e-3)
    for _ in range(300):
        opt.zero_grad()
        loss = torch.mean((net(x) - y) ** 2)
        loss.backward()
        opt.step()
    return net


def test01_brdf_mlp_through_the_recipe(
    tmp_path_factory: pytest.TempPathFactory, tmp_path: Path
) -> None:
    import matforge.datasets
    import matforge.export

    folder = tmp_path_factory.mktemp("external_brdf") / "data"
    placeholder = {"model": "sha256:" + "0" * 64}
    conf, first = run_recipe(
        tmp_path_factory, "external_brdf.yaml", shrink,
        keep=lambda steps: [s for s in steps if s.name == "tables"],
        variables=placeholder, data_dir=folder,
    )  # fmt: skip
    tables = first["tables"]
    table = matforge.datasets.open(f"job:{tables.id}", data_dir=folder)[MATERIAL].table
    net = train_mlp(table)
    path = matforge.export.brdf_mlp(net, tmp_path / "mine.json", output_activation="exp")
    jobs, store = JobStore(conf.db_path), ArtifactStore(conf.store_dir)
    ref = f"sha256:{import_file(path, jobs, store).digest}"

    conf, steps = run_recipe(
        tmp_path_factory, "external_brdf.yaml", shrink, variables={"model": ref}, data_dir=folder
    )
    for name, job in steps.items():
        assert job.state == "succeeded", (name, job.error)
    assert steps["tables"].id == tables.id  # the same spec: the same job

    metrics = json.loads(artifact(conf, steps["scores"], "metrics.json"))
    wi, wo = direction_pairs(DEFAULT_PAIRS, seed=PAIRS_SEED, distribution="cosine")
    reference = TableSampler(table, interpolate=True).eval(wi, wo)
    keep = ~np.any(reference < 0, axis=1)
    with torch.no_grad():
        x = torch.from_numpy(np.concatenate([wi[keep], wo[keep]], axis=1).astype(np.float32))
        mine = torch.exp(net(x)).double().numpy()
    expect = own_smape(reference[keep], mine)
    assert metrics["metrics"]["mine"]["smape"] == pytest.approx(expect, rel=1e-4)
    assert set(metrics["metrics"]) == {"mine", "hybrid", "analytic"}

    pareto = json.loads(artifact(conf, steps["pareto"], "pareto.json"))
    panel = next(p for p in pareto["panels"] if p["cost"] == "ns_per_eval")
    points = {p["candidate"]: p for p in panel["points"]}
    assert {"mine", "hybrid", "analytic"} <= set(points)
    assert points["mine"]["mean"] == pytest.approx(metrics["metrics"]["mine"]["smape"])
    assert points["mine"]["runtime"] == points["hybrid"]["runtime"] == "drjit-fused"
    assert points["mine"]["cost"] > 0 and points["hybrid"]["cost"] > 0
    assert panel["runtimes"] == ["drjit-fused"] and "differ" not in panel["cost_label"]
    manifest = json.loads(ArtifactStore(conf.store_dir).read(steps["scores"].manifest_digest))
    cost = manifest["timings"]["measured"]["cost"]["candidates"]["mine"]
    assert cost["bytes_per_network"] == 4 * sum(p.numel() for p in net.parameters())

    select = json.loads(artifact(conf, steps["select"], "select.json"))
    (ladder,) = select["ladders"]
    rungs = {r["candidate"]: r for r in ladder["rungs"]}
    assert rungs["mine"]["runtime"] == "drjit-fused"
    assert [r["cost"] for r in ladder["rungs"]] == sorted(r["cost"] for r in ladder["rungs"])
    stability = json.loads(artifact(conf, steps["stability"], "stability.json"))
    assert any(f.get("candidate") == "mine" for f in stability["families"])


def train_btf(rgb: np.ndarray, wi: np.ndarray, wo: np.ndarray) -> tuple[Any, Any]:
    """A neural BTF in plain torch: a 4-channel latent texture and a 4 + 6 -> 16 -> 3 MLP,
    fitted at the texel centres of every slice (L1, Adam)."""
    n, h, w, _ = rgb.shape
    torch.manual_seed(0)
    tex = torch.nn.Parameter(0.1 * torch.randn(4, h, w))
    net = torch.nn.Sequential(torch.nn.Linear(10, 16), torch.nn.ReLU(), torch.nn.Linear(16, 3))
    opt = torch.optim.Adam([tex, *net.parameters()], lr=1e-2)
    target = torch.from_numpy(rgb.reshape(n, h * w, 3).astype(np.float32))
    dirs = torch.from_numpy(np.concatenate([wi, wo], axis=1).astype(np.float32))
    for _ in range(200):
        opt.zero_grad()
        x = features(tex, dirs)
        loss = torch.mean(torch.abs(net(x) - target))
        loss.backward()
        opt.step()
    return net, tex.detach()


def features(tex: Any, dirs: Any) -> Any:
    """``(N, H W, 4 + 6)``: every texel's latent (row-major) with each slice's (wi, wo)."""
    c = tex.shape[0]
    lat = tex.reshape(c, -1).T[None].expand(len(dirs), -1, -1)
    return torch.cat([lat, dirs[:, None, :].expand(-1, lat.shape[1], -1)], dim=2)


def test02_neural_btf_through_the_recipe(
    tmp_path_factory: pytest.TempPathFactory, tmp_path: Path
) -> None:
    import matforge.datasets
    import matforge.export

    folder = tmp_path_factory.mktemp("external_btf") / "data"
    conf, first = run_recipe(
        tmp_path_factory, "external_btf.yaml", shrink_btf,
        keep=lambda steps: [s for s in steps if s.name == "leather"],
        variables={"model": "sha256:" + "0" * 64}, data_dir=folder,
    )  # fmt: skip
    leather = first["leather"]
    arrays = matforge.datasets.open(f"job:{leather.id}", data_dir=folder).numpy()
    rgb, wi, wo = arrays["rgb"], arrays["wi"], arrays["wo"]
    net, tex = train_btf(rgb, wi, wo)
    path = matforge.export.btf_mlp(net, tmp_path / "mine.json", textures=[tex])
    jobs, store = JobStore(conf.db_path), ArtifactStore(conf.store_dir)
    ref = f"sha256:{import_file(path, jobs, store).digest}"

    conf, steps = run_recipe(
        tmp_path_factory, "external_btf.yaml", shrink_btf, variables={"model": ref},
        data_dir=folder,
    )  # fmt: skip
    for name, job in steps.items():
        assert job.state == "succeeded", (name, job.error)
    assert steps["leather"].id == leather.id

    metrics = json.loads(artifact(conf, steps["scores"], "metrics.json"))
    # The test's own L1: the torch model at every slice's texel centres (the exported
    # texture is sampled bilinearly there: exactly the texel's latent).
    with torch.no_grad():
        dirs = torch.from_numpy(np.concatenate([wi, wo], axis=1).astype(np.float32))
        pred = net(features(tex, dirs)).double().numpy().reshape(rgb.shape)
    own = float(np.mean(np.abs(pred - rgb.astype(np.float64))))
    assert metrics["metrics"]["mine"]["l1"] == pytest.approx(own, rel=1e-4)
    assert set(metrics["metrics"]) == {"mine", "lafortune", "neumip"}
    assert [c["case"] for c in metrics["cases"]["mine"]] == ["shadowing", "specular", "rest"]

    pareto = json.loads(artifact(conf, steps["pareto"], "pareto.json"))
    panel = next(p for p in pareto["panels"] if p["cost"] == "ns_per_eval")
    points = {p["candidate"]: p for p in panel["points"]}
    assert set(points) == {"mine", "lafortune", "neumip"}
    assert {p["runtime"] for p in points.values()} == {"drjit-fused"}
    assert all(p["cost"] > 0 for p in points.values())
    select = json.loads(artifact(conf, steps["select"], "select.json"))
    assert {r["candidate"] for r in select["ladders"][0]["rungs"]} == set(points)

    # Bytes by one rule for the user's model and the built-ins: per material the latent
    # textures, per network every weight and bias, in all both (counted here from the torch
    # module and from each built-in's model.json).
    manifest = json.loads(ArtifactStore(conf.store_dir).read(steps["scores"].manifest_digest))
    cost = manifest["timings"]["measured"]["cost"]["candidates"]
    assert cost["mine"]["bytes_per_material"] == 4 * tex.numel()
    assert cost["mine"]["bytes_per_network"] == 4 * sum(p.numel() for p in net.parameters())
    for label in ("lafortune", "neumip"):
        doc = json.loads(artifact(conf, steps[label], "model.json"))
        layers = doc["layers"].values()
        floats = sum(np.size(v["weight"]) + np.size(v["bias"]) for v in layers)
        assert cost[label]["bytes_per_network"] == 4 * floats
    for label in ("mine", "lafortune", "neumip"):
        c = cost[label]
        assert c["bytes_total"] == c["bytes_per_network"] + c["bytes_per_material"], label
