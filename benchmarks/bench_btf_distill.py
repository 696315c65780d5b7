"""Does distillation (Eq. 5 of Xu et al. 2025) help the coarse-to-fine student? Fig. 11's
claim, with seeds and spread.

Runs, in-process through the job kinds (``generate.btf``, then ``train.btf``):

1. a procedural leather BTF at ``--res`` texels over ``--slices`` light x view pairs drawn
   (seeded) from UBO2014's 151 x 151 dome pairs;
2. one NeuMIP Max teacher (128 wide, ``--teacher-epochs``);
3. the arms, each at ``--seeds`` seeds (the job's seed: the student's initial weights,
   texture jitter and slice order):

   - ``c2f``: the student without distillation;
   - ``mse s/l``: distilled with the mean-squared-error hints (the default form), sigma =
     lambda_1 = lambda_2 as given;
   - ``std s/l``: distilled with the standardised hints, on the ``--grid`` of sigma x lambda.

Prints, per arm, the mean, sample std and min..max over seeds of the held-out L1 and the
whole-BTF L1, and each distilled arm's difference from ``c2f`` with its verdict: "helps" /
"hurts" only when the two arms' seed ranges do not overlap, else "not resolved". Writes
every run's numbers to ``--out``.

Run: ``nice -n 5 .venv/bin/python benchmarks/bench_btf_distill.py --data-dir D``
(defaults: 1024 pairs at 32^2, 12 epochs; about 30-40 minutes on 2 loaded cores).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))


def arms(grid_s: list[float], grid_l: list[float]) -> list[tuple[str, dict[str, Any] | None]]:
    """``(name, distill params without the teacher)`` of every arm, ``None``: undistilled."""
    out: list[tuple[str, dict[str, Any] | None]] = [("c2f", None)]
    out.append(("mse 0.1/0.1", {"sigma": 0.1, "lambda1": 0.1, "lambda2": 0.1}))
    for s in grid_s:
        for lam in grid_l:
            out.append(
                (
                    f"std {s:g}/{lam:g}",
                    {"sigma": s, "lambda1": lam, "lambda2": lam, "hint": "standardised"},
                )
            )
    return out


def verdict(a: list[float], b: list[float]) -> str:
    """``a`` (distilled) against ``b`` (undistilled), lower is better: outside the seed
    spread (the ranges do not overlap) or not resolved."""
    if max(a) < min(b):
        return "helps"
    if min(a) > max(b):
        return "hurts"
    return "not resolved"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data-dir", type=Path, required=True)
    ap.add_argument("--slices", type=int, default=1024)
    ap.add_argument("--res", type=int, default=32)
    ap.add_argument("--spp", type=int, default=8)
    ap.add_argument("--epochs", type=int, default=12)
    ap.add_argument("--teacher-epochs", type=int, default=12)
    ap.add_argument("--plateau-steps", type=int, default=2048)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--sigma", type=float, nargs="+", default=[0.1, 1.0])
    ap.add_argument("--lam", type=float, nargs="+", default=[0.1, 1.0])
    ap.add_argument("--out", type=Path, default=Path("btf_distill.json"))
    args = ap.parse_args()

    import numpy as np

    from materials.btf.directions import preset_pairs, to_angles
    from service.cli.batch import parse_batch
    from service.cli.batch_local import run_steps_in_process
    from service.settings import Settings
    from storage.artifacts import ArtifactStore

    wi, wo = preset_pairs("ubo2014")
    pick = np.sort(np.random.default_rng(2025).choice(len(wi), args.slices, replace=False))
    ti, pi = to_angles(wi[pick])
    to, po = to_angles(wo[pick])
    pairs = [
        [round(float(a), 6), round(float(b), 6), round(float(c), 6), round(float(d), 6)]
        for a, b, c, d in zip(ti, pi, to, po, strict=True)
    ]
    train = {"data": "step:leather", "preset": "small", "plateau_steps": args.plateau_steps}
    steps: list[dict[str, Any]] = [
        {
            "name": "leather",
            "spec": {
                "kind": "generate.btf",
                "seed": 1,
                "params": {
                    "surface": {"procedural": "leather"},
                    "directions": pairs,
                    "resolution": args.res,
                    "spp": args.spp,
                    "shard_slices": 256,
                },
            },
        },
        {
            "name": "teacher",
            "spec": {
                "kind": "train.btf",
                "seed": 0,
                "params": {**train, "model": "neumip_max", "epochs": args.teacher_epochs},
            },
        },
    ]
    plan = arms(args.sigma, args.lam)
    for name, d in plan:
        for seed in range(args.seeds):
            params: dict[str, Any] = {**train, "model": "c2f", "epochs": args.epochs}
            if d is not None:
                params["distill"] = {"teacher": "step:teacher", **d}
            steps.append(
                {
                    "name": f"{name.replace(' ', '_').replace('/', '_')}_s{seed}",
                    "spec": {"kind": "train.btf", "seed": seed, "params": params},
                }
            )
    batch = parse_batch({"steps": steps}, "bench_btf_distill")
    settings = Settings.from_env({}).with_(data_dir=args.data_dir, pool_processes=1)
    started = time.perf_counter()

    def done(step: Any, job: Any, seconds: float) -> None:
        print(f"  {step.name}: {seconds:.0f} s; {job.message}", file=sys.stderr, flush=True)

    jobs = run_steps_in_process(batch.steps, settings, on_step=done)
    store = ArtifactStore(settings.store_dir)

    def metrics(step: str) -> dict[str, Any]:
        (digest,) = [a.digest for a in jobs[step].artifacts if a.name == "metrics.json"]
        return dict(json.loads(store.read(digest)))

    teacher = metrics("teacher")
    results: dict[str, list[dict[str, float]]] = {}
    for name, _ in plan:
        for seed in range(args.seeds):
            m = metrics(f"{name.replace(' ', '_').replace('/', '_')}_s{seed}")
            results.setdefault(name, []).append(
                {"seed": seed, "l1": m["l1"], "l1_heldout": m["l1_heldout"]}
            )
    base = [r["l1_heldout"] for r in results["c2f"]]
    table = []
    print(
        f"\nteacher: held-out L1 {teacher['l1_heldout']:.5f}; {args.slices} pairs at "
        f"{args.res}^2, {args.epochs} epochs, {args.seeds} seeds, load "
        f"{os.getloadavg()[0]:.2f}, {time.perf_counter() - started:.0f} s\n"
    )
    print("| arm | held-out L1 mean | std | min..max | vs c2f | verdict |")
    print("|---|---|---|---|---|---|")
    for name, rs in results.items():
        v = [r["l1_heldout"] for r in rs]
        mean, sd = statistics.fmean(v), statistics.stdev(v) if len(v) > 1 else 0.0
        rel = mean / statistics.fmean(base) - 1.0
        ver = "" if name == "c2f" else verdict(v, base)
        table.append({"arm": name, "mean": mean, "std": sd, "min": min(v), "max": max(v),
                      "vs_c2f": rel, "verdict": ver, "runs": rs})  # fmt: skip
        print(
            f"| {name} | {mean:.5f} | {sd:.5f} | {min(v):.5f}..{max(v):.5f} | "
            f"{100 * rel:+.1f} % | {ver} |"
        )
    args.out.write_text(
        json.dumps(
            {
                "args": {k: str(v) for k, v in vars(args).items()},
                "teacher": teacher,
                "arms": table,
                "load": os.getloadavg()[0],
            },
            indent=2,
        )  # fmt: skip
    )


if __name__ == "__main__":
    main()
