"""Glints (Xing et al. 2024) against the Yan et al. reference: speed, memory, precompute,
example size and the failure modes, each table printed as markdown, all in one run.

Tables (see BENCHMARKS.md for the recorded figures):

1. **P-NDF evaluation speed** (the issue's goal: tiny-example >= 5x Yan per evaluation at
   footprints covering 4 or more examples). Both evaluators run through their fused Dr.Jit
   kernels (:mod:`materials.glints.pndf_drjit`) on 2^18 random queries per footprint size,
   median of ``--repeats`` runs after a warm-up, host read-back included. Yan runs on the
   microstructure exported at 2 texels per example texel (the render's default). Footprint
   sizes are given in examples covered (the footprint's 3.5-sigma support box, side over n).
2. **Memory** (Table 3 analogue): NDF maps + lobes against the explicit reference at the
   paper's resolutions (its input sizes, R = 128, 4k / 6k maps).
3. **Precompute** (Table 2 analogue): seconds for the maps against example size and R.
4. **Example size** (Fig. 13 analogue): brushed metal at 8, 16, 32 texels: P-NDF error
   against Yan on the exported surface, against memory.
5. **Where it fails**: a macroscopic pattern (wood grain) that a tiny example cannot hold;
   footprints below the finest tile; overlapping stochastic instances.

Errors are relative L1 distances of P-NDF values at random queries ``s`` in ``[-0.5, 0.5]^2``
(numpy evaluators, float64).

Run: ``.venv/bin/python benchmarks/bench_glint.py [--repeats 5] [--quick]``
"""

from __future__ import annotations

import argparse
import math
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from materials.backend import load_mitsuba  # noqa: E402
from materials.glints.examples import procedural_example  # noqa: E402
from materials.glints.footprint import (  # noqa: E402
    SUPPORT_SIGMAS,
    TinyExample,
    tiny_pndf,
    yan_pndf,
)
from materials.glints.lobes import LOBE_BYTES, make_lobes  # noqa: E402
from materials.glints.ndf_maps import auto_extent, map_bytes, ndf_maps  # noqa: E402
from materials.glints.pndf_drjit import Sym2, jit_lobes, jit_maps, lobes_pndf  # noqa: E402
from materials.glints.pndf_drjit import tiny_pndf as jit_tiny  # noqa: E402
from materials.glints.surface import (  # noqa: E402
    Distribution,
    Surface,
    Transform,
    export_normal_map,
)

SIGMA_R = 0.02


def l1(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.abs(a - b).sum() / max(np.abs(b).sum(), 1e-300))


def tiny_of(normals: np.ndarray, resolution: int, rate: int = 2) -> TinyExample:
    lobes = make_lobes(normals, rate=rate, sigma_r=SIGMA_R)
    e = auto_extent(lobes)
    return TinyExample(lobes, ndf_maps(lobes, resolution, e), e)


def timed(fn, repeats: int) -> tuple[float, object]:  # type: ignore[no-untyped-def]
    out = fn()  # warm-up: kernel compilation
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def speed_table(repeats: int, queries: int) -> None:
    mi = load_mitsuba()
    n = 16
    normals = procedural_example("isotropic_noise", n, np.random.default_rng(3))
    ex = tiny_of(normals, 64)
    surf = Surface(normals, Distribution())
    side = 2 * 8 * n  # the exported region (global texels) covers the widest footprint
    k = 2
    ref = make_lobes(export_normal_map(surf, side, oversample=k), rate=1, sigma_r=SIGMA_R)
    jl, jm, jr = jit_lobes(mi, ex.lobes), jit_maps(mi, ex.maps, ex.extent), jit_lobes(mi, ref)
    rng = np.random.default_rng(0)
    q = rng.uniform(-0.5, 0.5, (queries, 2)).astype(np.float32)
    fq = (mi.Float(q[:, 0]), mi.Float(q[:, 1]))
    print(
        "| examples covered | footprint sigma (texels) | tiny ns/eval | Yan ns/eval | speed-up "
        "| L1 tiny vs Yan |"
    )
    print("| --- | --- | --- | --- | --- | --- |")
    c = np.array([side / 2, side / 2])
    for covered in (0.25, 1.0, 4.0, 16.0):
        # The support box's side is 2 * 3.5 sigma; `covered` examples of n x n fill it.
        sigma = math.sqrt(covered) * n / (2 * SUPPORT_SIGMAS)
        t_tiny, a = timed(_tiny_call(mi, jm, jl, c, sigma, fq, queries), repeats)
        t_yan, b = timed(_yan_call(mi, jr, k * c, k * sigma, fq, queries), repeats)
        err = l1(np.asarray(a), np.asarray(b))
        print(
            f"| {covered:g} | {sigma:.2f} | {1e9 * t_tiny / queries:.1f} | "
            f"{1e9 * t_yan / queries:.1f} | {t_yan / t_tiny:.1f}x | {err:.3f} |"
        )


def _full(mi: object, v: float, n: int) -> object:
    return mi.Float(np.full(n, v, np.float32))  # type: ignore[attr-defined]


def _tiny_call(mi, jm, jl, c, sigma, fq, n):  # type: ignore[no-untyped-def]
    def run() -> np.ndarray:
        cov = Sym2(_full(mi, sigma**2, n), _full(mi, 0.0, n), _full(mi, sigma**2, n))
        centre = (_full(mi, c[0], n), _full(mi, c[1], n))
        return jit_tiny(mi, jm, jl, (np.eye(2), np.zeros(2)), centre, cov, fq).numpy()

    return run


def _yan_call(mi, jr, c, sigma, fq, n):  # type: ignore[no-untyped-def]
    def run() -> np.ndarray:
        cov = Sym2(_full(mi, sigma**2, n), _full(mi, 0.0, n), _full(mi, sigma**2, n))
        centre = (_full(mi, c[0], n), _full(mi, c[1], n))
        return lobes_pndf(mi, jr, centre, cov, fq).numpy()

    return run


def memory_table() -> None:
    print("| material (Table 3) | example | R | ours MiB | reference | reference MiB | ratio |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    rows = [("structure", 8, 6144), ("isotropic", 16, 4096), ("scratches", 32, 4096),
            ("anisotropic", 256, 4096)]  # fmt: skip
    for name, n, ref_side in rows:
        levels = int(math.log2(n))
        tiles = sum((n >> (lv + 1)) ** 2 for lv in range(levels))
        ours = tiles * 128 * 128 * 4 + n * n * 16 * LOBE_BYTES  # R = 128, rate 4
        ref = ref_side * ref_side * 16 * LOBE_BYTES  # the same lobe rate, one record each
        print(
            f"| {name} | {n}x{n} | 128 | {ours / 2**20:.2f} | {ref_side}^2 | {ref / 2**20:.0f} "
            f"| {100 * ours / ref:.2f} % |"
        )


def precompute_table(quick: bool) -> None:
    print("| example | R = 32 s | R = 64 s | R = 128 s |")
    print("| --- | --- | --- | --- |")
    sizes = (8, 16, 32) if quick else (8, 16, 32, 64)
    for n in sizes:
        normals = procedural_example("scratches", n, np.random.default_rng(1))
        cells = []
        for r in (32, 64, 128):
            t0 = time.perf_counter()
            lobes = make_lobes(normals, rate=2, sigma_r=SIGMA_R)
            ndf_maps(lobes, r, auto_extent(lobes))
            cells.append(f"{time.perf_counter() - t0:.2f}")
        print(f"| {n}x{n} | " + " | ".join(cells) + " |")


def example_size_table() -> None:
    print("| brushed metal example | memory KiB (R = 64) | L1 vs Yan, sigma 2 | L1, sigma 8 |")
    print("| --- | --- | --- | --- |")
    # The "true" microstructure: a 32x32 example tiled; smaller examples are crops of it.
    truth = procedural_example("brushed_metal", 32, np.random.default_rng(5))
    big = make_lobes(
        export_normal_map(Surface(truth, Distribution()), 64, oversample=2),
        rate=1,
        sigma_r=SIGMA_R,
    )
    q = np.random.default_rng(1).uniform(-0.5, 0.5, (3000, 2))
    for n in (8, 16, 32):
        crop = truth[:n, :n].copy()
        ex = tiny_of(crop, 64)
        surf = Surface(crop, Distribution())
        mem = map_bytes(ex.maps) + len(ex.lobes) * LOBE_BYTES
        errs = []
        for sigma in (2.0, 8.0):
            c, cov = np.array([32.0, 32.0]), np.eye(2) * sigma**2
            errs.append(l1(tiny_pndf(ex, surf, c, cov, q), yan_pndf(big, 2 * c, 4 * cov, q)))
        print(f"| {n}x{n} | {mem / 1024:.0f} | {errs[0]:.3f} | {errs[1]:.3f} |")


def wood_grain(size: int, rng: np.random.Generator) -> np.ndarray:
    """A macroscopic pattern: rings of a log, distorted, across the whole map (Fig. 14)."""
    y, x = np.mgrid[0:size, 0:size].astype(np.float64) + 0.5
    cx, cy = 0.3 * size, -0.8 * size
    r = np.hypot(x - cx, y - cy) / size
    warp = 0.02 * np.sin(2 * math.pi * (x / size * 3 + rng.uniform()))
    h = 0.6 * np.sin(2 * math.pi * 40 * (r + warp))
    gx = np.gradient(h, axis=1)
    gy = np.gradient(h, axis=0)
    v = np.stack([-gx, -gy, np.ones_like(h)], axis=-1)
    return (v / np.linalg.norm(v, axis=-1, keepdims=True)).astype(np.float32)


def failure_table() -> None:
    q = np.random.default_rng(2).uniform(-0.5, 0.5, (3000, 2))
    print("| case | setting | L1 tiny vs Yan | note |")
    print("| --- | --- | --- | --- |")
    # Macroscopic structure: the best a tiny example can do is a crop of the big map.
    wood = wood_grain(256, np.random.default_rng(4))
    ref = make_lobes(wood, rate=1, sigma_r=SIGMA_R)
    crop = wood[:32, :32].copy()
    ex = tiny_of(crop, 64)
    surf = Surface(crop, Distribution())
    for c in ((40.0, 40.0), (200.0, 180.0)):
        cc, cov = np.array(c), np.eye(2) * 36.0
        err = l1(tiny_pndf(ex, surf, cc, cov, q), yan_pndf(ref, cc, cov, q))
        print(f"| wood grain (Fig. 14) | 32x32 crop, footprint at {c} | {err:.3f} | "
              "the rings' orientation drifts across the map |")  # fmt: skip
    # Footprints below the finest tile: both use lobes; the error is the lobe rates'.
    normals = procedural_example("isotropic_noise", 16, np.random.default_rng(3))
    ex = tiny_of(normals, 64)
    s_t = Surface(normals, Distribution(transform=Transform.compose(rotation_deg=30.0)))
    big = make_lobes(export_normal_map(s_t, 64, oversample=4), rate=1, sigma_r=SIGMA_R)
    for sigma in (0.25, 1.0, 4.0, 16.0):
        c, cov = np.array([30.0, 31.0]), np.eye(2) * sigma**2
        err = l1(tiny_pndf(ex, s_t, c, cov, q), yan_pndf(big, 4 * c, 16 * cov, q))
        print(f"| footprint size | sigma {sigma:g} texels | {err:.3f} | "
              f"{'lobes' if sigma < 4 else 'NDF maps'} |")  # fmt: skip
    # Grazing views: the footprint stretches along the view (1 : 1/cos theta_o); the level
    # follows its smallest width, so long footprints cost many tiles.
    for deg in (60.0, 80.0, 85.0):
        stretch = 1.0 / math.cos(math.radians(deg))
        c, cov = np.array([30.0, 31.0]), np.diag([4.0, 4.0 * stretch**2])
        err = l1(tiny_pndf(ex, s_t, c, cov, q), yan_pndf(big, 4 * c, 16 * cov, q))
        print(f"| grazing view | theta_o {deg:g}, footprint 2 x {2 * stretch:.0f} texels | "
              f"{err:.3f} | level set by the narrow side |")  # fmt: skip
    # Overlapping stochastic instances: error where the footprint sits on an overlap.
    s_s = Surface(normals, Distribution(kind="stochastic", scale_range=(0.8, 1.25), seed=1))
    big = make_lobes(export_normal_map(s_s, 64, oversample=4), rate=1, sigma_r=SIGMA_R)
    for sigma in (1.0, 4.0):
        errs = []
        for c in np.random.default_rng(5).uniform(12, 52, (6, 2)):
            cov = np.eye(2) * sigma**2
            errs.append(l1(tiny_pndf(ex, s_s, c, cov, q), yan_pndf(big, 4 * c, 16 * cov, q)))
        print(
            f"| stochastic overlaps | sigma {sigma:g}, 6 positions | "
            f"{np.median(errs):.3f} (max {max(errs):.3f}) | occlusion resolved per tile |"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--queries", type=int, default=1 << 18)
    parser.add_argument("--quick", action="store_true", help="smaller precompute table")
    args = parser.parse_args()
    print(
        f"machine: {platform.processor() or platform.machine()}, python {platform.python_version()}"
    )
    print("\n### P-NDF evaluation speed\n")
    speed_table(args.repeats, args.queries)
    print("\n### Memory (Table 3 analogue)\n")
    memory_table()
    print("\n### Precompute (Table 2 analogue)\n")
    precompute_table(args.quick)
    print("\n### Example size (Fig. 13 analogue)\n")
    example_size_table()
    print("\n### Where the method fails\n")
    failure_table()
    print(f"\ncommand: .venv/bin/python benchmarks/bench_glint.py --repeats {args.repeats}")


if __name__ == "__main__":
    main()
