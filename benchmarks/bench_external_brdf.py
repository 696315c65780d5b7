"""``scripts/external_brdf.yaml`` at its real sizes, with a user's model trained here.

Runs the recipe's ``tables`` step, fits a 6 -> 32 -> 32 -> 32 -> 3 ReLU MLP (exp output,
log-space MSE, Adam, ``--steps`` steps of 4096 pairs) to its thin-film table in plain
torch, exports it with ``matforge.export.brdf_mlp``, imports it as ``matforge import``
does, then runs the whole recipe (``--var model=<ref>``) in process and prints one table
row per candidate of the score step: SMAPE, MAE, ``ns_per_eval``, runtime, bytes, and
whether it is on the Pareto front (SMAPE against ns_per_eval), plus select's choice.

Run: ``.venv/bin/python benchmarks/bench_external_brdf.py [--data-dir DIR] [--steps 2000]``
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

MATERIAL = "iridescent-000-Au"


def fit(table: Any, steps: int) -> Any:
    import torch

    from evaluators.metrics.brdf import TableSampler

    rng = np.random.default_rng(0)

    def cosine(n: int) -> np.ndarray:
        u = rng.random((n, 2))
        r, phi = np.sqrt(u[:, 0]), 2.0 * math.pi * u[:, 1]
        return np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(1.0 - u[:, 0])], axis=1)

    wi, wo = cosine(1 << 16), cosine(1 << 16)
    f = TableSampler(table, interpolate=True).eval(wi, wo)
    ok = ~np.any(f < 0, axis=1)
    x = torch.from_numpy(np.concatenate([wi, wo], axis=1)[ok].astype(np.float32))
    y = torch.from_numpy(np.log(np.maximum(f[ok], 1e-4)).astype(np.float32))
    torch.manual_seed(0)
    layers: list[Any] = []
    for i in range(3):
        layers += [torch.nn.Linear(6 if i == 0 else 32, 32), torch.nn.ReLU()]
    net = torch.nn.Sequential(*layers, torch.nn.Linear(32, 3))
    opt = torch.optim.Adam(net.parameters(), lr=2e-3)
    for _ in range(steps):
        idx = torch.randint(0, len(x), (4096,))
        opt.zero_grad()
        loss = torch.mean((net(x[idx]) - y[idx]) ** 2)
        loss.backward()
        opt.step()
    return net


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--data-dir", type=Path, default=None)
    ap.add_argument("--steps", type=int, default=2000)
    args = ap.parse_args()

    import matforge.datasets
    import matforge.export
    from service import kinds
    from service.cli.batch import load_batch
    from service.cli.batch_local import run_steps_in_process
    from service.settings import Settings
    from service.submission import import_file
    from storage.artifacts import ArtifactStore
    from storage.jobs import JobStore

    kinds.load_builtin()
    folder = args.data_dir or Path(tempfile.mkdtemp(prefix="bench-external-brdf-"))
    conf = Settings.from_env({}).with_(data_dir=folder, pool_processes=1)
    recipe = ROOT / "scripts" / "external_brdf.yaml"
    first = load_batch(recipe, variables={"model": "sha256:" + "0" * 64}).steps[:1]
    tables = run_steps_in_process(list(first), conf)["tables"]
    table = matforge.datasets.open(f"job:{tables.id}", data_dir=folder)[MATERIAL].table
    net = fit(table, args.steps)
    path = matforge.export.brdf_mlp(net, folder / "mine.json", output_activation="exp")
    jobs, store = JobStore(conf.db_path), ArtifactStore(conf.store_dir)
    ref = f"sha256:{import_file(path, jobs, store).digest}"
    steps = run_steps_in_process(list(load_batch(recipe, variables={"model": ref}).steps), conf)
    failed = {n: j.error for n, j in steps.items() if j.state != "succeeded"}
    if failed:
        raise SystemExit(f"steps failed: {failed}")

    def read(job: Any, name: str) -> Any:
        (digest,) = [a.digest for a in job.artifacts if a.name == name]
        return json.loads(store.read(digest))

    metrics = read(steps["scores"], "metrics.json")["metrics"]
    pareto = read(steps["pareto"], "pareto.json")
    panel = next(p for p in pareto["panels"] if p["cost"] == "ns_per_eval")
    bytes_panel = next(p for p in pareto["panels"] if p["cost"] == "bytes_per_network")
    size = {p["candidate"]: p["cost"] for p in bytes_panel["points"]}
    print("| candidate | SMAPE | MAE (1/sr) | ns_per_eval | runtime | bytes_per_network | front |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for p in sorted(panel["points"], key=lambda p: p["cost"]):
        c = p["candidate"]
        print(f"| {c} | {metrics[c]['smape']:.4f} | {metrics[c]['mae']:.4g} | {p['cost']:.3f} | "
              f"{p['runtime']} | {size.get(c, float('nan')):.0f} | {p['front']} |")  # fmt: skip
    lad = read(steps["select"], "select.json")["ladders"][0]
    print(f"select (SMAPE <= 0.1, by ns_per_eval): {lad['chosen']}: {lad['why']}")
    print(f"command: .venv/bin/python benchmarks/bench_external_brdf.py --steps {args.steps}")


if __name__ == "__main__":
    main()
