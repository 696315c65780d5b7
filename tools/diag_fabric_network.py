"""Diagnosis of the neural woven fabric's darkness: where does the network lose energy?

The `small` network renders `cloth_plane` about 30 % darker than the Monte Carlo ground
truth (BENCHMARKS.md, "Fabric evaluation"). This script trains one configuration
(``generate.fabric`` then ``train.fabric``, both through the registry in-process, as
``matforge run`` does) and measures the trained network against fresh, low-noise Monte
Carlo estimates (:func:`materials.fabric.aggregate.estimate`, drjit backend, ``--samples``
Sobol samples per query, a query design seed no dataset uses):

- **ratio** = ``sum pred / sum target`` per component (C_warp, C_weft, S_warp, S_weft) and
  of the Eq. 8 RGB value, per footprint-size bucket (tile units, box side, as in the
  training data and as the renderer passes ``sqrt |det duv|``); 1 is unbiased;
- **log residual**: the mean of ``g(pred) - g(target)`` of the specular components in the
  training space of Eq. 9 (``g(x) = ln(k x + 1)``); near 0 with a ratio below 1 means the
  fit is unbiased in log space and biased low in linear space (Jensen: the log loss
  regresses to a geometric-type mean of what the inputs cannot separate);
- **oracle** (``oracle_rgb``, ``oracle_S_warp``, ``oracle_S_weft``): the same ratio for
  a model that minimises the log loss exactly but resolves neither the footprint centre nor
  directions finer than a 4 x 4 cell each: the targets' ``g^-1(mean g)`` per (size bucket,
  wi cell, wo cell, side) group of queries (``_oracle``); its shortfall is the log loss's
  Jensen bias alone (run with ``--samples 256`` and ``1024`` to see it is not noise);
- materials: every training material, the recipe's unseen twill 4x4, and the Fig. 8 twill
  3x3 at beta 0.2, 0.5, 0.8 (the beta response: mean RGB of network and reference).

Query sets: ``design`` (the training design: sizes over [0, 5] tiles) and ``render``
(the same directions and centres, sizes uniform in [0.03, 0.1] tile: the pixel footprints of
``cloth_plane`` at 8-16 tiles per uv).

Run: ``.venv/bin/python tools/diag_fabric_network.py --config small --out d.json``
(configs: see :data:`CONFIGS`; ``--gen`` / ``--train`` add JSON params over them).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402

#: name -> (generate.fabric params, train.fabric params without the dataset).
CONFIGS: dict[str, tuple[dict[str, Any], dict[str, Any]]] = {
    "small": ({"preset": "small"}, {"preset": "small"}),
    # more queries per material (one complete round of the design)
    "queries": ({"preset": "small", "queries_per_material": 20480, "shard_queries": 5120},
                {"preset": "small"}),
    # more materials: 4 (alpha, beta, w, albedo) draws per pattern, 20480 queries each
    "materials": ({"preset": "small", "shading_sets": 4, "queries_per_material": 20480,
                   "shard_queries": 5120}, {"preset": "small"}),
    # less target noise: 2048 samples per query
    "samples": ({"preset": "small", "samples": 2048}, {"preset": "small"}),
    # scripts/fabric_eval.yaml: one complete design round per material, 6,000 steps
    "recipe": ({"preset": "small", "queries_per_material": 20480, "shard_queries": 5120},
               {"preset": "small", "steps": 6000}),
}  # fmt: skip
#: Footprint-size buckets, tile units.
BUCKETS = ((0.0, 0.1), (0.1, 0.3), (0.3, 1.0), (1.0, 5.0))
SEEN = {"pattern": "twill_3x3", "psi_deg": 20, "u_max_deg": 25, "alpha": 0.4, "w": 0.5,
        "kd_warp": [0.6, 0.5, 0.2], "kd_weft": [0.3, 0.4, 0.6], "ks_warp": 0.5,
        "ks_weft": 0.5, "gap": 0.2, "t_rho": 2.0}  # fmt: skip
UNSEEN = {"pattern": "twill_4x4", "psi_deg": 20, "u_max_deg": 25, "alpha": 0.35, "beta": 0.6,
          "w": 0.5, "kd_warp": [0.7, 0.25, 0.15], "kd_weft": [0.2, 0.35, 0.6],
          "ks_warp": 0.5, "ks_weft": 0.4, "gap": 0.2, "t_rho": 2.0}  # fmt: skip
DESIGN_SEED = 0xD1A6


def train(gen: dict[str, Any], tr: dict[str, Any], data: Path) -> tuple[Any, Any, dict, float]:
    """Run both jobs; ``(settings, train job, materials.json, train seconds)``."""
    from service.settings import Settings
    from service.submission import run_in_process

    settings = Settings.from_env({}).with_(data_dir=data, lease_seconds=60.0, pool_processes=2)
    t0 = time.perf_counter()
    g = run_in_process({"kind": "generate.fabric", "seed": 0, "params": gen}, settings)
    assert g.state == "succeeded", g.error
    t1 = time.perf_counter()
    spec = {"kind": "train.fabric", "seed": 0, "params": {"dataset": f"job:{g.id}", **tr}}
    j = run_in_process(spec, settings)
    assert j.state == "succeeded", j.error
    t2 = time.perf_counter()
    print(f"generate {t1 - t0:.1f} s, train {t2 - t1:.1f} s", file=sys.stderr)
    return settings, j, _artifact_json(settings, g, "materials.json"), t2 - t1


def _artifact(settings: Any, job: Any, name: str) -> bytes:
    from storage.artifacts import ArtifactStore

    (digest,) = [a.digest for a in job.artifacts if a.name == name]
    return ArtifactStore(settings.store_dir).read(digest)


def _artifact_json(settings: Any, job: Any, name: str) -> Any:
    return json.loads(_artifact(settings, job, name))


def query_sets(n: int) -> dict[str, np.ndarray]:
    """``{name: (n, 9) float64 cx, cy, size, wi.xyz, wo.xyz}``: ``design`` and ``render``."""
    from generators.fabric.queries import design_queries

    q = design_queries(DESIGN_SEED, 0, n)
    base = np.concatenate([q.centre, q.size[:, None], q.wi, q.wo], axis=1)
    render = base.copy()
    render[:, 2] = np.random.default_rng(7).uniform(0.03, 0.1, n)
    return {"design": base, "render": render}


def reference(params: Any, q: np.ndarray, samples: int) -> np.ndarray:
    from materials.fabric.aggregate import FootprintQueries, estimate

    fq = FootprintQueries(centre=q[:, :2], size=q[:, 2], wi=q[:, 3:6], wo=q[:, 6:9])
    return estimate(params, fq, samples=samples, sampler="sobol", seed=11, backend="drjit").mean


def _oracle(q: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Per query, ``g^-1`` of the mean ``g(target)`` over the queries that share its
    direction-pair cell (4 x 4 for wi, 4 x 4 for wo, side) and size bucket: a model that cannot
    resolve what varies inside a cell (centre, fine direction) and minimises the log loss
    predicts this; its linear ratio is the Jensen bias of the log loss alone."""
    from models.fabric.losses import log_targets_numpy
    from models.fabric.networks import components_numpy

    def cell(w: np.ndarray) -> np.ndarray:
        return (np.clip((w[:, 0] + 1) * 2, 0, 3.999).astype(int) * 4
                + np.clip((w[:, 1] + 1) * 2, 0, 3.999).astype(int))  # fmt: skip

    b = np.digitize(q[:, 2], [hi for _, hi in BUCKETS[:-1]])
    key = ((cell(q[:, 3:6]) * 16 + cell(q[:, 6:9])) * 2 + (q[:, 5] < 0)) * len(BUCKETS) + b
    logt = log_targets_numpy(target, q[:, 5])
    out = np.empty_like(logt)
    for k in np.unique(key):
        m = key == k
        out[m] = logt[m].mean(axis=0)
    return components_numpy(out.astype(np.float32), q[:, 5]).astype(np.float64)


def stats(pred: np.ndarray, target: np.ndarray, q: np.ndarray, albedos: np.ndarray,
          oracle: np.ndarray | None = None) -> dict[str, Any]:  # fmt: skip
    """Ratios and log residuals per size bucket (module docstring)."""
    from models.fabric.losses import log_targets_numpy

    out: dict[str, Any] = {}
    for lo, hi in BUCKETS:
        m = (q[:, 2] >= lo) & (q[:, 2] < hi)
        if not m.any():
            continue
        p, t = pred[m], target[m]
        row = {"n": int(m.sum())}
        for k, name in enumerate(("C_warp", "C_weft", "S_warp", "S_weft")):
            row[name] = float(p[:, k].sum() / max(t[:, k].sum(), 1e-30))
        row["rgb"] = float((p @ albedos).sum() / max((t @ albedos).sum(), 1e-30))
        lp, lt = log_targets_numpy(p, q[m, 5]), log_targets_numpy(t, q[m, 5])
        row["log_resid_S"] = float((lp[:, 2:] - lt[:, 2:]).mean())
        row["rel_l1_rgb"] = float(np.abs(p @ albedos - t @ albedos).sum() / (t @ albedos).sum())
        if oracle is not None:
            row["oracle_rgb"] = float((oracle[m] @ albedos).sum() / (t @ albedos).sum())
            for k, name in ((2, "S_warp"), (3, "S_weft")):
                row[f"oracle_{name}"] = float(oracle[m][:, k].sum() / max(t[:, k].sum(), 1e-30))
        out[f"{lo:g}-{hi:g}"] = row
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default="small", choices=sorted(CONFIGS))
    ap.add_argument("--gen", default="{}", help="JSON generate.fabric params over the config")
    ap.add_argument("--train", default="{}", help="JSON train.fabric params over the config")
    ap.add_argument("--queries", type=int, default=4096)
    ap.add_argument("--samples", type=int, default=1024)
    ap.add_argument("--data-dir", type=Path, default=None)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()

    from evaluators.render.sources.fabric import FabricSpec
    from models.fabric.fused import encode_material, load_fabric_model, material_maps
    from models.fabric.networks import components_numpy
    from models.fabric.portable import load_checkpoint
    from models.fabric.report import decode_raw

    gen, tr = CONFIGS[args.config]
    gen, tr = {**gen, **json.loads(args.gen)}, {**tr, **json.loads(args.train)}
    data = args.data_dir or Path(tempfile.mkdtemp(prefix="diag_fabric_"))
    settings, job, mats, seconds = train(gen, tr, data)
    blob = _artifact(settings, job, "model.pt")
    net, _ = load_checkpoint(blob)
    model = load_fabric_model(blob)
    metrics = _artifact_json(settings, job, "metrics.json")["mean"]
    sets = query_sets(args.queries)

    def to_params(rec: dict[str, Any]) -> Any:
        return FabricSpec.model_validate(rec, strict=False).to_params()

    materials = {r["name"]: to_params(r["params"]) for r in mats["materials"]}
    materials["unseen-twill_4x4"] = to_params(UNSEEN)
    for beta in (0.2, 0.5, 0.8):
        materials[f"fig8-beta{beta}"] = to_params({**SEEN, "beta": beta})
    result: dict[str, Any] = {"config": args.config, "gen": gen, "train": tr,
                              "train_seconds": seconds, "load": os.getloadavg()[0],
                              "heldout": {"rgb_rel": metrics["rgb"]["rel"],
                                          "loss": metrics["loss"]},
                              "materials": {}}  # fmt: skip
    for name, params in materials.items():
        normal, orient = material_maps(params, 256)
        z = encode_material(model, params, normal, orient)
        alb = params.albedos()
        row: dict[str, Any] = {}
        for sname, q in sets.items():
            target = reference(params, q, args.samples)
            q8 = np.concatenate([q[:, :6], q[:, 6:8]], axis=1).astype(np.float32)
            pred = components_numpy(decode_raw(net, z, q8), q8[:, 5]).astype(np.float64)
            row[sname] = stats(pred, target, q, alb, _oracle(q, target))
            row[sname]["mean_rgb"] = {"net": float((pred @ alb).mean()),
                                      "mc": float((target @ alb).mean())}  # fmt: skip
        result["materials"][name] = row
        print(name, json.dumps({s: {b: {k: round(v, 3) for k, v in r.items()}
                                    if isinstance(r, dict) else r for b, r in row[s].items()}
                                for s in row}), file=sys.stderr)  # fmt: skip
    report(result)
    if args.out is not None:
        args.out.write_text(json.dumps(result, indent=1))


def report(result: dict[str, Any]) -> None:
    """Markdown: RGB ratio per bucket (design set) and render set, per material."""
    h = result["heldout"]
    print(
        f"\nconfig {result['config']}: train {result['train_seconds']:.0f} s, held-out RGB "
        f"rel. {h['rgb_rel']:.3f}, loss {h['loss']:.4f}; gen {json.dumps(result['gen'])}"
    )
    names = [f"{lo:g}-{hi:g}" for lo, hi in BUCKETS]
    print("\n| material | " + " | ".join(f"RGB ratio {b}" for b in names)
          + " | render-set RGB ratio | oracle RGB | S_warp, S_weft (oracle) | C_warp, C_weft "
          "| log resid S | mean RGB net / MC |")  # fmt: skip
    print("| --- " * (len(names) + 7) + "|")
    for name, row in result["materials"].items():
        d, r = row["design"], row["render"]["0-0.1"]
        cells = " | ".join(f"{d[b]['rgb']:.3f}" if b in d else "" for b in names)
        mr = row["render"]["mean_rgb"]
        print(
            f"| {name} | {cells} | {r['rgb']:.3f} | {r['oracle_rgb']:.3f} | "
            f"{r['S_warp']:.2f}, {r['S_weft']:.2f} ({r['oracle_S_warp']:.2f}, "
            f"{r['oracle_S_weft']:.2f}) | {r['C_warp']:.2f}, {r['C_weft']:.2f} | "
            f"{r['log_resid_S']:+.3f} | {mr['net']:.4f} / {mr['mc']:.4f} |"
        )


if __name__ == "__main__":
    main()
