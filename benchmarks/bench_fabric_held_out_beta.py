"""``train.fabric`` on the ``beta`` preset with betas held out: the beta response on them.

``generate.fabric`` ``beta`` (seed 0; ``--patterns``, 16 materials per pattern differing only
in beta, 0.1-1; ``--queries`` queries and ``--samples`` samples per query), then
``train.fabric`` with the ``--arch`` preset's architecture for ``--steps`` SGD steps, once
per ``--seeds``, with ``held_out_beta`` ``--held-out`` (those materials are never trained
on). Per pattern and component: the slope of the held-out queries' mean against beta,
Monte Carlo's and the network's (metrics.json ``beta_response``), as mean and spread
(min..max) over the seeds, and how many seeds meet the goal (the network has Monte Carlo's
sign and at least half its size).

The machine is shared with other work: the load average is printed with the table.

Run: ``nice -n 5 .venv/bin/python benchmarks/bench_fabric_held_out_beta.py [--steps 1500]
[--seeds 0 1 2] [--patterns twill_3x3] [--held-out 0.4 0.7]``
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

NAMES = ("C_warp", "C_weft", "S_warp", "S_weft", "rgb")


def run(args: argparse.Namespace) -> list[dict[str, Any]]:
    from service.settings import Settings
    from service.submission import run_in_process
    from storage.artifacts import ArtifactStore

    with tempfile.TemporaryDirectory() as tmp:
        settings = Settings.from_env({}).with_(data_dir=Path(tmp), pool_processes=2)
        data = {"preset": "beta", "patterns": args.patterns,
                "queries_per_material": args.queries, "samples": args.samples}  # fmt: skip
        start = time.perf_counter()
        gen = run_in_process({"kind": "generate.fabric", "seed": 0, "params": data}, settings)
        if gen.state != "succeeded":
            sys.exit(f"generate.fabric failed: {gen.error}")
        print(f"  generate.fabric: {time.perf_counter() - start:.0f} s", flush=True)
        out = []
        for seed in args.seeds:
            params = {"dataset": f"job:{gen.id}", "preset": args.arch, "steps": args.steps,
                      "held_out_beta": args.held_out}  # fmt: skip
            start = time.perf_counter()
            job = run_in_process({"kind": "train.fabric", "seed": seed, "params": params},
                                 settings)  # fmt: skip
            wall = time.perf_counter() - start
            if job.state != "succeeded":
                sys.exit(f"train.fabric (seed {seed}) failed: {job.error}")
            (digest,) = [a.digest for a in job.artifacts if a.name == "metrics.json"]
            metrics = json.loads(ArtifactStore(settings.store_dir).read(digest))
            out.append({"seed": seed, "wall_s": wall, "response": metrics["beta_response"]})
            print(f"  seed {seed}: {wall:.0f} s", flush=True)
        return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=1500)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--patterns", nargs="+", default=["twill_3x3"])
    parser.add_argument("--held-out", type=float, nargs="+", default=[0.4, 0.7])
    parser.add_argument("--queries", type=int, default=1280)
    parser.add_argument("--samples", type=int, default=256)
    parser.add_argument("--arch", default="medium")
    args = parser.parse_args()
    print(f"load average before: {os.getloadavg()[0]:.2f}, cores: {os.cpu_count()}")
    runs = run(args)
    print(f"\ntrain.fabric {args.arch}, {args.steps} steps, beta preset {args.patterns}, "
          f"{args.queries} queries x {args.samples} samples, held out {args.held_out}, seeds "
          f"{args.seeds} (load average now {os.getloadavg()[0]:.2f})")  # fmt: skip
    for p, entry in enumerate(runs[0]["response"]):
        print(f"\n{entry['pattern']}, held-out betas {[round(b, 3) for b in entry['beta']]}")
        print("| component | Monte Carlo slope | model slope mean (min..max) | ratio mean "
              "(min..max) | seeds meeting the goal |")  # fmt: skip
        print("| --- | --- | --- | --- | --- |")
        for name in NAMES:
            mc = [r["response"][p][name]["slope_monte_carlo"] for r in runs]
            nn = [r["response"][p][name]["slope_model"] for r in runs]
            ratio = [r["response"][p][name]["slope_ratio"] for r in runs]
            goal = sum(bool(r["response"][p][name]["goal"]) for r in runs)
            print(f"| {name} | {np.mean(mc):.4g} | {np.mean(nn):.4g} ({min(nn):.4g}..{max(nn):.4g})"
                  f" | {np.mean(ratio):.3f} ({min(ratio):.3f}..{max(ratio):.3f}) | "
                  f"{goal}/{len(runs)} |")  # fmt: skip
    print(f"\nmedian train.fabric wall s: {np.median([r['wall_s'] for r in runs]):.0f}")


if __name__ == "__main__":
    main()
