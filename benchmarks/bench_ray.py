"""``generate.fabric`` through Ray against the local process pool, on this one machine.

Runs the real job path (spec validation, ``JobContext.map_shards``, the artifact store, the
manifest) with one long-lived executor per backend, as a worker holds it: the local pool of
``--cpus`` spawned processes (``MATFORGE_EXECUTOR=process``), and Ray tasks on a private
local Ray of ``--cpus`` CPUs (``MATFORGE_EXECUTOR=ray``, one node, token auth, no
dashboard). Each backend first runs one small warm-up job (process start, imports, Dr.Jit's
kernel compilation), then ``--repeats`` timed jobs of the same spec (``force``), the two
backends interleaved so that the load of this shared machine falls on both alike. A job's
throughput is its samples over its wall time (the manifest's ``timings.measured.throughput``,
overheads included); the rows
give the median and the range, and the Ray/pool ratio of the medians (the goal is >= 0.9x).

Then the extrapolation for the fabric paper's dataset (Chen et al. 2024, Sec. 5.1: 465
materials x 3.2 M queries x 2,048 samples; the ``paper`` preset's 3,276,800 queries; 165 h
on the authors' machine) on N nodes of this machine's size, at Ray's measured rate per node,
assuming linear scaling. What bounds that assumption is measured too: the job's own thread
stores every shard (SHA-256, CAS write with fsync, SQLite record), so the driver sustains
at most ``1 / (seconds per shard)`` shards per second. ``--driver-only`` measures just that,
for the earlier path (the pickled result stored too) and the current one.

Run: ``.venv/bin/python benchmarks/bench_ray.py [--queries 20480] [--shard-queries 4096]
[--repeats 3] [--cpus 2]``
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import platform
import secrets
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from jobapi.executor import Executor  # noqa: E402
from service.settings import Settings  # noqa: E402
from service.submission import submit  # noqa: E402
from service.workers.execution import execute, worker_id  # noqa: E402
from service.workers.executors import make_executor  # noqa: E402
from storage.artifacts import ArtifactStore  # noqa: E402
from storage.jobs import JobStore  # noqa: E402

MATERIALS = 465
PAPER_QUERIES = 3_276_800
PAPER_SAMPLES = 2048
PAPER_HOURS = 165.0
NODES = (1, 32, 128)


def run_job(settings: Settings, executor: Executor, params: dict[str, Any]) -> dict[str, Any]:
    """Queue, claim and run one ``generate.fabric`` job with ``executor``; its stats.json
    with its manifest's executor and throughput (``timings.measured.throughput``)."""
    jobs, store = JobStore(settings.db_path), ArtifactStore(settings.store_dir)
    job, _ = submit(
        {"kind": "generate.fabric", "seed": 0, "params": params, "force": True}, jobs, store
    )
    claimed = jobs.claim(worker_id(), settings.lease_seconds, job_id=job.id)
    assert claimed is not None
    execute(claimed, jobs=jobs, store=store, lease_seconds=30.0, executor=executor)
    done = jobs.get(job.id)
    if done.state != "succeeded":
        raise SystemExit(f"job {job.id} {done.state}: {done.error}")
    (digest,) = [a.digest for a in done.artifacts if a.name == "stats.json"]
    stats = json.loads(store.read(digest))
    assert done.manifest_digest is not None
    manifest = json.loads(store.read(done.manifest_digest))
    stats["executor"] = manifest["executor"]
    stats.update(manifest["timings"]["measured"]["throughput"])
    jobs.close()
    return stats


def driver_seconds_per_shard(
    settings: Settings, shard_queries: int, samples: int, *, twice: bool = False
) -> float:
    """The job thread's own cost of one finished fabric shard, for a result of the real
    size (random bytes: incompressible): its npz artifact written to the store and the
    shard record (``generate.fabric`` through ``map_artifact_shards``). ``twice``: the
    earlier path, which also stored the pickled result (``map_shards``) beside the npz."""
    jobs, store = JobStore(settings.db_path), ArtifactStore(settings.store_dir)
    job, _ = submit(
        {"kind": "generate.fabric", "seed": 1, "params": {"preset": "small", "samples": samples}},
        jobs,
        store,
    )
    # material int32, centre 2 x f32, size f32, wi/wo 3 x f32, value/stderr 4 x f32
    npz = os.urandom(shard_queries * 4 * (1 + 2 + 1 + 3 + 3 + 4 + 4))
    n = 40
    tag = b"old" if twice else b"new"
    t0 = time.perf_counter()
    for i in range(n):
        data = npz + tag + i.to_bytes(4)
        if twice:
            info = store.put_bytes(pickle.dumps({"npz": data, "seconds": 1.0}))
            jobs.record_shard(job.id, f"shard-{i:04d}", info.digest)
            store.put_bytes(data)
        else:
            info = store.put_bytes(data)
            jobs.record_shard(job.id, f"shard-{i:04d}.npz", info.digest)
    jobs.close()
    return (time.perf_counter() - t0) / n


def driver_only(args: argparse.Namespace) -> None:
    """``--driver-only``: the job thread's cost per shard, the earlier path (stored twice)
    and this one (once), alternated ``--repeats`` times, and the node count at which one
    job's thread saturates at ``--node-rate`` samples/s per node."""
    costs: dict[str, list[float]] = {"twice (before)": [], "once (now)": []}
    with tempfile.TemporaryDirectory() as tmp:
        settings = Settings.from_env(dict(os.environ)).with_(data_dir=Path(tmp) / "data")
        for _ in range(args.repeats):
            for name, twice in (("twice (before)", True), ("once (now)", False)):
                costs[name].append(
                    driver_seconds_per_shard(
                        settings, args.shard_queries, args.samples, twice=twice
                    )
                )
    shard_samples = args.shard_queries * PAPER_SAMPLES
    print(f"| shard stored | ms per {args.shard_queries}-query shard (median, range) | "
          f"shards/s | nodes at {args.node_rate / 1e6:.0f} M samples/s each |")  # fmt: skip
    print("| --- | --- | --- | --- |")
    for name, v in costs.items():
        med = statistics.median(v)
        nodes = shard_samples / med / args.node_rate
        print(
            f"| {name} | {med * 1e3:.2f} ({min(v) * 1e3:.2f}-{max(v) * 1e3:.2f}) | "
            f"{1 / med:.0f} | {nodes:.0f} |"
        )
    print(f"load {os.getloadavg()[0]:.1f}; {os.cpu_count()} cores")
    print(
        f"reproduce: .venv/bin/python benchmarks/bench_ray.py --driver-only --shard-queries "
        f"{args.shard_queries} --repeats {args.repeats} --node-rate {args.node_rate:g}"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--patterns", nargs="*", default=["plain", "twill_3x3"])
    ap.add_argument("--queries", type=int, default=20480, help="queries per material")
    ap.add_argument("--samples", type=int, default=PAPER_SAMPLES)
    ap.add_argument("--shard-queries", type=int, default=4096)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--cpus", type=int, default=2, help="pool processes = Ray CPUs")
    ap.add_argument("--driver-only", action="store_true", help="only the job thread's cost")
    ap.add_argument(
        "--node-rate", type=float, default=8e6, help="samples/s per node (--driver-only)"
    )
    args = ap.parse_args()
    if args.driver_only:
        driver_only(args)
        return
    # Token auth as a deployment runs it, with a token of this run only (Ray would otherwise
    # write one under ~/.ray for a new local cluster). Set before Ray is imported.
    os.environ.setdefault("RAY_AUTH_MODE", "token")
    os.environ.setdefault("RAY_AUTH_TOKEN", secrets.token_hex(16))
    params: dict[str, Any] = {
        "preset": "small",
        "patterns": args.patterns,
        "texture_sets": 1,
        "shading_sets": 1,
        "queries_per_material": args.queries,
        "shard_queries": args.shard_queries,
        "samples": args.samples,
    }
    warmup = {**params, "queries_per_material": 2 * 256, "shard_queries": 256, "samples": 64}
    rates: dict[str, list[float]] = {"process": [], "ray": []}
    with tempfile.TemporaryDirectory() as tmp:
        settings = Settings.from_env(dict(os.environ)).with_(
            data_dir=Path(tmp) / "data", pool_processes=args.cpus
        )
        executors = {name: make_executor(name, args.cpus) for name in rates}
        try:
            for ex in executors.values():
                ex.start()
                run_job(settings, ex, warmup)
            for i in range(args.repeats):
                for name, ex in executors.items():
                    stats = run_job(settings, ex, params)
                    assert stats["executor"] == name
                    rates[name].append(stats["samples_per_second"])
                    print(
                        f"{name} run {i + 1}: {stats['samples']:.3g} samples in "
                        f"{stats['seconds']:.2f} s, {stats['samples_per_second'] / 1e6:.2f} M/s",
                        file=sys.stderr,
                        flush=True,
                    )
        finally:
            for ex in executors.values():
                ex.close()
        per_shard = driver_seconds_per_shard(settings, args.shard_queries, args.samples)
    med = {k: statistics.median(v) for k, v in rates.items()}
    load = os.getloadavg()[0]
    print("| backend | M samples/s per node (median, range) | vs local pool |")
    print("| --- | --- | --- |")
    for name in ("process", "ray"):
        v = rates[name]
        print(
            f"| {name} | {med[name] / 1e6:.2f} ({min(v) / 1e6:.2f}-{max(v) / 1e6:.2f}) | "
            f"{med[name] / med['process']:.2f}x |"
        )
    total = MATERIALS * PAPER_QUERIES * PAPER_SAMPLES
    shard_samples = args.shard_queries * PAPER_SAMPLES
    print(f"\n| nodes | hours for {total:.3g} samples | paper's {PAPER_HOURS:.0f} h / ours |")
    print("| --- | --- | --- |")
    for n in NODES:
        hours = total / (n * med["ray"]) / 3600
        print(f"| {n} | {hours:.1f} | {PAPER_HOURS / hours:.2f}x |")
    ceiling = shard_samples / per_shard  # samples/s the one job thread can store
    print(
        f"\ndriver: {per_shard * 1e3:.1f} ms per {args.shard_queries}-query shard -> at most "
        f"{1 / per_shard:.0f} shards/s = {ceiling / 1e9:.2f} G samples/s = "
        f"{ceiling / med['ray']:.0f} nodes' worth from one job"
    )
    print(
        f"\nmachine: {platform.machine()}, {os.cpu_count()} cores, {args.cpus} pool processes "
        f"/ Ray CPUs, load {load:.1f}"
    )
    print(
        f"reproduce: .venv/bin/python benchmarks/bench_ray.py --patterns {' '.join(args.patterns)}"
        f" --queries {args.queries} --samples {args.samples} --shard-queries "
        f"{args.shard_queries} --repeats {args.repeats} --cpus {args.cpus}"
    )


if __name__ == "__main__":
    main()
