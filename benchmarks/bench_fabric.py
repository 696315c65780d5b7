"""Throughput of the woven-fabric footprint estimator (Eq. 3-5), in million samples per second.

One material (twill 5x5, psi 25 deg, u_max 30 deg, alpha 0.3, beta 0.7) and a batch of
queries drawn like the paper's data (Sec. 5.1): footprint centres uniform over the tile,
sizes uniform in [0, 1] or [1, 5] tiles (half each), light directions uniform over the
sphere (half of them from below: transmission), view directions uniform over the upper
hemisphere. Every query gets ``--samples`` footprint samples (the paper uses 2048). Each
configuration runs once to warm up (Dr.Jit compiles its kernel), then ``--repeats``
rounds that interleave the configurations; rows report the median. ``--march all`` (the
default) times every visibility march (batched, hierarchical, plain) in the same run and
prints their ratios to the plain march, the figure to compare on a shared, loaded machine;
``--lane-samples 1,2,4`` adds a batched row per value (samples per SIMD lane, whose rays
are marched back to back; ``aggregate_drjit.LANE_SAMPLES``). Results are read back to
numpy, so Dr.Jit's lazy evaluation cannot hide work (NOTES.md). The paper's rate, 3.2 M
queries x 2048 samples in 22 minutes on an RTX 3090, is 4.96 M samples/s.

Run: ``.venv/bin/python benchmarks/bench_fabric.py [--queries 4096] [--samples 2048]
[--march all|batched|hierarchical|plain] [--lane-samples 2]``
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from materials.fabric import aggregate_drjit  # noqa: E402
from materials.fabric.aggregate import Backend, FootprintQueries, estimate  # noqa: E402
from materials.fabric.march import MARCHES, March  # noqa: E402
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


PARAMS = FabricParams(
    PATTERNS["twill_5x5"],
    psi_deg=YarnPair(25.0, 25.0),
    u_max_deg=YarnPair(30.0, 30.0),
    alpha=YarnPair(0.3, 0.3),
    beta=YarnPair(0.7, 0.7),
)
#: Samples of one material at the ``paper`` preset: 3,276,800 queries x 2,048 samples.
PAPER_MATERIAL_SAMPLES = 3_276_800 * 2048


@dataclass(frozen=True)
class Config:
    backend: Backend
    sampler: Sampler
    visibility: bool
    march: March
    queries: FootprintQueries
    threads: int
    lane_samples: int = aggregate_drjit.LANE_SAMPLES

    @property
    def march_label(self) -> str:
        if not self.visibility:
            return "-"
        if self.march == "batched" and self.backend == "drjit":
            return f"batched ({self.lane_samples} per lane)"
        return self.march

    def run(self, samples: int) -> float:
        """Seconds of one estimate() over the whole batch."""
        aggregate_drjit.LANE_SAMPLES = self.lane_samples
        t0 = time.perf_counter()
        est = estimate(
            PARAMS,
            self.queries,
            samples=samples,
            sampler=self.sampler,
            with_visibility=self.visibility,
            march=self.march,
            backend=self.backend,
            threads=self.threads,
        )
        seconds = time.perf_counter() - t0
        assert np.all(np.isfinite(est.mean))
        return seconds


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--queries", type=int, default=4096, help="queries for the Dr.Jit rows")
    ap.add_argument(
        "--numpy-queries", type=int, default=512, help="queries for numpy rows (0: none)"
    )
    ap.add_argument("--samples", type=int, default=2048)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--threads", type=int, default=2, help="numpy worker threads")
    ap.add_argument(
        "--march",
        choices=("all", *MARCHES),
        default="all",
        help="visibility march of the rows with visibility (all: each, for the ratios)",
    )
    ap.add_argument(
        "--lane-samples",
        default=str(aggregate_drjit.LANE_SAMPLES),
        help="comma-separated samples per lane of the Dr.Jit batched rows (powers of two)",
    )
    args = ap.parse_args()
    marches: list[March] = list(MARCHES) if args.march == "all" else [args.march]
    lane_samples = [int(x) for x in args.lane_samples.split(",")]
    machine = f"{platform.machine()}, {os.cpu_count()} cores, {platform.system()}"
    drjit_q = paper_like_queries(args.queries)
    configs: list[Config] = []
    for m in marches:
        for per_lane in lane_samples if m == "batched" else [lane_samples[0]]:
            configs.append(Config("drjit", "sobol", True, m, drjit_q, args.threads, per_lane))
    configs.append(Config("drjit", "independent", True, marches[0], drjit_q, args.threads))
    configs.append(Config("drjit", "sobol", False, marches[0], drjit_q, args.threads))
    if args.numpy_queries > 0:
        numpy_q = paper_like_queries(args.numpy_queries)
        for m in marches:
            configs.append(Config("numpy", "sobol", True, m, numpy_q, args.threads))
        configs.append(Config("numpy", "sobol", False, marches[0], numpy_q, args.threads))
    for c in configs:
        c.run(args.samples)  # warm-up: Dr.Jit kernel compilation, Sobol nets, mip-maps
    # Rounds interleave the configurations, so a change in the machine's load falls on all.
    times: list[list[float]] = [[] for _ in configs]
    loads = []
    for _ in range(args.repeats):
        for i, c in enumerate(configs):
            times[i].append(c.run(args.samples))
        loads.append(os.getloadavg()[0])
    print(
        "| backend | sampler | visibility | march | queries | samples/query | median s "
        "| M samples/s | vs paper 4.96 M/s | machine |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    rates: dict[tuple[str, str, bool, str], float] = {}
    labelled: dict[tuple[str, str, bool, str], float] = {}
    for c, ts in zip(configs, times, strict=True):
        seconds = statistics.median(ts)
        count = len(c.queries)
        rate = count * args.samples / seconds
        rates.setdefault((c.backend, c.sampler, c.visibility, c.march), rate)
        labelled[(c.backend, c.sampler, c.visibility, c.march_label)] = rate
        label = c.backend if c.backend == "drjit" else f"numpy ({args.threads} threads)"
        print(
            f"| {label} | {c.sampler} | {'on' if c.visibility else 'off'} | "
            f"{c.march_label} | {count} | {args.samples} | {seconds:.3f} | "
            f"{rate / 1e6:.2f} | {rate / PAPER_RATE:.2f}x | {machine} |",
            flush=True,
        )
    print(f"\nload average (1 min) after each round: {', '.join(f'{x:.1f}' for x in loads)}")
    for (backend, sampler, vis, label), rate in labelled.items():
        old = rates.get((backend, "sobol", True, "plain"))
        if sampler == "sobol" and vis and label != "plain" and old:
            print(f"{backend} sobol, visibility on: {label} / plain = {rate / old:.2f}x")
    best = rates.get(("drjit", "sobol", True, marches[0]))
    if best:
        minutes = PAPER_MATERIAL_SAMPLES / best / 60
        print(
            f"one paper-scale material (3,276,800 queries x 2,048 samples) at the "
            f"{marches[0]} rate: {minutes:.1f} min (estimator only, extrapolated)"
        )
    print(
        f"\nreproduce: .venv/bin/python benchmarks/bench_fabric.py --queries {args.queries} "
        f"--numpy-queries {args.numpy_queries} --samples {args.samples} "
        f"--repeats {args.repeats} --threads {args.threads} --march {args.march} "
        f"--lane-samples {args.lane_samples}"
    )


if __name__ == "__main__":
    main()
