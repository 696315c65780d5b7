"""``generate.fabric`` end to end: sustained throughput and time per material at paper scale.

Runs the real job path (``service.submission.run_in_process``: spec validation, the local
process pool of ``MATFORGE_POOL_PROCESSES`` workers, shards, the artifact store) on a
temporary data directory, reads the job's ``stats.json`` (samples) and its manifest's
``timings.measured.throughput`` (wall seconds, samples per second) and
extrapolates linearly to the paper's per-material budget: Chen et al. 2024, Sec. 5.1, about
3.2 M queries x 2,048 samples per material in 22 minutes (4.96 M samples/s); the ``paper``
preset's 3,276,800 queries. The extrapolation assumes the cost per query is the same over the
whole design (the measured slice is whole rounds of the stratified design when ``--queries``
is a multiple of 20,480) and uses the job's wall time, overheads included (process start,
Dr.Jit compilation, EXR maps, the preview), so it is slightly pessimistic. Each configuration
runs ``--repeats`` times (``force``); the row gives the median and the range.

Run: ``.venv/bin/python benchmarks/bench_fabric_generate.py [--patterns twill_3x3]
[--queries 40960] [--samples 2048] [--shard-queries 4096]``; ``--preset small`` with no
``--queries`` measures the small preset as it is. Every run also prints the time of the
named preset's whole dataset (its materials x queries x samples) at the measured rate, e.g.
``--preset unseen --patterns plain twill_8x8 satin_5x10 --queries 20480 --samples 256``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import tempfile
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from generators.fabric.params import PRESETS, FabricGenParams, plan_sets  # noqa: E402
from service.settings import Settings  # noqa: E402
from service.submission import run_in_process  # noqa: E402
from storage.artifacts import ArtifactStore  # noqa: E402

PAPER_QUERIES = 3_276_800  # the paper preset (160 x 20480); Sec. 5.1 says "about 3.2 M"
PAPER_SAMPLES = 2048


def run_job(settings: Settings, params: dict[str, Any], force: bool) -> dict[str, Any]:
    """Run one job; its stats.json with its manifest's throughput
    (``timings.measured.throughput``: ``seconds``, ``samples_per_second``)."""
    job = run_in_process(
        {"kind": "generate.fabric", "seed": 0, "params": params, "force": force}, settings
    )
    if job.state != "succeeded":
        raise SystemExit(f"job {job.id} {job.state}: {job.error}")
    store = ArtifactStore(settings.store_dir)
    (digest,) = [a.digest for a in job.artifacts if a.name == "stats.json"]
    stats: dict[str, Any] = json.loads(store.read(digest))
    assert job.manifest_digest is not None
    stats.update(json.loads(store.read(job.manifest_digest))["timings"]["measured"]["throughput"])
    return stats


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="small", choices=tuple(PRESETS))
    ap.add_argument("--patterns", nargs="*", default=None, help="default: the preset's")
    ap.add_argument("--queries", type=int, default=None, help="queries per material")
    ap.add_argument("--samples", type=int, default=PAPER_SAMPLES)
    ap.add_argument("--sampler", default="sobol", choices=("sobol", "independent"))
    ap.add_argument("--shard-queries", type=int, default=None)
    ap.add_argument("--backend", default="drjit", choices=("drjit", "numpy"))
    ap.add_argument("--sizes", default="strata", choices=("strata", "log_uniform"))
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    params: dict[str, Any] = {
        "preset": args.preset,
        "samples": args.samples,
        "sampler": args.sampler,
        "backend": args.backend,
    }
    if args.sizes != "strata":
        params["sizes"] = args.sizes
    if args.patterns:
        params.update(patterns=args.patterns, texture_sets=1, shading_sets=1)
    if args.queries:
        params["queries_per_material"] = args.queries
    if args.shard_queries:
        params["shard_queries"] = args.shard_queries
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        settings = Settings.from_env(dict(os.environ)).with_(data_dir=Path(tmp) / "data")
        for i in range(args.repeats):
            stats = run_job(settings, params, force=i > 0)
            runs.append(stats)
            print(
                f"run {i + 1}: {stats['samples']:.3g} samples in {stats['seconds']:.2f} s, "
                f"{stats['samples_per_second'] / 1e6:.2f} M samples/s",
                file=sys.stderr,
                flush=True,
            )
    rates = [r["samples_per_second"] for r in runs]
    rate = statistics.median(rates)
    first = runs[0]
    per_material_q = first["queries"] // first["materials"]
    minutes = PAPER_QUERIES * PAPER_SAMPLES / rate / 60
    machine = (
        f"{platform.machine()}, {os.cpu_count()} cores, {settings.pool_processes} pool "
        f"processes, load {os.getloadavg()[0]:.1f}"
    )
    print(
        "| materials | queries/material | samples/query | sampler | backend | median s "
        "| M samples/s (median, range) | min per material at 3.28 M queries x 2048 "
        "(extrapolated) | vs paper 22 min | machine |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    print(
        f"| {first['materials']} | {per_material_q} | {first['samples_per_query']} | "
        f"{args.sampler} | {first['backend']} | "
        f"{statistics.median(r['seconds'] for r in runs):.2f} | {rate / 1e6:.2f} "
        f"({min(rates) / 1e6:.2f}-{max(rates) / 1e6:.2f}) | {minutes:.1f} | "
        f"{minutes / 22:.2f}x | {machine} |"
    )
    cmd = f"--preset {args.preset} --samples {args.samples} --sampler {args.sampler}"
    if args.patterns:
        cmd += " --patterns " + " ".join(args.patterns)
    if args.queries:
        cmd += f" --queries {args.queries}"
    if args.shard_queries:
        cmd += f" --shard-queries {args.shard_queries}"
    if args.sizes != "strata":
        cmd += f" --sizes {args.sizes}"
    # the preset's whole dataset at its own queries and samples, at the measured rate
    full = FabricGenParams(preset=args.preset).resolved()
    total = len(plan_sets(full)) * full.queries * full.samples
    print(
        f"\npreset {args.preset} in full: {len(plan_sets(full))} materials x {full.queries} "
        f"queries x {full.samples} samples = {total:.3g} samples: "
        f"{total / rate / 3600:.2f} h at the median rate "
        f"({total / max(rates) / 3600:.2f}-{total / min(rates) / 3600:.2f} h over the runs)"
    )
    print(
        f"\nreproduce: .venv/bin/python benchmarks/bench_fabric_generate.py {cmd} "
        f"--backend {args.backend} --repeats {args.repeats}"
    )


if __name__ == "__main__":
    main()
