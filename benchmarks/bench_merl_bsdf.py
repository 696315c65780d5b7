"""Render throughput of the MERL table BSDF against the native Mitsuba BSDF it tabulates.

Renders ``sphere_env`` exactly as the ``render`` kind does (same scene dict, passes of about
4 M paths, host read-back after every pass, so Dr.Jit's lazy evaluation cannot hide work)
with a native Mitsuba material and with the ``merl_table`` BSDF of its tabulation
(:mod:`evaluators.render.bsdfs.merl_table`): a GGX gold conductor (alpha 0.3) and a rough
plastic. The table BSDF is rendered in each of the ``--arms`` asked for, all in one run:
``PRECISION/LAYOUT`` with the precisions ``float32`` (the default, 17.5 MB), ``float16``
(11.7 MB, one 64-bit word per bin) and ``rgb9e5`` (5.8 MB, one 32-bit shared-exponent word
per bin), and the layouts ``phi_d`` (MERL's order, phi_d fastest) and ``theta_h`` (theta_h
fastest); and ``texture``, the float32 table read through Dr.Jit's ``Texture3f``
(a measurement arm only, see :func:`texture_bsdf`).

Each configuration is warmed up once (kernel compilation), then timed ``--repeats`` times,
native and table renders interleaved (one of each per repeat, at that repeat's seeds); a
row reports the median wall time, the throughput relative to the native BSDF, the median
CPU time of the process (all its threads), the throughput ratio by CPU time, the range of
the per-repeat CPU-time ratios (each against the native render of the same repeat: the
spread over seeds), and the 1-minute load average after the runs. On a shared, loaded
machine the wall-clock ratio swings with whatever else runs (other processes take the
cores for whole time slices); the CPU-time ratio counts only this process's own work and
is the steadier figure (it still sees the cache misses other processes cause).

With ``--breakdown`` the same run also renders variants of the table BSDF whose ``brdf``
is cut down, to show where its time goes: no table read (a constant), the bin coordinates
only, one read of the nearest bin, and both of those with every read confined to an
L2-sized slice of the table (768 KB). Sampling and pdf are the table BSDF's own in all.

Run: ``.venv/bin/python benchmarks/bench_merl_bsdf.py [--repeats 5] [--spp 64] [--size 256]
[--arms float32/phi_d rgb9e5/phi_d ...] [--breakdown]``
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

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from evaluators.render.bsdfs.merl_table import merl_bsdf, register_merl_bsdf  # noqa: E402
from evaluators.render.kind import plan_passes, render_passes  # noqa: E402
from evaluators.render.scenes import SceneSetup, build_scene  # noqa: E402
from evaluators.render.sources.common import load_bsdf  # noqa: E402
from materials import halfdiff as hd  # noqa: E402
from materials.backend import active_variant, load_mitsuba  # noqa: E402
from materials.lobe_fit import fit_sampling_lobe  # noqa: E402
from materials.tabulate import tabulate_mitsuba  # noqa: E402
from storage.formats.merl import MerlTable  # noqa: E402

#: Bins of the L2-sized slice of the breakdown (64 Ki RGB bins, 768 KB of float32).
L2_SLICE = (1 << 16) - 1

MATERIALS: dict[str, dict[str, Any]] = {
    "roughconductor Au a=0.3": {
        "type": "roughconductor",
        "distribution": "ggx",
        "alpha": 0.3,
        "material": "Au",
    },
    "roughplastic a=0.3": {
        "type": "roughplastic",
        "distribution": "ggx",
        "alpha": 0.3,
        "diffuse_reflectance": {"type": "rgb", "value": [0.2, 0.5, 0.8]},
    },
}


def bench(
    bsdfs: dict[str, Any], size: int, spp: int, max_depth: int, repeats: int
) -> dict[str, tuple[float, float, float, list[float]]]:
    """Median wall seconds of one full ``sphere_env`` render per BSDF, its Mpaths/s, the
    median CPU seconds of the process over the render, and the CPU seconds of each repeat.

    The BSDFs' renders are interleaved (one of each per repeat), so that a change in the
    machine's load affects them alike and their ratio stays meaningful.
    """
    mi = load_mitsuba()
    passes = plan_passes(size, size, spp)
    seeds = list(range(1, len(passes) + 1))
    setup = SceneSetup(resolution=(size, size), spp=passes[0], max_depth=max_depth)
    scenes = {k: mi.load_dict(build_scene("sphere_env", mi, b, setup)) for k, b in bsdfs.items()}
    for scene in scenes.values():
        render_passes(mi, scene, passes, seeds)  # warm-up: kernel compilation
    times: dict[str, list[float]] = {k: [] for k in scenes}
    cpu: dict[str, list[float]] = {k: [] for k in scenes}
    for r in range(repeats):
        for label, scene in scenes.items():
            t0, c0 = time.perf_counter(), time.process_time()
            render_passes(mi, scene, passes, [s + 1000 * (r + 1) for s in seeds])
            times[label].append(time.perf_counter() - t0)
            cpu[label].append(time.process_time() - c0)
    out = {}
    for label, t in times.items():
        seconds = statistics.median(t)
        rate = size * size * spp / seconds / 1e6
        out[label] = (seconds, rate, statistics.median(cpu[label]), cpu[label])
    return out


def breakdown_bsdfs(mi: Any, table: MerlTable) -> dict[str, Any]:
    """The table BSDF and its cut-down variants (see the module docstring), same lobe."""
    import drjit as dr

    cls: Any = register_merl_bsdf(mi)
    ops = hd.drjit_ops(dr)

    def coords(self: Any, wi: Any, wo: Any) -> Any:
        th, td, pd = hd.halfdiff_angles(wi.x, wi.y, wi.z, wo.x, wo.y, wo.z, ops)
        return hd.merl_coordinates(th, td, pd, self.phi_d_bins, ops)

    def constant(self: Any, ctx: Any, wi: Any, wo: Any, active: Any = True) -> Any:
        active = active & (wi.z > 0) & (wo.z > 0)
        return dr.select(active, mi.Color3f(0.3), 0.0)

    def coordinates(self: Any, ctx: Any, wi: Any, wo: Any, active: Any = True) -> Any:
        active = active & (wi.z > 0) & (wo.z > 0)
        return dr.select(active, mi.Color3f(*coords(self, wi, wo)) * 1e-3, 0.0)

    def nearest(mask: int) -> Any:
        def brdf(self: Any, ctx: Any, wi: Any, wo: Any, active: Any = True) -> Any:
            active = active & (wi.z > 0) & (wo.z > 0)
            u_h, u_d, u_p = coords(self, wi, wo)
            n_p = self.phi_d_bins
            i_h = mi.UInt32(dr.clip(mi.Int32(u_h), 0, hd.RES_THETA_H - 1))
            i_d = mi.UInt32(dr.clip(mi.Int32(u_d), 0, hd.RES_THETA_D - 1))
            i_p = mi.UInt32(dr.clip(mi.Int32(u_p), 0, n_p - 1))
            index = ((i_h * hd.RES_THETA_D + i_d) * n_p + i_p) & mask
            return dr.select(active, dr.gather(mi.Color3f, self.table, index, active), 0.0)

        return brdf

    def interpolated_in_slice(self: Any, ctx: Any, wi: Any, wo: Any, active: Any = True) -> Any:
        # The shipped brdf() itself, traced while dr.gather reads modulo the slice.
        gather = dr.gather

        def in_slice(dtype: Any, source: Any, index: Any, *args: Any, **kwargs: Any) -> Any:
            return gather(dtype, source, index & L2_SLICE, *args, **kwargs)

        dr.gather = in_slice
        try:
            return cls.brdf(self, ctx, wi, wo, active)
        finally:
            dr.gather = gather

    variants = {
        "no table read": constant,
        "coordinates only": coordinates,
        "nearest bin": nearest(0xFFFFFFFF),
        "nearest bin, L2 slice": nearest(L2_SLICE),
        "interpolated, L2 slice": interpolated_in_slice,
    }
    lobe = fit_sampling_lobe(table.rgb)
    out = {"merl_table": merl_bsdf(mi, table, lobe)}
    data = mi.TensorXf(table.rgb.astype("float32"))
    for i, (label, brdf) in enumerate(variants.items()):
        sub = type(f"MerlBreakdown{i}", (cls,), {"brdf": brdf})
        name = f"merl_table_breakdown_{i}"
        mi.register_bsdf(name, lambda props, sub=sub: sub(props))
        out[label] = mi.load_dict(
            {
                "type": name,
                "data": data,
                "alpha": lobe.alpha,
                "specular_weight": lobe.specular_weight,
            }
        )
    return out


def texture_bsdf(mi: Any, table: MerlTable, lobe: Any) -> Any:
    """The table BSDF reading its table through Dr.Jit's ``Texture3f`` (trilinear, clamped
    at the edges; phi_d made periodic by one padding bin on each side). A measurement arm
    only: the texture cannot renormalise missing corners, so it is not shipped."""
    import drjit as dr

    cls: Any = register_merl_bsdf(mi)
    n_p = table.phi_d_bins
    rgb = np.asarray(table.rgb, np.float32)
    padded = np.concatenate([rgb[:, :, -1:], rgb, rgb[:, :, :1]], axis=2)
    ops = hd.drjit_ops(dr)

    def brdf(self: Any, ctx: Any, wi: Any, wo: Any, active: Any = True) -> Any:
        active = active & (wi.z > 0) & (wo.z > 0)
        th, td, pd = hd.halfdiff_angles(wi.x, wi.y, wi.z, wo.x, wo.y, wo.z, ops)
        u_h, u_d, u_p = hd.merl_coordinates(th, td, pd, n_p, ops)
        # Texture3f axes: tensor (D, H, W, C) = (theta_h, theta_d, phi_d + 2, 3); pos (x, y, z)
        # along (W, H, D); texel centres at (i + 1/2) / N, as MERL's bin centres.
        pos = mi.Point3f((u_p + 1.0) / (n_p + 2), u_d / hd.RES_THETA_D, u_h / hd.RES_THETA_H)
        v = self.texture.eval(pos, active)
        value = dr.maximum(mi.Color3f(v[0], v[1], v[2]), 0.0)
        return dr.select(active, value, 0.0)

    def init(self: Any, props: Any) -> None:
        cls.__init__(self, props)
        self.texture = mi.Texture3f(
            mi.TensorXf(padded),
            use_accel=True,
            filter_mode=dr.FilterMode.Linear,
            wrap_mode=dr.WrapMode.Clamp,
        )

    sub = type("MerlTexture", (cls,), {"brdf": brdf, "__init__": init})
    mi.register_bsdf("merl_table_texture", lambda props: sub(props))
    return mi.load_dict(
        {
            "type": "merl_table_texture",
            "data": mi.TensorXf(rgb),
            "alpha": lobe.alpha,
            "specular_weight": lobe.specular_weight,
        }
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--max-depth", type=int, default=8)
    ap.add_argument("--breakdown", action="store_true", help="also render cut-down variants")
    ap.add_argument(
        "--arms",
        nargs="+",
        default=[
            "float32/phi_d",
            "float32/theta_h",
            "float16/phi_d",
            "float16/theta_h",
            "rgb9e5/phi_d",
            "rgb9e5/theta_h",
            "texture",
        ],
        help="table arms PRECISION/LAYOUT (float32|float16 / phi_d|theta_h), or 'texture'",
    )
    args = ap.parse_args()
    mi = load_mitsuba()
    machine = f"{platform.machine()}, {os.cpu_count()} cores, {platform.system()}"
    print(
        "| scene | material | BSDF | resolution | spp | max_depth | variant | median s "
        "| Mpaths/s | table / native | median CPU s | table / native (CPU) "
        "| CPU ratio over repeats | machine | load (1 min) |"
    )
    print("| --- " * 15 + "|")
    for name, plugin in MATERIALS.items():
        table, _ = tabulate_mitsuba(plugin)
        bsdfs = {"native": load_bsdf(plugin, mi, name)}
        if args.breakdown:
            bsdfs.update(breakdown_bsdfs(mi, table))
        else:
            lobe = fit_sampling_lobe(table.rgb)
            for arm in args.arms:
                if arm == "texture":
                    bsdfs[arm] = texture_bsdf(mi, table, lobe)
                    continue
                precision, layout = arm.split("/")
                bsdfs[arm] = merl_bsdf(mi, table, lobe, precision=precision, layout=layout)
        results = bench(bsdfs, args.size, args.spp, args.max_depth, args.repeats)
        native_rate, native_cpu = results["native"][1], results["native"][2]
        native_each = results["native"][3]
        for label, (seconds, rate, cpu, each) in results.items():
            paired = [n / c for n, c in zip(native_each, each, strict=True)]
            print(
                f"| sphere_env | {name} | {label} | {args.size}x{args.size} | {args.spp} | "
                f"{args.max_depth} | {active_variant()} | {seconds:.3f} | {rate:.2f} | "
                f"{rate / native_rate:.2f} | {cpu:.3f} | {native_cpu / cpu:.2f} | "
                f"{min(paired):.2f}-{max(paired):.2f} | {machine} | "
                f"{os.getloadavg()[0]:.1f} |",
                flush=True,
            )
    print(
        f"\nreproduce: .venv/bin/python benchmarks/bench_merl_bsdf.py --repeats {args.repeats} "
        f"--spp {args.spp} --size {args.size} --max-depth {args.max_depth} "
        + ("--breakdown" if args.breakdown else f"--arms {' '.join(args.arms)}")
    )


if __name__ == "__main__":
    main()
