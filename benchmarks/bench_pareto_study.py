"""``report.pareto``, ``report.stability`` and ``select`` over a small real BRDF study.

Runs, in one data directory (jobs already there are reused): the ``small`` MERL collection
(seed 0); ``train.brdf`` analytic with ``--analytic-steps`` steps (300: the issue's
under-trained GGX fit), hybrid 16x3 and neural 16x3 with the ``small`` preset (seed 0); then
``report.pareto``, ``report.stability`` and ``select`` (SMAPE <= ``--target`` by ns/eval)
over the three runs. Prints one markdown row per run (error, ns/eval, front, convergence,
NaN/Inf, albedo, reciprocity), the claims and the selection, and the command.

    .venv/bin/python benchmarks/bench_pareto_study.py --data-dir /tmp/pareto-study
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from service.settings import Settings  # noqa: E402
from service.submission import run_in_process  # noqa: E402
from storage.artifacts import ArtifactStore  # noqa: E402
from storage.jobs import Job  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data-dir", type=Path, required=True)
    ap.add_argument("--analytic-steps", type=int, default=300)
    ap.add_argument("--target", type=float, default=0.2)
    args = ap.parse_args()
    settings = Settings.from_env({}).with_(data_dir=args.data_dir, pool_processes=1)
    (settings.data_dir / "scratch").mkdir(parents=True, exist_ok=True)
    store = ArtifactStore(settings.store_dir)

    def run(spec: dict[str, Any]) -> Job:
        start = time.perf_counter()
        job = run_in_process(spec, settings)
        if job.state != "succeeded":
            raise SystemExit(f"{spec['kind']}: {job.error}")
        print(f"{spec['kind']}: {time.perf_counter() - start:.0f} s", file=sys.stderr)
        return job

    def read(job: Job, name: str) -> Any:
        (digest,) = [a.digest for a in job.artifacts if a.name == name]
        return json.loads(store.read(digest))

    gen = run({"kind": "generate.merl", "seed": 0, "params": {"collection": {"preset": "small"}}})
    base = {"dataset": f"job:{gen.id}", "preset": "small"}
    runs = [
        run(
            {
                "kind": "train.brdf",
                "seed": 0,
                "params": {**base, "model": "analytic", "steps": args.analytic_steps},
            }
        )
    ]
    for model in ("hybrid", "neural"):
        runs.append(
            run(
                {
                    "kind": "train.brdf",
                    "seed": 0,
                    "params": {**base, "model": model, "width": 16, "depth": 3},
                }
            )
        )
    refs = [f"job:{j.id}" for j in runs]
    pareto = read(run({"kind": "report.pareto", "params": {"runs": refs}}), "pareto.json")
    stab = read(run({"kind": "report.stability", "params": {"runs": refs}}), "stability.json")
    sel = read(
        run(
            {
                "kind": "select",
                "params": {
                    "runs": refs,
                    "metric": "smape",
                    "target": args.target,
                    "cost": "ns_per_eval",
                },
            }
        ),
        "select.json",
    )
    (panel,) = [
        p for p in pareto["panels"] if (p["metric"], p["cost"]) == ("brdf.smape", "ns_per_eval")
    ]
    points = {p["candidate"]: p for p in panel["points"]}
    print(
        "| run | mean SMAPE | ns/eval | on the front | loss change, 2nd half / last tenth | "
        "flattened | NaN/Inf | max albedo | reciprocity error |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for r in stab["runs"]:
        p, c = points[r["candidate"]], r["convergence"]
        steps = args.analytic_steps if r["candidate"] == "analytic" else "small preset"
        print(
            f"| {r['candidate']} ({steps}) | {r['error']:.4f} | {p['cost']:.1f} | "
            f"{'yes' if p['front'] else 'no'} | -{100 * c['second_half_drop']:.1f} % / "
            f"-{100 * c['last_tenth_drop']:.1f} % | {c['flattened']} | "
            f"{r['nonfinite_total']} | {r['albedo_max']:.3f} | "
            f"{r['reciprocity_error']:.2g} |"
        )
    for claim in pareto["claims"]:
        print(f"- {claim['claim']}: {claim['holds']} ({claim['why']})")
    for lad in sel["ladders"]:
        print(f"- select SMAPE <= {args.target:g}: {lad['chosen']} ({lad['why']})")
    print(f"\n.venv/bin/python benchmarks/bench_pareto_study.py --data-dir {args.data_dir}")


if __name__ == "__main__":
    main()
