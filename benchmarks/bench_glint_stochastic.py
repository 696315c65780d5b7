"""The stochastic tiny-example P-NDF against the tiled one: ns per evaluation of the fused
Dr.Jit kernels (:func:`materials.glints.pndf_drjit.stochastic_pndf`,
:func:`materials.glints.pndf_drjit.tiny_pndf`) on the same 16 x 16 example, at footprints
from below a texel to several examples, the ratio per footprint and its median.

Queries: 2^14 random projected normals per footprint, one footprint for all lanes; median
of ``--repeats`` runs after a warm-up (compilation), host read-back included.

Run: ``.venv/bin/python benchmarks/bench_glint_stochastic.py [--repeats 5]``
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

from materials.backend import load_mitsuba  # noqa: E402
from materials.glints.examples import procedural_example  # noqa: E402
from materials.glints.lobes import make_lobes  # noqa: E402
from materials.glints.ndf_maps import auto_extent, ndf_maps  # noqa: E402
from materials.glints.pndf_drjit import (  # noqa: E402
    Sym2,
    jit_lobes,
    jit_maps,
    jit_placement,
    stochastic_pndf,
    tiny_pndf,
)
from materials.glints.surface import Distribution, Surface  # noqa: E402

SIGMAS = (0.8, 2.5, 6.0, 16.0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--queries", type=int, default=1 << 14)
    args = ap.parse_args()
    mi = load_mitsuba()
    normals = procedural_example("scratches", 16, np.random.default_rng(4))
    lobes = make_lobes(normals, rate=2, sigma_r=0.02)
    e = auto_extent(lobes)
    maps = ndf_maps(lobes, 48, e)
    jm, jl = jit_maps(mi, maps, e), jit_lobes(mi, lobes)
    surf = Surface(normals, Distribution(kind="stochastic", scale_range=(0.8, 1.25), seed=5))
    jp = jit_placement(mi, surf)
    m = args.queries
    q = np.random.default_rng(0).uniform(-0.5, 0.5, (m, 2)).astype(np.float32)
    fq = (mi.Float(q[:, 0]), mi.Float(q[:, 1]))

    def full(v: float) -> object:
        return mi.Float(np.full(m, v, np.float32))

    def timed(fn) -> float:  # type: ignore[no-untyped-def]
        fn()
        ts = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            fn()
            ts.append(time.perf_counter() - t0)
        return statistics.median(ts)

    print(f"# {platform.processor() or platform.machine()}, load {os.getloadavg()[0]:.2f}")
    print("| footprint sigma (texels) | tiled ns/eval | stochastic ns/eval | ratio |")
    print("| --- | --- | --- | --- |")
    ratios = []
    for sigma in SIGMAS:
        c = (full(40.3), full(37.7))
        cov = Sym2(full(sigma**2), full(0.25 * sigma**2), full(0.8 * sigma**2))
        t_t = timed(lambda c=c, cov=cov: tiny_pndf(
            mi, jm, jl, (np.eye(2), np.zeros(2)), c, cov, fq).numpy())  # fmt: skip
        t_s = timed(lambda c=c, cov=cov: stochastic_pndf(mi, jm, jl, jp, c, cov, fq).numpy())
        ratios.append(t_s / t_t)
        print(f"| {sigma:g} | {1e9 * t_t / m:.0f} | {1e9 * t_s / m:.0f} | {t_s / t_t:.1f}x |")
    print(f"| median ratio | | | {statistics.median(ratios):.1f}x |")
    print(f"# load {os.getloadavg()[0]:.2f}; command: .venv/bin/python {' '.join(sys.argv)}")


if __name__ == "__main__":
    main()
