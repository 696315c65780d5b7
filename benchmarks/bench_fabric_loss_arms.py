"""``train.fabric`` loss arms on the same seeds: today's relative L2 against ``relative_l2_mean``.

``generate.fabric`` ``small`` (seed 0; 3 materials x 1280 queries, with stored Monte Carlo
standard errors), then ``train.fabric`` with the ``medium`` preset's architecture and
``--steps`` SGD steps, once per ``--seeds`` (default 0 1 2) and per ``--losses`` arm, through
the registry as ``matforge run`` does, in a temporary data directory. Per arm: the held-out
relative L2 and per-component relative L1, and the held-out mean ratio ``sum pred / sum gt``
of the specular components and of the Eq. 8 RGB value (the goal: within +-3 %), as mean and
spread (min..max) over the seeds. A difference inside the spreads is "not resolved".

The machine is shared with other work: the load average is printed with the table.

The two additions of ``relative_l2_mean`` each alone: ``--losses relative_l2
relative_l2_stderr relative_l2_meanterm relative_l2_mean`` (neither, the Monte Carlo
weights only, the mean term only, both).

Run: ``nice -n 5 .venv/bin/python benchmarks/bench_fabric_loss_arms.py [--steps 1500]
[--seeds 0 1 2] [--losses relative_l2 relative_l2_mean] [--out runs.json]``
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

#: Held-out figures per arm: label and how to read it from metrics.json's ``mean``.
FIGURES = (
    ("relative L2", lambda m: m["relative_l2"]),
    ("C_warp rel", lambda m: m["C_warp"]["rel"]),
    ("C_weft rel", lambda m: m["C_weft"]["rel"]),
    ("S_warp rel", lambda m: m["S_warp"]["rel"]),
    ("S_weft rel", lambda m: m["S_weft"]["rel"]),
    ("S_warp mean ratio", lambda m: m["S_warp"]["ratio"]),
    ("S_weft mean ratio", lambda m: m["S_weft"]["ratio"]),
    ("RGB mean ratio", lambda m: m["rgb"]["ratio"]),
)


def run_arms(steps: int, seeds: list[int], losses: list[str]) -> dict[str, list[dict[str, Any]]]:
    from service.settings import Settings
    from service.submission import run_in_process
    from storage.artifacts import ArtifactStore

    with tempfile.TemporaryDirectory() as tmp:
        settings = Settings.from_env({}).with_(data_dir=Path(tmp), pool_processes=2)
        gen_spec = {"kind": "generate.fabric", "seed": 0, "params": {"preset": "small"}}
        gen = run_in_process(gen_spec, settings)
        if gen.state != "succeeded":
            sys.exit(f"generate.fabric failed: {gen.error}")
        out: dict[str, list[dict[str, Any]]] = {loss: [] for loss in losses}
        for seed in seeds:
            for loss in losses:
                params = {"dataset": f"job:{gen.id}", "preset": "medium", "steps": steps,
                          "loss": loss}  # fmt: skip
                start = time.perf_counter()
                job = run_in_process({"kind": "train.fabric", "seed": seed, "params": params},
                                     settings)  # fmt: skip
                wall = time.perf_counter() - start
                if job.state != "succeeded":
                    sys.exit(f"train.fabric ({loss}, seed {seed}) failed: {job.error}")
                (digest,) = [a.digest for a in job.artifacts if a.name == "metrics.json"]
                mean = json.loads(ArtifactStore(settings.store_dir).read(digest))["mean"]
                out[loss].append({"seed": seed, "wall_s": wall, "mean": mean})
                print(f"  seed {seed} {loss}: {wall:.0f} s", flush=True)
        return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=1500)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--losses", nargs="+", default=["relative_l2", "relative_l2_mean"])
    parser.add_argument("--out", default=None, help="write every run's figures as JSON")
    args = parser.parse_args()
    print(f"load average before: {os.getloadavg()[0]:.2f}, cores: {os.cpu_count()}")
    arms = run_arms(args.steps, args.seeds, args.losses)
    if args.out:
        Path(args.out).write_text(json.dumps(arms, indent=1))
    print(f"\ntrain.fabric medium architecture, {args.steps} steps, small dataset, seeds "
          f"{args.seeds} (load average now {os.getloadavg()[0]:.2f})")  # fmt: skip
    print("| held-out figure | " + " | ".join(f"{a} mean (min..max)" for a in arms) + " |")
    print("| --- |" + " --- |" * len(arms))
    for label, get in FIGURES:
        cells = []
        for runs in arms.values():
            v = [float(get(r["mean"])) for r in runs]
            cells.append(f"{np.mean(v):.3f} ({min(v):.3f}..{max(v):.3f})")
        print(f"| {label} | " + " | ".join(cells) + " |")
    walls = {a: float(np.median([r["wall_s"] for r in runs])) for a, runs in arms.items()}
    print("| median job wall s | " + " | ".join(f"{w:.0f}" for w in walls.values()) + " |")


if __name__ == "__main__":
    main()
