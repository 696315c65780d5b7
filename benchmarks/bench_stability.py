"""Where the trained models fail, per family and failure case: ``report.stability`` over the
BTF and fabric models of ``scripts/btf_eval.yaml`` and ``scripts/fabric_eval.yaml``.

Runs, in-process (a step whose spec already ran in ``--data-dir`` is reused, so it resumes):

- **BTF**: the recipe's leather (UBO2014's 151 x 151 pairs at 32 x 32 texels, 16 spp), the
  4-lobe Lafortune fit, NeuMIP 25 and 8 wide and the coarse-to-fine student, each network
  for ``--btf-epochs`` epochs (the recipe: 8; the 128-wide teacher and the distilled student
  are left out: they alone take most of the recipe's 75 minutes), then ``report.stability``
  over them: relative L1 on the strongly shadowed slices (light 50+ degrees from the
  normal), the near-specular ones (half vector within 12 degrees of it) and the rest;
- **glint**: the recipe's six example types, each its tiny-example render against the Yan
  reference (Table 3's scores), then ``report.stability``: the tiny model's FLIP per type
  against its mean over the types;
- **fabric**: the recipe's dataset and network (6,000 steps) and its seen / unseen renders
  and scores (Sec. 6), then ``report.stability``: the network's held-out RGB error per weave
  pattern and footprint size, and each method's FLIP on the seen and the unseen material.

Prints, per kind, the heat table as markdown (a cell: the family's error and its ratio to the
model's whole-set error; above 1, the model does worse there than on average) and each run's
convergence verdict, and writes ``stability.png`` of each ``report.stability`` job to
``--png-dir``.

Run: ``.venv/bin/python benchmarks/bench_stability.py [--data-dir DIR] [--btf-epochs 2]
[--only btf|fabric|glint] [--png-dir .]``
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from materials.glints.examples import TYPES as GLINT_TYPES  # noqa: E402

SCRIPTS = Path(__file__).resolve().parent.parent / "scripts"
#: Per family: the recipe and the steps of it that run here (the stability step last).
PLANS = {
    "btf": (SCRIPTS / "btf_eval.yaml", ("leather", "lafortune", "neumip", "neumip8", "c2f")),
    "glint": (
        SCRIPTS / "glint_eval.yaml",
        tuple(f"{t}{part}" for t in GLINT_TYPES for part in ("", "_tiny", "_yan", "_score")),
    ),
    "fabric": (
        SCRIPTS / "fabric_eval.yaml",
        ("dataset", "model")
        + tuple(
            f"{m}_{r}"
            for m in ("seen", "unseen")
            for r in ("gt", "mc1", "mc_eq", "net16", "net1", "scores")
        ),
    ),  # fmt: skip
}


def run_family(family: str, data_dir: Path, btf_epochs: int) -> tuple[Any, dict[str, Any]]:
    """Run the family's steps and its ``stability`` step over the trained runs among them."""
    from service.cli.batch import load_batch
    from service.cli.batch_local import StepFailed, run_steps_in_process
    from service.settings import Settings

    recipe, names = PLANS[family]
    steps = {s.name: s for s in load_batch(recipe).steps}
    kept = [steps[n] for n in names]
    # the recipe's stability step over the runs among the kept steps, with their labels
    stab = steps["stability"]
    runs = stab.spec["params"]["runs"]
    labels = stab.spec["params"].get("labels") or [None] * len(runs)
    pairs = [(r, lab) for r, lab in zip(runs, labels, strict=True) if r[len("step:") :] in names]
    params = {**stab.spec["params"], "runs": [r for r, _ in pairs]}
    if stab.spec["params"].get("labels"):
        params["labels"] = [lab for _, lab in pairs]
    kept.append(dataclasses.replace(stab, spec={**stab.spec, "params": params}))

    def transform(spec: dict[str, Any]) -> dict[str, Any]:
        params = spec["params"]
        if spec["kind"] == "train.btf" and params.get("model") != "lafortune":
            return {**spec, "params": {**params, "epochs": btf_epochs}}
        return spec

    def done(step: Any, job: Any, seconds: float) -> None:
        print(f"  {family}/{step.name}: {seconds:.0f} s; {job.message}", file=sys.stderr)

    settings = Settings.from_env({}).with_(data_dir=data_dir, pool_processes=2)
    try:
        jobs = run_steps_in_process(kept, settings, transform=transform, on_step=done)
    except StepFailed as exc:
        sys.exit(str(exc))
    return settings, jobs


def artifact(settings: Any, job: Any, name: str) -> bytes:
    from storage.artifacts import ArtifactStore

    (digest,) = [a.digest for a in job.artifacts if a.name == name]
    return ArtifactStore(settings.store_dir).read(digest)


def print_tables(doc: dict[str, Any]) -> None:
    """The heat table per kind (markdown) and the runs' convergence."""
    for kind in dict.fromkeys(f["kind"] for f in doc["families"]):
        cells = [f for f in doc["families"] if f["kind"] == kind]
        cands = list(dict.fromkeys(str(f["candidate"]) for f in cells))
        fams = list(dict.fromkeys(f["family"] for f in cells))
        metric = cells[0]["metric"]
        base = "its mean over the scores" if kind == "score" else f"the model's whole-set {metric}"
        print(f"\n{kind}: {metric} per family (ratio to {base})\n")
        head = "mean over the scores" if kind == "score" else "whole set"
        print(f"| model | {head} | " + " | ".join(fams) + " |")
        print("| --- | --- | " + " | ".join("---" for _ in fams) + " |")
        for cand in cands:
            mine = {f["family"]: f for f in cells if str(f["candidate"]) == cand}
            whole = next(iter(mine.values()))["whole"]
            row = [
                f"{mine[f]['mean']:.4g} ({mine[f]['ratio']:.2f}x)"
                if f in mine and mine[f]["ratio"]
                else "-"
                for f in fams
            ]
            print(f"| {cand} | {whole:.4g} | " + " | ".join(row) + " |")
    trained = [r for r in doc["runs"] if r["kind"] != "score"]  # score runs: no training
    if trained:
        print("\n| run | candidate | error | flattened | loss change, 2nd half |")
        print("| --- | --- | --- | --- | --- |")
    for r in trained:
        conv = r["convergence"]
        drop = conv.get("second_half_drop")
        print(f"| {r['run']} | {r['candidate']} | {r['error']:.4g} | {conv.get('flattened')} | "
              f"{'-' if drop is None else f'{-100 * drop:+.1f} %'} |")  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-dir", type=Path, default=Path("stability-data"))
    parser.add_argument("--btf-epochs", type=int, default=2)
    parser.add_argument("--only", choices=sorted(PLANS), action="append")
    parser.add_argument("--png-dir", type=Path, default=Path("."))
    args = parser.parse_args()
    load = os.getloadavg()
    print(f"# load average {load[0]:.1f} at start, {time.strftime('%Y-%m-%d %H:%M UTC')}")
    for family in args.only or sorted(PLANS):
        started = time.perf_counter()
        settings, jobs = run_family(family, args.data_dir, args.btf_epochs)
        job = jobs["stability"]
        doc = json.loads(artifact(settings, job, "stability.json"))
        print(f"\n## {family} ({time.perf_counter() - started:.0f} s)")
        print_tables(doc)
        out = args.png_dir / f"stability_{family}.png"
        out.write_bytes(artifact(settings, job, "stability.png"))
        print(f"\nwrote {out}")
    print(f"# load average {os.getloadavg()[0]:.1f} at the end")


if __name__ == "__main__":
    main()
