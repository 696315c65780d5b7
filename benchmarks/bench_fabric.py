"""Throughput of the woven-fabric footprint estimator (Eq. 3-5), in million samples per second.

One material (twill 5x5, psi 25 deg, u_max 30 deg, alpha 0.3, beta 0.7) and a batch of
queries drawn like the paper's data (Sec. 5.1): footprint centres uniform over the tile,
sizes uniform in [0, 1] or [1, 5] tiles (half each), light directions uniform over the
sphere (half of them from below: transmission), view directions uniform over the upper
hemisphere. Every query gets ``--samples`` footprint samples (the paper uses 2048). Each
configuration runs once to warm up (Dr.Jit compiles its kernel), then ``--repeats`` times;
rows report the median. Results are read back to numpy, so Dr.Jit's lazy evaluation cannot
hide work (NOTES.md). The paper's rate, 3.2 M queries x 2048 samples in 22 minutes on an
RTX 3090, is 4.96 M samples/s.

Run: ``.venv/bin/python benchmarks/bench_fabric.py [--queries 4096] [--samples 2048]``
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from materials.fabric.aggregate import Backend, FootprintQueries, estimate  # noqa: E402
from materials.fabric.params import FabricParams, YarnPair  # noqa: E402
from materials.fabric.patterns import PATTERNS  # noqa: E402
from materials.fabric.samplers import Sampler  # noqa: E402

PAPER_RATE = 3.2e6 * 2048 / (22 * 60)  # samples per second


def paper_like_queries(count: int, seed: int = 0) -> FootprintQueries:
    rng = np.random.default_rng(seed)
    size = np.where(
        rng.uniform(size=count) < 0.5, rng.uniform(0, 1, count), rng.uniform(1, 5, count)
    )
    wi = rng.normal(size=(count, 3))
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wi[np.abs(wi[:, 2]) < 1e-3, 2] = 1e-3
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo = rng.normal(size=(count, 3))
    wo[:, 2] = np.abs(wo[:, 2]) + 1e-3
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    return FootprintQueries(rng.uniform(0, 1, (count, 2)), size, wi, wo)


def bench(
    backend: Backend,
    sampler: Sampler,
    queries: FootprintQueries,
    samples: int,
    visibility: bool,
    repeats: int,
    threads: int,
) -> float:
    """Median seconds of one estimate() over the whole batch."""
    params = FabricParams(
        PATTERNS["twill_5x5"],
        psi_deg=YarnPair(25.0, 25.0),
        u_max_deg=YarnPair(30.0, 30.0),
        alpha=YarnPair(0.3, 0.3),
        beta=YarnPair(0.7, 0.7),
    )

    def run() -> None:
        est = estimate(
            params,
            queries,
            samples=samples,
            sampler=sampler,
            with_visibility=visibility,
            backend=backend,
            threads=threads,
        )
        assert np.all(np.isfinite(est.mean))

    run()  # warm-up: Dr.Jit kernel compilation, Sobol nets
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        run()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--queries", type=int, default=4096, help="queries for the Dr.Jit rows")
    ap.add_argument("--numpy-queries", type=int, default=512, help="queries for numpy rows")
    ap.add_argument("--samples", type=int, default=2048)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--threads", type=int, default=2, help="numpy worker threads")
    args = ap.parse_args()
    machine = f"{platform.machine()}, {os.cpu_count()} cores, {platform.system()}"
    print(
        "| backend | sampler | visibility | queries | samples/query | median s "
        "| M samples/s | vs paper 4.96 M/s | machine | load (1 min) |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    configs: list[tuple[Backend, Sampler, bool]] = [
        ("drjit", "sobol", True),
        ("drjit", "independent", True),
        ("drjit", "sobol", False),
        ("numpy", "sobol", True),
        ("numpy", "sobol", False),
    ]
    for backend, sampler, visibility in configs:
        count = args.queries if backend == "drjit" else args.numpy_queries
        q = paper_like_queries(count)
        seconds = bench(backend, sampler, q, args.samples, visibility, args.repeats, args.threads)
        rate = count * args.samples / seconds
        label = backend if backend == "drjit" else f"numpy ({args.threads} threads)"
        print(
            f"| {label} | {sampler} | {'on' if visibility else 'off'} | {count} | "
            f"{args.samples} | {seconds:.3f} | {rate / 1e6:.2f} | {rate / PAPER_RATE:.2f}x | "
            f"{machine} | {os.getloadavg()[0]:.1f} |",
            flush=True,
        )
    print(
        f"\nreproduce: .venv/bin/python benchmarks/bench_fabric.py --queries {args.queries} "
        f"--numpy-queries {args.numpy_queries} --samples {args.samples} "
        f"--repeats {args.repeats} --threads {args.threads}"
    )


if __name__ == "__main__":
    main()
