"""Mean SMAPE and training time of ``train.brdf`` models on the ``small`` collection.

The headline comparison of the hybrid-BRDF paper (Fig. 4, Table 1) at our scale: the
``small`` generate.merl collection (12 materials, every family; seed 0, or each of
``--seed`` / ``--collection-seeds``), each model trained
with the ``small`` preset (5000 steps of 1024 pairs per material, AdamW lr 0.005 with cosine
decay, clip 0.01) through the registry exactly as ``matforge run`` does, in a temporary
data directory (or ``--data-dir``). Rows: ``analytic`` (GGX + Lambert), and ``hybrid`` and
``neural`` at each ``--sizes`` with latent ``l`` (``--latent``); the neural code has the
hybrid's per-material float count, ``l + 7`` (``--paper-neural`` adds rows with the paper's
``l + 8``).

Columns: ``smape`` is the mean over materials of Eq. 6 at 2^18 fixed-seed pairs
(``metrics.json``), ``smape_floor`` that of the variant stable at exact table zeros
(:func:`evaluators.metrics.brdf.smape_floor`; ``--per-material`` prints both per
material); ``smape f_a`` that of the hybrid's analytic part alone; ``irid.`` and
``blend`` the family means singled out by the paper's Sec. 6 (iridescence, multi-lobe);
``wall s`` the job's wall time (loading, training, scoring; training runs on one thread,
:data:`models.brdf.train.TORCH_THREADS`). The machine is shared: the load average is
printed with each row.

``--paper-steps N`` instead times the ``paper`` preset (Sec. 3.3: hybrid 32x3, latent 4,
1024 pairs per material per step, 100 materials; 200k steps): N optimiser steps of
:func:`models.brdf.train.fit` on the 12 small-collection tables tiled to 100 materials
(speed does not depend on the values), on the job's thread count, and prints ms per step and
the extrapolated hours for 200k steps.

Run: ``.venv/bin/python benchmarks/bench_train_brdf.py [--sizes 16x3 32x3] [--latent 4]
[--models analytic hybrid neural] [--steps N] [--paper-neural] [--train-seeds 0 1 2]
[--seed 0 1] [--per-material] [--no-speed] [--out DIR] [--data-dir D] [--paper-steps N]``
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from service.settings import Settings  # noqa: E402
from service.submission import run_in_process  # noqa: E402
from storage.artifacts import ArtifactStore  # noqa: E402


def metrics_of(settings: Settings, job: Any) -> dict[str, Any]:
    (digest,) = [a.digest for a in job.artifacts if a.name == "metrics.json"]
    return dict(json.loads(ArtifactStore(settings.store_dir).read(digest)))


def fmt(v: float | None) -> str:
    return "-" if v is None else f"{v:.4f}"


def paper_step(settings: Settings, gen: Any, steps: int) -> None:
    """Time ``steps`` steps of the paper preset on 100 tiled tables; print one row."""
    import torch

    from models.brdf.data import MaterialTable, stack_tables
    from models.brdf.kind import PRESETS
    from models.brdf.networks import Architecture, build_model
    from models.brdf.train import TORCH_THREADS, FitConfig, deterministic_torch, fit
    from storage.formats.merl import read_merl

    store = ArtifactStore(settings.store_dir)
    tables = [a for a in gen.artifacts if a.name.endswith(".binary") and "/" not in a.name]
    mats = [MaterialTable(a.name, "x", read_merl(store.path(a.digest), a.name), a.name)
            for a in tables]  # fmt: skip
    mats = [mats[i % len(mats)] for i in range(100)]
    p = PRESETS["paper"]
    arch = Architecture("hybrid", p.width, p.depth, p.latent_dim)
    config = FitConfig(steps, p.batch_pairs, p.lr, p.weight_decay, p.clip)
    with deterministic_torch():
        model = build_model(arch, len(mats), torch.Generator().manual_seed(0))
        curves = fit(model, stack_tables(mats), config, torch.Generator().manual_seed(1))
    ms = 1000.0 * curves.seconds / steps
    print("| preset | materials | MLP | pairs per step | threads | ms per step | 200k steps |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    hours = ms * p.steps / 3.6e6
    load = os.getloadavg()[0]
    print(f"| paper | 100 | {p.width}x{p.depth} | {100 * p.batch_pairs} | {TORCH_THREADS} "
          f"| {ms:.0f} | {hours:.1f} h (load {load:.1f}) |")  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", nargs="+", default=["16x3", "32x3"])
    ap.add_argument("--latent", type=int, choices=(4, 8), default=4)
    ap.add_argument("--models", nargs="+", default=["analytic", "hybrid", "neural"])
    ap.add_argument("--steps", type=int, default=None, help="override the preset's steps")
    ap.add_argument("--paper-neural", action="store_true", help="also neural with l + 8")
    ap.add_argument("--seed", "--collection-seeds", dest="seeds", type=int, nargs="+", default=[0],
                    help="seeds of the generate.merl collection, one collection each")  # fmt: skip
    ap.add_argument("--per-material", action="store_true",
                    help="print smape and smape_floor per material after each job")  # fmt: skip
    ap.add_argument("--no-speed", action="store_true", help="train.brdf speed: off")
    ap.add_argument("--out", type=Path, default=None, help="write each job's metrics.json here")
    ap.add_argument(
        "--train-seeds", type=int, nargs="+", default=[0], help="train.brdf seeds, one row each"
    )
    ap.add_argument("--data-dir", type=Path, default=None)
    ap.add_argument("--paper-steps", type=int, default=0, help="time the paper preset instead")
    args = ap.parse_args()

    tmp = None
    if args.data_dir is None:
        tmp = tempfile.TemporaryDirectory(prefix="bench_train_brdf-")
        args.data_dir = Path(tmp.name)
    settings = Settings.from_env({}).with_(data_dir=args.data_dir, pool_processes=2)
    gens = {}
    for cseed in args.seeds:
        gen = run_in_process(
            {"kind": "generate.merl", "seed": cseed,
             "params": {"collection": {"preset": "small"}}},
            settings,
        )  # fmt: skip
        if gen.state != "succeeded":
            raise SystemExit(f"generate.merl failed: {gen.error}")
        gens[cseed] = gen
    if args.paper_steps:
        paper_step(settings, gens[args.seeds[0]], args.paper_steps)
        print(
            f"\n`.venv/bin/python benchmarks/bench_train_brdf.py --paper-steps {args.paper_steps}`"
        )
        return

    configs: list[dict[str, Any]] = []
    for model in args.models:
        if model == "analytic":
            configs.append({"model": "analytic"})
            continue
        for size in args.sizes:
            w, d = (int(x) for x in size.split("x"))
            configs.append({"model": model, "width": w, "depth": d, "latent_dim": args.latent})
            if model == "neural" and args.paper_neural:
                configs.append({**configs[-1], "neural_latent_dim": args.latent + 8})

    print(f"# {platform.node()} {platform.processor() or platform.machine()}, "
          f"{os.cpu_count()} cores, python {platform.python_version()}")  # fmt: skip
    print("| collection | model | MLP | per-material floats | seed | smape | smape_floor "
          "| smape f_a | irid. | blend | wall s | load avg |")  # fmt: skip
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    runs = ((cs, c, s) for cs in args.seeds for c in configs for s in args.train_seeds)
    for cseed, cfg, seed in runs:
        params = {"dataset": f"job:{gens[cseed].id}", "preset": "small", **cfg}
        if args.steps is not None:
            params["steps"] = args.steps
        if args.no_speed:
            params["speed"] = "off"
        t0 = time.perf_counter()
        job = run_in_process({"kind": "train.brdf", "seed": seed, "params": params},
                             settings)  # fmt: skip
        wall = time.perf_counter() - t0
        if job.state != "succeeded":
            print(f"| {cfg} | failed: {job.error} |")
            continue
        m = metrics_of(settings, job)
        fam = m["families"]
        (mats_digest,) = [a.digest for a in job.artifacts if a.name == "materials.json"]
        floats = json.loads(ArtifactStore(settings.store_dir).read(mats_digest))[
            "per_material_params"
        ]
        mlp = f"{cfg['width']}x{cfg['depth']}" if "width" in cfg else "-"
        print(
            f"| {cseed} | {cfg['model']} | {mlp} | {floats} | {seed} | {fmt(m['mean']['smape'])} "
            f"| {fmt(m['mean'].get('smape_floor'))} | {fmt(m['mean']['smape_analytic'])} "
            f"| {fmt(fam.get('iridescent', {}).get('smape'))} "
            f"| {fmt(fam.get('blend', {}).get('smape'))} | {wall:.0f} "
            f"| {os.getloadavg()[0]:.1f} |",
            flush=True,
        )
        label = f"c{cseed}-{cfg['model']}-{mlp}-s{seed}"
        if args.out is not None:
            args.out.mkdir(parents=True, exist_ok=True)
            (args.out / f"{label}.json").write_text(json.dumps(m, indent=1))
        if args.per_material:
            for r in m["materials"]:
                print(f"|   {label} | {r['name']} ({r['family']}) | smape {fmt(r['smape'])} "
                      f"| smape_floor {fmt(r.get('smape_floor'))} |", flush=True)  # fmt: skip
    print(f"\n`.venv/bin/python benchmarks/bench_train_brdf.py {' '.join(sys.argv[1:])}`".rstrip())
    if tmp is not None:
        tmp.cleanup()


if __name__ == "__main__":
    main()
