"""How many Sobol samples match independent sampling's error at 2,048 samples per query?

The fabric estimator (``materials.fabric.aggregate.estimate``, Eq. 3-5 of Chen et al. 2024)
integrates each query's footprint with ``N`` samples; the paper uses N = 2048 independent
points (Sec. 5.1). ``generate.fabric`` defaults to scrambled Sobol (4 replicates). This
script measures the smallest Sobol N whose error is at most independent sampling's at 2048.

Queries: one material per weave family (plain, twill 3x3, satin 5x5; drawn with
``sample_params`` from the paper's ranges, fixed seeds), ``--queries`` queries each from the
generator's own stratified design (``generators.fabric.queries.design_queries``: footprint
sizes over 0-5 tiles, half BTDF pairs), so both BRDF and BTDF pairs and small (< 1 tile) and
large (>= 1 tile) footprints are covered. Reference: Sobol at ``--reference-samples``
(default 2^17) with its own seed.

Two error measures, pooled over queries and the four components (C_warp, C_weft, S_warp,
S_weft), in the units of the data (an L2 training loss sees these):

- ``rmse``: the root mean square of (estimate - reference), averaged over ``--seeds``
  independent randomisations (the reference's own standard error is reported and removed
  in quadrature; it is small at 2^17);
- ``rms se``: the root mean square of the standard errors the estimator reports for itself
  (independent: delta method over N samples; Sobol: spread of the 4 replicate means,
  3 degrees of freedom per query, unbiased for the variance on average).

The break-even N is interpolated linearly in log(N)-log(error) between the two Sobol sample
counts that bracket independent sampling's error at 2048. Dr.Jit backend; results are read
back to numpy before timing stops (NOTES.md).

Run: ``.venv/bin/python benchmarks/bench_fabric_sobol.py [--queries 192] [--seeds 4]``
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from generators.fabric.queries import design_queries  # noqa: E402
from materials.fabric.aggregate import Backend, FootprintQueries, estimate  # noqa: E402
from materials.fabric.params import FabricParams, sample_params  # noqa: E402

FAMILIES = ("plain", "twill_3x3", "satin_5x5")
REPLICATES = 4
REFERENCE_SEED = 987_654
SOBOL_COUNTS = (16, 32, 64, 128, 256, 512, 1024, 2048)
INDEPENDENT_N = 2048


def materials() -> list[FabricParams]:
    """One fixed material per weave family, from the paper's parameter ranges."""
    return [sample_params(np.random.default_rng([7, i]), name) for i, name in enumerate(FAMILIES)]


def queries(count: int, seed: int) -> FootprintQueries:
    """``count`` queries of the generator's stratified design, float32-rounded as stored."""
    q = design_queries(seed, 0, count)
    f32 = np.float32
    return FootprintQueries(
        q.centre.astype(f32), q.size.astype(f32), q.wi.astype(f32), q.wo.astype(f32)
    )


def run(
    params: FabricParams, q: FootprintQueries, samples: int, sampler: str, seed: int, b: Backend
) -> tuple[np.ndarray, np.ndarray]:
    est = estimate(
        params,
        q,
        samples=samples,
        sampler=sampler,  # type: ignore[arg-type]
        seed=seed,
        replicates=REPLICATES,
        backend=b,
    )
    return est.mean, est.stderr


def break_even(counts: list[int], errors: list[float], target: float) -> float | None:
    """Smallest N with error <= target, log-log interpolated; None if never reached."""
    if errors[0] <= target:
        return float(counts[0])
    for i in range(1, len(counts)):
        n0, e0, n1, e1 = counts[i - 1], errors[i - 1], counts[i], errors[i]
        if e1 <= target < e0:
            t = (math.log(target) - math.log(e0)) / (math.log(e1) - math.log(e0))
            return math.exp(math.log(n0) + t * (math.log(n1) - math.log(n0)))
    return None


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--queries", type=int, default=192, help="queries per material")
    ap.add_argument("--seeds", type=int, default=4, help="randomisations per estimator")
    ap.add_argument("--reference-samples", type=int, default=1 << 17)
    ap.add_argument("--backend", default="drjit", choices=("drjit", "numpy"))
    args = ap.parse_args()
    started = time.perf_counter()
    mats = materials()
    qs = [queries(args.queries, 100 + i) for i in range(len(mats))]
    size = np.concatenate([q.size for q in qs])
    below = np.concatenate([q.wi[:, 2] < 0 for q in qs])
    subsets = {
        "all": np.ones_like(below),
        "small (<1 tile)": size < 1.0,
        "large (>=1 tile)": size >= 1.0,
        "BRDF": ~below,
        "BTDF": below,
    }

    def pooled(samples: int, sampler: str, seed: int) -> tuple[np.ndarray, np.ndarray]:
        parts = [
            run(m, q, samples, sampler, seed, args.backend) for m, q in zip(mats, qs, strict=True)
        ]
        return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])

    ref, ref_se = pooled(args.reference_samples, "sobol", REFERENCE_SEED)

    def errors(samples: int, sampler: str) -> dict[str, tuple[float, float]]:
        """Per subset: (rmse against the reference, rms reported standard error)."""
        sq = np.zeros_like(ref)
        se2 = np.zeros_like(ref)
        for s in range(args.seeds):
            mean, se = pooled(samples, sampler, 1000 + s)
            sq += (mean - ref) ** 2
            se2 += se**2
        sq = np.maximum(sq / args.seeds - ref_se**2, 0.0)  # the reference's own noise out
        se2 /= args.seeds
        return {
            k: (float(np.sqrt(sq[m].mean())), float(np.sqrt(se2[m].mean())))
            for k, m in subsets.items()
        }

    indep = errors(INDEPENDENT_N, "independent")
    sobol = {n: errors(n, "sobol") for n in SOBOL_COUNTS}
    machine = f"{platform.machine()}, {os.cpu_count()} cores, load {os.getloadavg()[0]:.1f}"
    n_q = len(ref)
    print(
        f"{n_q} queries ({args.queries} x {len(FAMILIES)} families), reference Sobol "
        f"{args.reference_samples} samples (rms se {np.sqrt((ref_se**2).mean()):.2e}), "
        f"{args.seeds} seeds, {args.backend}, {machine}\n"
    )
    head = " | ".join(f"Sobol {n}" for n in SOBOL_COUNTS)
    print(f"| subset | measure | independent {INDEPENDENT_N} | {head} | Sobol N to match |")
    print("| --- | --- | --- | " + " | ".join("---" for _ in SOBOL_COUNTS) + " | --- |")
    for k in subsets:
        for j, measure in enumerate(("rmse", "rms se")):
            target = indep[k][j]
            errs = [sobol[n][k][j] for n in SOBOL_COUNTS]
            n_star = break_even(list(SOBOL_COUNTS), errs, target)
            found = f"{n_star:.0f}" if n_star is not None else f"> {SOBOL_COUNTS[-1]}"
            cells = " | ".join(f"{e:.2e}" for e in errs)
            print(f"| {k} | {measure} | {target:.2e} | {cells} | {found} |", flush=True)
    print(f"\n{time.perf_counter() - started:.0f} s")
    print(
        f"reproduce: .venv/bin/python benchmarks/bench_fabric_sobol.py --queries {args.queries} "
        f"--seeds {args.seeds} --reference-samples {args.reference_samples} "
        f"--backend {args.backend}"
    )


if __name__ == "__main__":
    main()
