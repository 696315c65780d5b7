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
for the earliest path (the pickled result stored too), the job storing each returned shard
(``MATFORGE_SHARED_STORE`` unset), and the shard tasks storing their own results into a
store every node mounts (``MATFORGE_SHARED_STORE=1``: the job's thread checks an object's
size and records its digest), each through the real ``JobContext.map_artifact_shards``
with an executor whose results are ready at once; and, with ``--ray``, Ray's own cost per
shard on the job's thread (submitting a task, waiting for it, fetching its small result)
on a private local Ray.

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
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from jobapi.context import JobContext, NullMonitor  # noqa: E402
from jobapi.executor import Executor, InlineExecutor  # noqa: E402
from service.settings import Settings  # noqa: E402
from service.submission import submit  # noqa: E402
from service.workers.execution import execute, worker_id  # noqa: E402
from service.workers.executors import make_executor  # noqa: E402
from storage.artifacts import ArtifactStore, ObjectInfo  # noqa: E402
from storage.jobs import JobStore  # noqa: E402

MATERIALS = 465
PAPER_QUERIES = 3_276_800
PAPER_SAMPLES = 2048
PAPER_HOURS = 165.0
NODES = (1, 32, 128)
#: Shards in flight for the ``ray.wait`` timing (2 x CPUs: 1 to 1,000 two-core nodes).
WAIT_IN_FLIGHT = (4, 400, 4000)


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


class ReadyResults(InlineExecutor):
    """An executor whose shards finished elsewhere: ``map`` yields the results prepared
    beforehand (the npz bytes, or with ``shared_store`` the digests of objects the tasks
    already wrote), so timing ``map_artifact_shards`` times the job's thread alone."""

    def __init__(self, results: list[Any], shared_store: bool) -> None:
        self.results = results
        self.shared_store = shared_store

    def map(self, fn: Callable[[Any], Any], items: Sequence[Any]) -> Iterator[tuple[int, Any]]:
        yield from enumerate(self.results[: len(items)])


def _unused_shard(item: int) -> bytes:
    raise AssertionError("ReadyResults never runs a shard")


def driver_seconds_per_shard(
    settings: Settings, shard_queries: int, samples: int, *, path: str, n: int = 100
) -> float:
    """The job thread's own cost of one finished fabric shard, for a result of the real
    size (random bytes: incompressible). ``path``: ``"twice"``, the earliest, which stored
    the pickled result (``map_shards``) beside the npz; ``"job"``, the job storing each
    returned npz (``map_artifact_shards``, its artifact is the shard record); ``"task"``,
    the shard tasks storing into a shared store, the job checking sizes and recording."""
    jobs, store = JobStore(settings.db_path), ArtifactStore(settings.store_dir)
    job, _ = submit(
        {
            "kind": "generate.fabric",
            "seed": 1,
            "params": {"preset": "small", "samples": samples},
            "force": True,  # a new job each time: no shards recorded yet
        },
        jobs,
        store,
    )
    # material int32, centre 2 x f32, size f32, wi/wo 3 x f32, value/stderr 4 x f32
    npz = os.urandom(shard_queries * 4 * (1 + 2 + 1 + 3 + 3 + 4 + 4))
    shards = [npz + path.encode() + i.to_bytes(4) for i in range(n)]
    names = [f"shard-{i:04d}.npz" for i in range(n)]
    if path == "twice":
        t0 = time.perf_counter()
        for i, data in enumerate(shards):
            info = store.put_bytes(pickle.dumps({"npz": data, "seconds": 1.0}))
            jobs.record_shard(job.id, f"shard-{i:04d}", info.digest)
            store.put_bytes(data)
        jobs.close()
        return (time.perf_counter() - t0) / n
    results: list[Any]
    if path == "task":  # the tasks' own writes, done before the clock starts
        results = [ArtifactStore(store.root.resolve()).put_bytes(d) for d in shards]
    else:
        results = shards
    ctx = JobContext(
        job_id=job.id, seed=1, spec=job.spec, store=store, jobs=jobs,
        workdir=Path(settings.data_dir), monitor=NullMonitor(),
        executor=ReadyResults(results, shared_store=path == "task"),
    )  # fmt: skip
    t0 = time.perf_counter()
    ctx.map_artifact_shards(_unused_shard, range(n), names, media_type="application/x-npz")
    seconds = time.perf_counter() - t0
    jobs.close()
    return seconds / n


def _small_result(i: int) -> Any:
    """A Ray task's result with a shared store: a digest and a size."""
    return ObjectInfo(f"{i:064x}", 294912)


def _sleeper(seconds: float) -> None:
    time.sleep(seconds)


def ray_wait_seconds(in_flight: int, calls: int = 20) -> float:
    """Seconds of the two ``ray.wait`` calls :meth:`RayExecutor.map` makes per round (one
    finished shard among ``in_flight`` unfinished ones): the scan whose cost grows with
    the shards in flight, 2 x the cluster's CPUs."""
    import ray

    sleeper = ray.remote(_sleeper).options(num_cpus=1)
    pending = [sleeper.remote(600.0) for _ in range(in_flight)]
    done = ray.put(b"digest")
    ray.wait([done])
    refs = [*pending, done]
    try:
        t0 = time.perf_counter()
        for _ in range(calls):
            ready, _ = ray.wait(refs, num_returns=1)
            more, _ = ray.wait(refs, num_returns=len(refs), timeout=0)
            assert ready == more == [done]
        return (time.perf_counter() - t0) / calls
    finally:
        for ref in pending:
            ray.cancel(ref, force=True)


def ray_seconds_per_shard(cpus: int, n: int) -> tuple[float, float, dict[int, float]]:
    """Ray's cost per shard on the job's thread, through :class:`RayExecutor`'s ``map``
    of ``n`` tasks that return a digest at once: (thread CPU seconds, wall seconds) per
    task. The wall time includes the tasks themselves on ``cpus`` CPUs of this machine.
    Then :func:`ray_wait_seconds` for each of :data:`WAIT_IN_FLIGHT`."""
    ex = make_executor("ray", cpus)
    ex.start()
    try:
        list(ex.map(_small_result, range(4 * cpus)))  # warm: the workers and the function
        c0, t0 = time.thread_time(), time.perf_counter()
        for _ in ex.map(_small_result, range(n)):
            pass
        per_task = (time.thread_time() - c0) / n, (time.perf_counter() - t0) / n
        waits = {k: ray_wait_seconds(k) for k in WAIT_IN_FLIGHT}
        return (*per_task, waits)
    finally:
        ex.close()


def driver_only(args: argparse.Namespace) -> None:
    """``--driver-only``: the job thread's cost per shard on each storing path, the paths
    alternated ``--repeats`` times, and the node count at which one job's thread
    saturates at ``--node-rate`` samples/s per node; with ``--ray``, Ray's own part."""
    arms = {
        "twice (earliest)": "twice",
        "job stores each shard (shared store unset)": "job",
        "tasks store, job records digests (MATFORGE_SHARED_STORE=1)": "task",
    }
    costs: dict[str, list[float]] = {name: [] for name in arms}
    with tempfile.TemporaryDirectory() as tmp:
        settings = Settings.from_env(dict(os.environ)).with_(data_dir=Path(tmp) / "data")
        for _ in range(args.repeats):
            for name, path in arms.items():
                costs[name].append(
                    driver_seconds_per_shard(settings, args.shard_queries, args.samples, path=path)
                )
    shard_samples = args.shard_queries * PAPER_SAMPLES
    print(f"| shard stored | ms per {args.shard_queries}-query shard (median, range) | "
          f"shards/s | nodes at {args.node_rate / 1e6:.0f} M samples/s each |")  # fmt: skip
    print("| --- | --- | --- | --- |")
    for name, v in costs.items():
        med = statistics.median(v)
        nodes = shard_samples / med / args.node_rate
        print(
            f"| {name} | {med * 1e3:.3f} ({min(v) * 1e3:.3f}-{max(v) * 1e3:.3f}) | "
            f"{1 / med:.0f} | {nodes:.0f} |"
        )
    if args.ray:
        os.environ.setdefault("RAY_AUTH_MODE", "token")
        os.environ.setdefault("RAY_AUTH_TOKEN", secrets.token_hex(16))
        cpu, wall, waits = zip(
            *(ray_seconds_per_shard(args.cpus, args.ray_tasks) for _ in range(args.repeats)),
            strict=True,
        )
        store_ms = statistics.median(costs[list(arms)[-1]]) * 1e3
        ray_ms = statistics.median(cpu) * 1e3
        total = (store_ms + ray_ms) / 1e3
        print(
            f"\nRay on the job's thread, {args.ray_tasks} tasks x {args.repeats}: CPU "
            f"{ray_ms:.3f} ms per task (range {min(cpu) * 1e3:.3f}-{max(cpu) * 1e3:.3f}); "
            f"wall {statistics.median(wall) * 1e3:.3f} ms per task with the tasks on "
            f"{args.cpus} CPUs here"
        )
        for k in WAIT_IN_FLIGHT:
            v = [w[k] for w in waits]
            print(
                f"ray.wait, one finished among {k} in flight: {statistics.median(v) * 1e3:.3f} "
                f"ms per round (range {min(v) * 1e3:.3f}-{max(v) * 1e3:.3f})"
            )
        print(
            f"shared store, all told: {store_ms:.3f} + {ray_ms:.3f} ms = {total * 1e3:.3f} ms "
            f"per shard -> {1 / total:.0f} shards/s = "
            f"{shard_samples / total / args.node_rate:.0f} nodes at "
            f"{args.node_rate / 1e6:.0f} M samples/s each"
        )
    print(f"load {os.getloadavg()[0]:.1f}; {os.cpu_count()} cores")
    print(
        f"reproduce: .venv/bin/python benchmarks/bench_ray.py --driver-only --shard-queries "
        f"{args.shard_queries} --repeats {args.repeats} --node-rate {args.node_rate:g}"
        + (f" --ray --ray-tasks {args.ray_tasks} --cpus {args.cpus}" if args.ray else "")
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
    ap.add_argument("--ray", action="store_true", help="--driver-only: Ray's part too")
    ap.add_argument("--ray-tasks", type=int, default=400, help="tasks per --ray measurement")
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
        per_shard = driver_seconds_per_shard(
            settings, args.shard_queries, args.samples, path="task" if settings.shared_store
            else "job"
        )  # fmt: skip
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
