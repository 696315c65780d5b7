"""``scripts/external_btf.yaml`` at a chosen size, with a user's neural BTF trained here.

Runs the recipe's ``leather`` step (generate.btf), reads its slices with
``matforge.datasets``, fits a neural BTF in plain torch (an 8-channel latent texture at the
slices' resolution and an 8 + 6 -> 32 -> 32 -> 3 ReLU MLP, its output times ``cos(theta_i)``;
L1, Adam, ``--steps`` steps of 8,192 random texels x slices), exports it with
``matforge.export.btf_mlp`` (``foreshortening="apply"``), imports it as ``matforge import``
does, then runs the whole recipe (``--var model=<ref>`` and the size variables) in process
and prints one table row per candidate of the score step: L1 (and per failure case),
``ns_per_eval``, runtime, bytes, the Pareto front and select's choice, and the seconds of
every step.

Run: ``.venv/bin/python benchmarks/bench_external_btf.py [--data-dir DIR] [--steps 4000]
[--var NAME=VALUE ...]`` (the recipe's size variables: ``resolution``, ``spp``,
``directions``, ``epochs``, ``lafortune_slices``)
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

CHANNELS, WIDTH, BATCH = 8, 32, 8192


def fit(rgb: np.ndarray, wi: np.ndarray, wo: np.ndarray, steps: int) -> tuple[Any, Any]:
    """The user's model: plain torch, nothing from matforge."""
    import torch

    n, h, w, _ = rgb.shape
    torch.manual_seed(0)
    tex = torch.nn.Parameter(0.1 * torch.randn(CHANNELS, h, w))
    net = torch.nn.Sequential(
        torch.nn.Linear(CHANNELS + 6, WIDTH), torch.nn.ReLU(), torch.nn.Linear(WIDTH, WIDTH),
        torch.nn.ReLU(), torch.nn.Linear(WIDTH, 3),
    )  # fmt: skip
    target = torch.from_numpy(rgb.reshape(n, h * w, 3).astype(np.float32))
    dirs = torch.from_numpy(np.concatenate([wi, wo], axis=1).astype(np.float32))
    opt = torch.optim.Adam([tex, *net.parameters()], lr=3e-3)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps)
    gen = torch.Generator().manual_seed(0)
    flat = tex.view(CHANNELS, h * w)
    for _ in range(steps):
        s = torch.randint(0, n, (BATCH,), generator=gen)
        t = torch.randint(0, h * w, (BATCH,), generator=gen)
        x = torch.cat([flat[:, t].T, dirs[s]], dim=1)
        pred = net(x) * dirs[s, 2:3]  # foreshortening: cos(theta_i) of the light
        loss = torch.mean(torch.abs(pred - target[s, t]))
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
    return net, tex.detach()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--data-dir", type=Path, default=None)
    ap.add_argument("--steps", type=int, default=4000)
    ap.add_argument("--var", action="append", default=[], metavar="NAME=VALUE")
    ap.add_argument("--references-only", action="store_true",
                    help="run only the steps before the user's model (generate.btf, "
                    "train.btf); a later run over the same --data-dir reuses them")  # fmt: skip
    args = ap.parse_args()

    import matforge.datasets
    import matforge.export
    from service import kinds
    from service.cli.batch import load_batch, parse_vars
    from service.cli.batch_local import run_steps_in_process
    from service.settings import Settings
    from service.submission import import_file
    from storage.artifacts import ArtifactStore
    from storage.jobs import JobStore

    kinds.load_builtin()
    sizes = parse_vars(args.var)
    folder = args.data_dir or Path(tempfile.mkdtemp(prefix="bench-external-btf-"))
    conf = Settings.from_env({}).with_(data_dir=folder, pool_processes=1)
    recipe = ROOT / "scripts" / "external_btf.yaml"
    seconds: dict[str, float] = {}
    placeholder = {**sizes, "model": "sha256:" + "0" * 64}
    first = [s for s in load_batch(recipe, variables=placeholder).steps
             if s.name in ("leather", "lafortune", "neumip")]  # fmt: skip
    for k in range(len(first)):
        t0 = time.perf_counter()
        ran = run_steps_in_process(first[: k + 1], conf)
        seconds[first[k].name] = time.perf_counter() - t0
        print(f"{first[k].name}: {ran[first[k].name].state} in {seconds[first[k].name]:.1f} s",
              flush=True)  # fmt: skip
    leather = ran["leather"]
    if args.references_only:
        return
    arrays = matforge.datasets.open(f"job:{leather.id}", data_dir=folder).numpy()
    t0 = time.perf_counter()
    net, tex = fit(arrays["rgb"], arrays["wi"], arrays["wo"], args.steps)
    seconds["mine: plain-torch fit"] = time.perf_counter() - t0
    path = matforge.export.btf_mlp(
        net, folder / "mine.json", textures=[tex], foreshortening="apply", name="plain-torch BTF"
    )
    jobs, store = JobStore(conf.db_path), ArtifactStore(conf.store_dir)
    ref = f"sha256:{import_file(path, jobs, store).digest}"
    batch = list(load_batch(recipe, variables={**sizes, "model": ref}).steps)
    done: dict[str, Any] = {}
    for k in range(len(batch)):  # one step at a time, to time each
        t0 = time.perf_counter()
        done = run_steps_in_process(batch[: k + 1], conf)
        seconds.setdefault(batch[k].name, time.perf_counter() - t0)
    failed = {n: j.error for n, j in done.items() if j.state != "succeeded"}
    if failed:
        raise SystemExit(f"steps failed: {failed}")

    def read(job: Any, name: str) -> Any:
        (digest,) = [a.digest for a in job.artifacts if a.name == name]
        return json.loads(store.read(digest))

    metrics = read(done["scores"], "metrics.json")
    manifest = json.loads(store.read(done["scores"].manifest_digest))
    cost = manifest["timings"]["measured"]["cost"]["candidates"]
    pareto = read(done["pareto"], "pareto.json")
    panel = next(p for p in pareto["panels"] if p["cost"] == "ns_per_eval")
    front = {p["candidate"]: p["front"] for p in panel["points"]}
    settings = metrics["settings"]
    print(f"slices {settings['slices']} at {settings['resolution']}, mean |BTF| "
          f"{settings['mean_abs_btf']:.4g}")  # fmt: skip
    print(
        "| candidate | L1 | relative L1 | L1 shadowing / specular / rest | ns_per_eval | "
        "runtime | bytes_per_network | bytes_per_material | bytes_total | front |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for c in sorted(metrics["metrics"], key=lambda c: cost[c]["ns_per_eval"]):
        m, k = metrics["metrics"][c], cost[c]
        cases = " / ".join(f"{x['l1']:.4g}" for x in metrics["cases"][c])
        sizes_ = [k.get(b) for b in ("bytes_per_network", "bytes_per_material", "bytes_total")]
        print(f"| {c} | {m['l1']:.5f} | {m['relative_l1']:.4f} | {cases} | "
              f"{k['ns_per_eval']:.2f} | {k['runtime']} | {' | '.join(map(str, sizes_))} | "
              f"{front.get(c)} |")  # fmt: skip
    lad = read(done["select"], "select.json")["ladders"][0]
    print(f"select (relative L1 <= 0.2, by ns_per_eval): {lad['chosen']}: {lad['why']}")
    for name, s in seconds.items():
        print(f"seconds {name}: {s:.1f}")
    extra = " ".join(f"--var {v}" for v in args.var)
    print(f"command: .venv/bin/python benchmarks/bench_external_btf.py --steps {args.steps} "
          f"{extra}")  # fmt: skip


if __name__ == "__main__":
    main()
