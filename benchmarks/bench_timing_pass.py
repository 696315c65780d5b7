"""``scripts/timing_pass.yaml``'s timing pass run twice, at two loads: does a model's cost
relative to the reference kernel hold?

Runs the recipe (two MERL tables; analytic, hybrid 16x2, hybrid 32x3, neural 32x3 fitted
briefly), then its ``pareto`` step twice more with ``force`` (a new job each time, the same
spec): once as the machine is, once with ``--busy`` extra processes spinning on the CPU
beside it (at the same priority). Each run's ``pareto.json`` holds its timing pass: every
model's fused kernel and Mitsuba's ``roughconductor`` on the same 2^20 direction pairs,
interleaved, ``--repeats`` rounds. Prints one row per model: per run its median ns per
evaluation by the pass's clock (process CPU time over the threads; min..max), its median
ratio to the reference kernel (IQR), how much the ratio moved between the runs, and the
same for the wall clock recorded beside it (ratio of medians); then the load average before
and after each run.

Run: ``nice -n 10 .venv/bin/python benchmarks/bench_timing_pass.py [--busy 2] [--repeats 15]``
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

SPIN = "import time\nend = time.time() + {s}\nwhile time.time() < end:\n    pass\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--data-dir", type=Path, default=None)
    ap.add_argument("--steps", type=int, default=500, help="training steps per model")
    ap.add_argument("--repeats", type=int, default=15)
    ap.add_argument("--busy", type=int, default=2, help="spinning processes in the 2nd run")
    args = ap.parse_args()

    from service import kinds
    from service.cli.batch import load_batch
    from service.cli.batch_local import run_steps_in_process
    from service.settings import Settings
    from service.submission import run_in_process
    from storage.artifacts import ArtifactStore

    kinds.load_builtin()
    folder = args.data_dir or Path(tempfile.mkdtemp(prefix="bench-timing-pass-"))
    conf = Settings.from_env({}).with_(data_dir=folder, pool_processes=1)
    steps = [s for s in load_batch(ROOT / "scripts" / "timing_pass.yaml").steps
             if s.name != "select"]  # fmt: skip

    def shrink(spec: dict[str, Any]) -> dict[str, Any]:
        if spec["kind"] == "train.brdf":
            spec = {**spec, "params": {**spec["params"], "steps": args.steps}}
        return spec

    jobs = run_steps_in_process(steps, conf, transform=shrink)
    failed = {n: j.error for n, j in jobs.items() if j.state != "succeeded"}
    if failed:
        raise SystemExit(f"steps failed: {failed}")
    store = ArtifactStore(conf.store_dir)
    base = jobs["pareto"].spec["params"]
    spec = {"kind": "report.pareto", "force": True,
            "params": {**base, "timing": {**base["timing"], "repeats": args.repeats}}}  # fmt: skip

    def one_run(busy: int) -> dict[str, Any]:
        spinners = [
            subprocess.Popen([sys.executable, "-c", SPIN.format(s=600)]) for _ in range(busy)
        ]
        try:
            if busy:
                time.sleep(20)  # let the load average see them
            job = run_in_process(spec, conf)
        finally:
            for p in spinners:
                p.terminate()
                p.wait()
        if job.state != "succeeded":
            raise SystemExit(f"pareto failed: {job.error}")
        (digest,) = [a.digest for a in job.artifacts if a.name == "pareto.json"]
        return dict(json.loads(store.read(digest))["timing"])

    runs = [one_run(0), one_run(args.busy)]
    names = [n for n in runs[0]["costs"] if n != runs[0]["reference"]]
    print("| model | run 1 ns/eval (min..max) | run 1 x ref (IQR) | "
          f"run 2 (+{args.busy} busy) ns/eval (min..max) | run 2 x ref (IQR) "
          "| ratio moved | wall ns/eval run 1, run 2 | wall ratio moved |")  # fmt: skip
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    ref = runs[0]["reference"]
    for name in [ref, *names]:
        cells, rels, walls, wall_rel = [], [], [], []
        for rec in runs:
            c = rec["costs"][name]
            d, r = c["distribution"], c["relative"]
            cells += [f"{d['median']:.2f} ({d['min']:.2f}..{d['max']:.2f})",
                      f"{r['median']:.2f} ({r['iqr']:.2f})"]  # fmt: skip
            rels.append(r["median"])
            walls.append(c["wall"]["median"])
            wall_rel.append(c["wall"]["median"] / rec["costs"][ref]["wall"]["median"])
        moved = abs(rels[1] - rels[0]) / rels[0] * 100
        wall_moved = abs(wall_rel[1] - wall_rel[0]) / wall_rel[0] * 100
        print(f"| {name} | {' | '.join(cells)} | {moved:.1f} % | {walls[0]:.2f}, {walls[1]:.2f} "
              f"| {wall_moved:.1f} % |")  # fmt: skip
    for i, rec in enumerate(runs, 1):
        m = rec["machine"]
        print(f"run {i}: load {m['load_before']} -> {m['load_after']}, {m['processor']}, "
              f"{m['cores']} cores, {m['threads']} threads, "
              f"{m['runtimes'].get('mitsuba_variant')}")  # fmt: skip
    print(f"command: nice -n 10 .venv/bin/python benchmarks/bench_timing_pass.py "
          f"--busy {args.busy} --repeats {args.repeats} --steps {args.steps}")  # fmt: skip


if __name__ == "__main__":
    main()
