"""Queue throughput: 1,000 tiny jobs through the SQLite queue.

Two measurements in one run:

1. ``store``: 1,000 jobs submitted, then claimed, heartbeaten once and completed (fenced)
   by W worker processes racing on the same database file: the queue's own ceiling.
2. ``service``: N tiny ``render`` jobs (8x8, 1 spp) executed by real workers
   (``service.workers.worker.run_worker`` in W processes): the per-job overhead of the whole path,
   Mitsuba scene set-up included.

Run: ``.venv/bin/python benchmarks/bench_queue.py [--jobs 1000] [--workers 2]``
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import platform
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from service.settings import Settings  # noqa: E402
from storage.jobs import ArtifactRecord, JobStore  # noqa: E402


def _drain(db: str, worker: int) -> int:
    js = JobStore(db)
    n = 0
    art = [ArtifactRecord("out.json", "0" * 64, 2, "application/json")]
    while (job := js.claim(f"bench:{worker}", 30)) is not None:
        js.heartbeat(job.id, job.lease_token, 30, 0.5, "half")
        js.complete(job.id, job.lease_token, art, "1" * 64)
        n += 1
    return n


def bench_store(n_jobs: int, workers: int) -> tuple[float, float]:
    with tempfile.TemporaryDirectory() as d:
        db = str(Path(d) / "jobs.sqlite3")
        js = JobStore(db)
        t0 = time.perf_counter()
        for i in range(n_jobs):
            js.submit(kind="toy", name=None, seed=i, spec_hash=f"{i:064x}", spec={"i": i})
        t_submit = time.perf_counter() - t0
        ctx = mp.get_context("spawn")
        with ctx.Pool(workers) as pool:
            t0 = time.perf_counter()
            done = sum(pool.starmap(_drain, [(db, w) for w in range(workers)]))
            t_run = time.perf_counter() - t0
        assert done == n_jobs, (done, n_jobs)
        assert js.counts()["succeeded"] == n_jobs
        return n_jobs / t_submit, n_jobs / t_run


def _work(data_dir: str, n: int) -> None:
    from service.workers.worker import run_worker

    s = Settings.from_env({}).with_(data_dir=Path(data_dir), pool_processes=1)
    run_worker(s, max_jobs=n, idle_exit_seconds=1.0)


def bench_service(n_jobs: int, workers: int) -> float:
    from service.submission import submit
    from storage.artifacts import ArtifactStore

    with tempfile.TemporaryDirectory() as d:
        s = Settings.from_env({}).with_(data_dir=Path(d))
        js, store = JobStore(s.db_path), ArtifactStore(s.store_dir)
        for i in range(n_jobs):
            submit(
                {
                    "kind": "render",
                    "seed": i,
                    "params": {
                        "scene": "sphere_points",
                        "material": {"mitsuba": {"type": "diffuse"}},
                        "resolution": [8, 8],
                        "spp": 1,
                    },
                },
                js,
                store,
            )
        ctx = mp.get_context("spawn")
        t0 = time.perf_counter()
        procs = [ctx.Process(target=_work, args=(d, n_jobs)) for _ in range(workers)]
        for p in procs:
            p.start()
        for p in procs:
            p.join()
        elapsed = time.perf_counter() - t0 - 1.0  # minus the idle-exit wait
        assert js.counts()["succeeded"] == n_jobs, js.counts()
        return n_jobs / elapsed


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--jobs", type=int, default=1000)
    ap.add_argument("--service-jobs", type=int, default=100)
    ap.add_argument("--workers", type=int, default=2)
    a = ap.parse_args()

    sub, run = bench_store(a.jobs, a.workers)
    svc = bench_service(a.service_jobs, a.workers)
    print(
        f"| queue (store) | {a.jobs} jobs, {a.workers} worker procs | submit {sub:.0f} jobs/s | "
        f"claim+heartbeat+complete {run:.0f} jobs/s | {platform.node()} |"
    )
    print(
        f"| queue (service) | {a.service_jobs} render 8x8 1spp jobs, {a.workers} workers | "
        f"{svc:.1f} jobs/s end to end | | {platform.node()} |"
    )
    print(
        f"command: .venv/bin/python benchmarks/bench_queue.py --jobs {a.jobs} "
        f"--service-jobs {a.service_jobs} --workers {a.workers}"
    )


if __name__ == "__main__":
    main()
