"""Render throughput of the MERL table BSDF against the native Mitsuba BSDF it tabulates.

Renders ``sphere_env`` exactly as the ``render`` kind does (same scene dict, passes of about
4 M paths, host read-back after every pass, so Dr.Jit's lazy evaluation cannot hide work)
with a native Mitsuba material and with the ``merl_table`` BSDF of its tabulation
(:mod:`evaluators.render.bsdfs.merl_table`): a GGX gold conductor (alpha 0.3) and a rough plastic.
Each
configuration is warmed up once (kernel compilation), then timed ``--repeats`` times,
native and table renders interleaved; a row reports the median wall time, the throughput
relative to the native BSDF, the median CPU time of the process (all its threads) and the
throughput ratio by CPU time, and the 1-minute load average after the runs. On a shared,
loaded machine the wall-clock ratio swings with whatever else runs (other processes take
the cores for whole time slices); the CPU-time ratio counts only this process's own work
and is the steadier figure (it still sees the cache misses other processes cause).

Run: ``.venv/bin/python benchmarks/bench_merl_bsdf.py [--repeats 5] [--spp 64] [--size 256]``
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

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from evaluators.render.bsdfs.merl_table import merl_bsdf  # noqa: E402
from evaluators.render.kind import plan_passes, render_passes  # noqa: E402
from evaluators.render.scenes import SceneSetup, build_scene  # noqa: E402
from evaluators.render.sources.common import load_bsdf  # noqa: E402
from materials.backend import active_variant, load_mitsuba  # noqa: E402
from materials.tabulate import tabulate_mitsuba  # noqa: E402

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
) -> dict[str, tuple[float, float, float]]:
    """Median wall seconds of one full ``sphere_env`` render per BSDF, its Mpaths/s, and
    the median CPU seconds of the process over the render.

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
        out[label] = (seconds, size * size * spp / seconds / 1e6, statistics.median(cpu[label]))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--max-depth", type=int, default=8)
    args = ap.parse_args()
    mi = load_mitsuba()
    machine = f"{platform.machine()}, {os.cpu_count()} cores, {platform.system()}"
    print(
        "| scene | material | BSDF | resolution | spp | max_depth | variant | median s "
        "| Mpaths/s | table / native | median CPU s | table / native (CPU) | machine "
        "| load (1 min) |"
    )
    print("| --- " * 14 + "|")
    for name, plugin in MATERIALS.items():
        table, _ = tabulate_mitsuba(plugin)
        bsdfs = {"native": load_bsdf(plugin, mi, name), "merl_table": merl_bsdf(mi, table)}
        results = bench(bsdfs, args.size, args.spp, args.max_depth, args.repeats)
        native_rate, native_cpu = results["native"][1], results["native"][2]
        for label, (seconds, rate, cpu) in results.items():
            print(
                f"| sphere_env | {name} | {label} | {args.size}x{args.size} | {args.spp} | "
                f"{args.max_depth} | {active_variant()} | {seconds:.3f} | {rate:.2f} | "
                f"{rate / native_rate:.2f} | {cpu:.3f} | {native_cpu / cpu:.2f} | {machine} | "
                f"{os.getloadavg()[0]:.1f} |",
                flush=True,
            )
    print(
        f"\nreproduce: .venv/bin/python benchmarks/bench_merl_bsdf.py --repeats {args.repeats} "
        f"--spp {args.spp} --size {args.size} --max-depth {args.max_depth}"
    )


if __name__ == "__main__":
    main()
