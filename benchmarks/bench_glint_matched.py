"""Glint P-NDF speed at matched error, at the render's own footprints: the tiny-example model
and Yan et al. 2016's hierarchical evaluation, each against the brute-force Yan, beside
Yan's own discretisation floor.

**Queries.** The ``bent_quad`` scene at ``--resolution`` (128 x 96) and ``--texels`` per uv
(2048): for every pixel whose centre ray (the ``fabric_path`` integrator's one-pixel
differentials) hits the quad, its Heckbert footprint in texels (as the ``glint`` BSDF
computes it) and half vectors: one per point light that lights the point (the same for
every seed) and ``--draws`` drawn from the matching GGX's visible normals (per render seed,
``--seeds`` of them). The script prints the pixels' median side in texels (the square root
of the footprint parallelogram's area).

**Methods**, all fused Dr.Jit kernels over the same queries:

- ``tiny``: the tiny-example model (``lookup`` ``flat``) over the tiled example;
- ``Yan hier``: :func:`materials.glints.pndf_yan_hier.hier_pndf` on the export (``oversample``
  1, ``yan_rate`` 2: 2 x 2 lobes per texel, as the tiny model's), its build timed as
  precompute;
- ``Yan brute``: :func:`materials.glints.pndf_drjit.lobes_pndf` on the same lobes (the
  reference);
- ``Yan rate 1`` (the floor): the brute force on the same export at one lobe per texel: how
  far Yan is from itself under its own sampling of the normal map.

No evaluation is capped (``MAX_ITEMS``). **Error**: relative L1 over a seed's queries,
``sum |D - D_ref| / sum |D_ref|``, mean and range over the seeds. **Time**: ns per
evaluation, the median over the seeds of each seed's median of ``--repeats`` runs after a
warm-up, host read-back included.

Run: ``.venv/bin/python benchmarks/bench_glint_matched.py [--examples scratches:32 ...]``
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from evaluators.render.bsdfs.glint import example_slopes  # noqa: E402
from evaluators.render.scenes import SCENES, SceneSetup, build_scene  # noqa: E402
from evaluators.render.sources.glint import matching_alpha  # noqa: E402
from materials.backend import load_mitsuba  # noqa: E402
from materials.glints.examples import procedural_example  # noqa: E402
from materials.glints.footprint import PIXEL_SIGMA  # noqa: E402
from materials.glints.lobes import LOBE_BYTES, make_lobes  # noqa: E402
from materials.glints.ndf_maps import auto_extent, map_bytes, ndf_maps  # noqa: E402
from materials.glints.pndf_drjit import Sym2, jit_lobes, jit_maps, lobes_pndf  # noqa: E402
from materials.glints.pndf_drjit import tiny_pndf as jit_tiny  # noqa: E402
from materials.glints.pndf_yan_hier import build_bounds, hier_pndf, jit_bounds  # noqa: E402
from materials.glints.surface import Distribution, Surface, export_normal_map  # noqa: E402

SIGMA_R = 0.02
#: Texels (tiles, leaf blocks) one evaluation may visit: far above any footprint here, so
#: that no method truncates (the render's cap, 2^16 texels, truncates the brute force at
#: the quad's grazing footprints).
MAX_ITEMS = 1 << 24


def footprints(mi: Any, scene_name: str, res: tuple[int, int], texels: float) -> dict[str, Any]:
    """Per pixel hitting the object: footprint centre and covariance (texels), and the
    interaction (for half vectors)."""
    import drjit as dr

    scene_dict = build_scene(scene_name, mi, {"type": "diffuse"}, SceneSetup(res, 1, 2))
    scene_dict["integrator"] = {"type": "path"}
    scene = mi.load_dict(scene_dict)
    sensor = scene.sensors()[0]
    w, h = res
    idx = dr.arange(mi.UInt32, w * h)
    pos = mi.Vector2f(mi.Float(idx % w) + 0.5, mi.Float(idx // w) + 0.5)
    ray, _ = sensor.sample_ray_differential(0.0, 0.0, pos / mi.ScalarVector2f(w, h), 0.0)
    si = scene.ray_intersect(ray)
    si.compute_uv_partials(ray)
    s2 = PIXEL_SIGMA * PIXEL_SIGMA
    ax, ay = si.duv_dx.x * texels, si.duv_dx.y * texels
    bx, by = si.duv_dy.x * texels, si.duv_dy.y * texels
    cov = (
        s2 * (ax * ax + bx * bx) + 1e-6,
        s2 * (ax * ay + bx * by),
        s2 * (ay * ay + by * by) + 1e-6,
    )
    return {"si": si, "hit": si.is_valid(), "c": (si.uv.x * texels, si.uv.y * texels), "cov": cov}


def queries(mi: Any, fp: dict[str, Any], lights: Any, alpha: float, draws: int, seed: int) -> dict:
    """The seed's queries: ``(c, cov, q)`` as numpy, one row per (pixel, half vector)."""
    import drjit as dr

    si = fp["si"]
    rows: list[tuple[np.ndarray, ...]] = []

    def add(hvec: Any, ok: Any) -> None:
        sx, sy = example_slopes(mi, si, hvec)
        keep = np.asarray((ok & fp["hit"]).numpy(), bool)
        cols = [*fp["c"], *fp["cov"], sx, sy]
        rows.append(tuple(np.asarray(v.numpy(), np.float32)[keep] for v in cols))

    wi = si.wi
    for light in lights:
        d = mi.Point3f(*light.position) - si.p
        wo = si.to_local(dr.normalize(d))
        add(dr.normalize(wi + wo), (wi.z > 0) & (wo.z > 0))
    ggx = mi.MicrofacetDistribution(mi.MicrofacetType.GGX, alpha, True)
    rng = np.random.default_rng(seed)
    m = dr.width(si.p)
    for _ in range(draws):
        u = mi.Point2f(*(mi.Float(rng.random(m).astype(np.float32)) for _ in range(2)))
        hvec, _ = ggx.sample(wi, u)
        add(hvec, wi.z > 0)
    cols = [np.concatenate([r[i] for r in rows]) for i in range(7)]
    return {"c": cols[0:2], "cov": cols[2:5], "q": cols[5:7]}


def timed(fn: Any, repeats: int) -> tuple[float, np.ndarray]:
    out = fn()
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        ts.append(time.perf_counter() - t0)
    return statistics.median(ts), np.asarray(out, np.float64)


def l1(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.abs(a - b).sum() / max(np.abs(b).sum(), 1e-300))


def run_example(mi: Any, kind: str, size: int, args: argparse.Namespace, fp: dict) -> None:
    normals = procedural_example(kind, size, np.random.default_rng(3))
    lobes = make_lobes(normals, rate=2, sigma_r=SIGMA_R)
    e = auto_extent(lobes)
    t0 = time.perf_counter()
    maps = ndf_maps(lobes, 64, e)
    t_maps = time.perf_counter() - t0
    surface = Surface(normals, Distribution())
    side = int(math.ceil(args.texels))
    t0 = time.perf_counter()
    explicit = export_normal_map(surface, side, oversample=1)
    ref2 = make_lobes(explicit, rate=2, sigma_r=SIGMA_R)
    t_export = time.perf_counter() - t0
    t0 = time.perf_counter()
    bounds = build_bounds(ref2)
    t_bounds = time.perf_counter() - t0
    ref1 = make_lobes(explicit, rate=1, sigma_r=SIGMA_R)
    del explicit
    jt, jm = jit_lobes(mi, lobes), jit_maps(mi, maps, e)
    j2, jb, j1 = jit_lobes(mi, ref2), jit_bounds(mi, bounds), jit_lobes(mi, ref1)
    del ref1
    alpha = matching_alpha(surface, SIGMA_R)
    lights = SCENES[args.scene].lights
    eye = (np.eye(2), np.zeros(2))
    cap = MAX_ITEMS
    methods = {
        "tiny": lambda c, cov, q: jit_tiny(mi, jm, jt, eye, c, cov, q, max_items=cap),
        "Yan hier (rate 2)": lambda c, cov, q: hier_pndf(mi, j2, jb, c, cov, q, max_items=cap),
        "Yan brute (rate 2)": lambda c, cov, q: lobes_pndf(mi, j2, c, cov, q, max_items=cap),
        "Yan brute (rate 1), floor": lambda c, cov, q: lobes_pndf(mi, j1, c, cov, q, max_items=cap),
    }
    errs: dict[str, list[float]] = {k: [] for k in methods}
    times: dict[str, list[float]] = {k: [] for k in methods}
    count = 0
    for seed in range(args.seeds):
        qs = queries(mi, fp, lights, alpha, args.draws, seed)
        count = len(qs["q"][0])
        c = tuple(mi.Float(v) for v in qs["c"])
        cov = Sym2(*(mi.Float(v) for v in qs["cov"]))
        q = tuple(mi.Float(v) for v in qs["q"])
        outs = {}
        for name, fn in methods.items():
            t, out = timed(lambda fn=fn, c=c, cov=cov, q=q: fn(c, cov, q).numpy(), args.repeats)
            times[name].append(1e9 * t / count)
            outs[name] = out
        ref = outs["Yan brute (rate 2)"]
        for name in methods:
            errs[name].append(l1(outs[name], ref))
    yan_bytes = len(ref2) * LOBE_BYTES
    mem = {
        "tiny": map_bytes(maps) + len(lobes) * LOBE_BYTES,
        "Yan hier (rate 2)": yan_bytes + bounds.nbytes,
        "Yan brute (rate 2)": yan_bytes,
        "Yan brute (rate 1), floor": yan_bytes // 4,
    }
    pre = {"tiny": t_maps, "Yan hier (rate 2)": t_export + t_bounds,
           "Yan brute (rate 2)": t_export, "Yan brute (rate 1), floor": float("nan")}  # fmt: skip
    base = statistics.median(times["Yan brute (rate 2)"])
    print(f"\n{kind} {size}x{size}, {args.texels:g} texels per uv, {count} queries per seed")
    print("| method | L1 vs brute Yan rate 2, mean (range) | ns/eval, median (range) "
          "| speed-up vs brute | precompute s | bytes |")  # fmt: skip
    print("| --- | --- | --- | --- | --- | --- |")
    for name in methods:
        e_, t_ = errs[name], times[name]
        print(
            f"| {name} | {statistics.mean(e_):.3g} ({min(e_):.3g}-{max(e_):.3g}) | "
            f"{statistics.median(t_):,.0f} ({min(t_):,.0f}-{max(t_):,.0f}) | "
            f"{base / statistics.median(t_):.2f}x | {pre[name]:.1f} | {mem[name]:,} |"
        )
    sys.stdout.flush()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--examples", nargs="+", default=["scratches:32", "brushed_metal:32"])
    ap.add_argument("--scene", default="bent_quad")
    ap.add_argument("--texels", type=float, default=2048.0)
    ap.add_argument("--resolution", type=int, nargs=2, default=[128, 96])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--draws", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=2)
    args = ap.parse_args()
    mi = load_mitsuba()
    print(f"# {platform.processor() or platform.machine()}, load {os.getloadavg()[0]:.2f}")
    fp = footprints(mi, args.scene, tuple(args.resolution), args.texels)
    hit = np.asarray(fp["hit"].numpy(), bool)
    det = np.asarray((fp["cov"][0] * fp["cov"][2] - fp["cov"][1] ** 2).numpy())[hit]
    side = 2.0 * np.sqrt(np.sqrt(np.maximum(det, 0.0))) / PIXEL_SIGMA / 2.0
    print(f"# {hit.sum()} pixels on the object; pixel side (sqrt of its texel area) median "
          f"{np.median(side):.1f} texels")  # fmt: skip
    for spec in args.examples:
        kind, size = spec.split(":")
        run_example(mi, kind, int(size), args, fp)
    print(f"\n# load {os.getloadavg()[0]:.2f}; command: .venv/bin/python {' '.join(sys.argv)}")


if __name__ == "__main__":
    main()
