"""The tiny example's two lookup rules, ``flat`` (the default) and ``paper`` (the paper's
descent, Sec. 6.3): P-NDF error against brute force and Dr.Jit evaluation speed, per
footprint size.

- **Error**: L1 over the 48 x 48 cells of ``[-0.6, 0.6]^2`` (total mass 1) of the numpy
  evaluator against a brute-force P-NDF written without lobes or maps (the bilinear normal
  field at 200,000 points of the Gaussian footprint, each normal blurred by sigma_r, as in
  ``tests/unit/materials/glints/test_lookup_rule.py``). Maps at R = 64, a 16^2 example.
- **Speed**: the fused Dr.Jit kernel (:func:`materials.glints.pndf_drjit.tiny_pndf`) on
  2^16 queries per footprint (random centres), wall time with host read-back, median of
  ``--repeats`` runs after a warm-up (kernel compilation excluded).

Run: ``nice -n 5 .venv/bin/python benchmarks/bench_glint_lookup.py [--repeats 5]``
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from scipy.special import ndtr

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from materials.backend import load_mitsuba  # noqa: E402
from materials.glints.examples import procedural_example  # noqa: E402
from materials.glints.footprint import LOOKUPS, TinyExample, tiny_pndf  # noqa: E402
from materials.glints.lobes import make_lobes  # noqa: E402
from materials.glints.ndf_maps import auto_extent, ndf_maps  # noqa: E402
from materials.glints.pndf_drjit import Sym2, jit_lobes, jit_maps  # noqa: E402
from materials.glints.pndf_drjit import tiny_pndf as jit_tiny  # noqa: E402
from materials.glints.surface import Distribution, Surface  # noqa: E402
from tests.helpers.glint_reference import bilinear_field  # noqa: E402

SIGMA_R = 0.02
EXTENT, CELLS = 0.6, 48
SIGMAS = (1.0, 1.5, 2.5, 4.0, 8.0, 16.0, 32.0)
KINDS = ("isotropic_noise", "scratches")


def brute(normals: np.ndarray, c: np.ndarray, sigma: float) -> np.ndarray:
    u = c + sigma * np.random.default_rng(0).standard_normal((200_000, 2))
    s = bilinear_field(normals, np.mod(u, normals.shape[0]))
    edges = np.linspace(-EXTENT, EXTENT, CELLS + 1)
    mx = np.diff(ndtr((edges[None, :] - s[:, 0:1]) / SIGMA_R), axis=1)
    my = np.diff(ndtr((edges[None, :] - s[:, 1:2]) / SIGMA_R), axis=1)
    return (my.T @ mx).ravel() / len(s)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--queries", type=int, default=1 << 16)
    args = ap.parse_args()
    print(f"machine: {platform.processor() or platform.machine()}, load {os.getloadavg()}")
    mi = load_mitsuba()
    edges = np.linspace(-EXTENT, EXTENT, CELLS + 1)
    g = (edges[:-1] + edges[1:]) / 2
    qy, qx = np.meshgrid(g, g, indexing="ij")
    grid = np.stack([qx.ravel(), qy.ravel()], axis=1)
    cell = float(edges[1] - edges[0])
    rng = np.random.default_rng(0)
    n = args.queries
    cen = rng.uniform(0.0, 64.0, (n, 2)).astype(np.float32)
    qq = rng.uniform(-0.5, 0.5, (n, 2)).astype(np.float32)
    print("| example | sigma (texels) | L1 flat | L1 paper | ns/eval flat | ns/eval paper "
          "| paper / flat time |")  # fmt: skip
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for kind in KINDS:
        normals = procedural_example(kind, 16, np.random.default_rng(3))
        lobes = make_lobes(normals, rate=2, sigma_r=SIGMA_R)
        e = auto_extent(lobes)
        ex = TinyExample(lobes, ndf_maps(lobes, 64, e), e)
        surf = Surface(normals, Distribution())
        jm, jl = jit_maps(mi, ex.maps, ex.extent), jit_lobes(mi, ex.lobes)
        c = np.array([7.3, 9.1])
        for sigma in SIGMAS:
            want = brute(normals, c, sigma)
            err, ns = {}, {}
            for lookup in LOOKUPS:
                d = tiny_pndf(ex, surf, c, np.eye(2) * sigma**2, grid, lookup=lookup)
                err[lookup] = float(np.abs(d * cell * cell - want).sum())

                def run(
                    lookup: str = lookup, sigma: float = sigma, jm: Any = jm, jl: Any = jl
                ) -> None:
                    full = mi.Float(np.full(n, sigma**2, np.float32))
                    cov = Sym2(full, mi.Float(np.zeros(n, np.float32)), full)
                    out = jit_tiny(
                        mi, jm, jl, (np.eye(2), np.zeros(2)),
                        (mi.Float(cen[:, 0]), mi.Float(cen[:, 1])), cov,
                        (mi.Float(qq[:, 0]), mi.Float(qq[:, 1])), lookup=lookup,
                    )  # fmt: skip
                    np.asarray(out.numpy())

                run()
                times = []
                for _ in range(args.repeats):
                    t0 = time.perf_counter()
                    run()
                    times.append(time.perf_counter() - t0)
                ns[lookup] = 1e9 * statistics.median(times) / n
            print(
                f"| {kind} | {sigma:g} | {err['flat']:.4f} | {err['paper']:.4f} | "
                f"{ns['flat']:.1f} | {ns['paper']:.1f} | {ns['paper'] / ns['flat']:.2f} |"
            )


if __name__ == "__main__":
    main()
