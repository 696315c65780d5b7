"""``train.fabric`` on the ``beta`` preset with betas held out: the beta response on them.

``generate.fabric`` ``beta`` (seed 0; ``--patterns``, 16 materials per pattern differing only
in beta, 0.1-1; ``--queries`` queries and ``--samples`` samples per query), then
``train.fabric`` with the ``--arch`` preset's architecture for ``--steps`` SGD steps, once
per ``--seeds``, with ``held_out_beta`` ``--held-out`` (those materials are never trained
on). Per pattern and component: the slope of the held-out materials' mean against beta,
Monte Carlo's and the network's (metrics.json ``beta_response``), as mean and spread
(min..max) over the seeds, and how many seeds meet the goal (the network has Monte Carlo's
sign and at least half its size). Monte Carlo's slope comes with its standard error (the
spread of the per-query slopes over sqrt(queries): the preset's materials share one query
set) and whether its sign is resolved (``|slope| > 2 SE``); beside it the Monte Carlo
noise alone (from the stored standard errors).

``--arms``: ``base`` (the ``--arch`` preset as it is) and/or ``param_skip`` (the same with
``param_skip``: the scalar parameters alpha, beta, w beside the latent code), each trained
on the one generated dataset. ``--out`` writes every run's ``beta_response`` as JSON.

The machine is shared with other work: the load average is printed with the table.

Run: ``nice -n 5 .venv/bin/python benchmarks/bench_fabric_held_out_beta.py [--steps 1500]
[--seeds 0 1 2] [--patterns twill_3x3] [--held-out 0.4 0.7] [--arms base param_skip]
[--out runs.json]``
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
        for arm in args.arms:
            for seed in args.seeds:
                params = {"dataset": f"job:{gen.id}", "preset": args.arch, "steps": args.steps,
                          "held_out_beta": args.held_out}  # fmt: skip
                if arm == "param_skip":
                    params["param_skip"] = True
                start = time.perf_counter()
                job = run_in_process({"kind": "train.fabric", "seed": seed, "params": params},
                                     settings)  # fmt: skip
                wall = time.perf_counter() - start
                if job.state != "succeeded":
                    sys.exit(f"train.fabric ({arm}, seed {seed}) failed: {job.error}")
                (digest,) = [a.digest for a in job.artifacts if a.name == "metrics.json"]
                metrics = json.loads(ArtifactStore(settings.store_dir).read(digest))
                out.append({"arm": arm, "seed": seed, "wall_s": wall,
                            "response": metrics["beta_response"]})  # fmt: skip
                print(f"  {arm} seed {seed}: {wall:.0f} s (load average "
                      f"{os.getloadavg()[0]:.2f})", flush=True)  # fmt: skip
                if args.out:
                    Path(args.out).write_text(json.dumps(out, indent=1))
        return out


def table(runs: list[dict[str, Any]]) -> None:
    """One arm's table per pattern: Monte Carlo's slope +- SE, the model's over seeds."""
    for p, entry in enumerate(runs[0]["response"]):
        print(f"\n{entry['pattern']}, held-out betas {[round(b, 3) for b in entry['beta']]}, "
              f"{entry.get('queries')} queries, paired {entry.get('paired')}")  # fmt: skip
        print("| component | Monte Carlo slope +- SE (noise SE) | MC sign resolved | "
              "model slope mean (min..max) | model SE | ratio mean (min..max) | "
              "goal per seed |")  # fmt: skip
        print("| --- | --- | --- | --- | --- | --- | --- |")
        for name in NAMES:
            e = [r["response"][p][name] for r in runs]
            mc, se, noise = (e[0][k] for k in ("slope_monte_carlo", "se_slope_monte_carlo",
                                               "se_slope_noise"))  # fmt: skip
            nn = [x["slope_model"] for x in e]
            ratio = [x["slope_ratio"] for x in e]
            goal = " ".join("yes" if x["goal"] else "no" for x in e)
            print(f"| {name} | {mc:.4g} +- {se:.2g} ({noise:.2g}) | "
                  f"{'yes' if e[0]['sign_resolved'] else 'no'} | "
                  f"{np.mean(nn):.4g} ({min(nn):.4g}..{max(nn):.4g}) | "
                  f"{np.mean([x['se_slope_model'] for x in e]):.2g} | "
                  f"{np.mean(ratio):.3f} ({min(ratio):.3f}..{max(ratio):.3f}) | "
                  f"{goal} ({sum(x['goal'] for x in e)}/{len(e)}) |")  # fmt: skip
    print(f"\nmedian train.fabric wall s: {np.median([r['wall_s'] for r in runs]):.0f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=1500)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--patterns", nargs="+", default=["twill_3x3"])
    parser.add_argument("--held-out", type=float, nargs="+", default=[0.4, 0.7])
    parser.add_argument("--queries", type=int, default=1280)
    parser.add_argument("--samples", type=int, default=256)
    parser.add_argument("--arch", default="medium")
    parser.add_argument("--arms", nargs="+", choices=["base", "param_skip"], default=["base"])
    parser.add_argument("--out", default=None)
    args = parser.parse_args()
    print(f"load average before: {os.getloadavg()[0]:.2f}, cores: {os.cpu_count()}")
    runs = run(args)
    print(f"\ntrain.fabric {args.arch}, {args.steps} steps, beta preset {args.patterns}, "
          f"{args.queries} queries x {args.samples} samples, held out {args.held_out}, seeds "
          f"{args.seeds} (load average now {os.getloadavg()[0]:.2f})")  # fmt: skip
    for arm in args.arms:
        print(f"\n### arm {arm}")
        table([r for r in runs if r["arm"] == arm])


if __name__ == "__main__":
    main()
