"""Render throughput of the ``render`` job's path tracer, in million paths per second.

Renders the ``sphere_env`` scene exactly as the ``render`` kind does (same scene dict, same
passes of about 4 M paths, host read-back after every pass, so Dr.Jit's lazy evaluation
cannot hide work) for a diffuse and a rough-conductor sphere at 256x256 and 512x512,
64 spp, max_depth 8. Each configuration is warmed up once (kernel compilation), then timed
5 times; the row reports the median, and the 1-minute load average after the runs (other
processes on the machine slow the render down; compare rows taken at low load).

Run: ``.venv/bin/python benchmarks/bench_render.py [--repeats 5] [--spp 64]``
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from evaluators.render.kind import plan_passes, render_passes  # noqa: E402
from evaluators.render.scenes import SceneSetup, build_scene  # noqa: E402
from evaluators.render.sources.common import load_bsdf  # noqa: E402
from materials.backend import active_variant, load_mitsuba  # noqa: E402

MATERIALS = {
    "diffuse": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.5, 0.5, 0.5]}},
    "roughconductor a=0.2": {"type": "roughconductor", "alpha": 0.2},
}


def bench(
    resolution: int, material: str, spp: int, max_depth: int, repeats: int
) -> tuple[float, float]:
    """Median seconds of one full render, and the Mpaths/s it gives."""
    mi = load_mitsuba()
    bsdf = load_bsdf(MATERIALS[material], mi, material)
    passes = plan_passes(resolution, resolution, spp)
    seeds = list(range(1, len(passes) + 1))
    setup = SceneSetup(resolution=(resolution, resolution), spp=passes[0], max_depth=max_depth)
    scene = mi.load_dict(build_scene("sphere_env", mi, bsdf, setup))
    render_passes(mi, scene, passes, seeds)  # warm-up: kernel compilation
    times = []
    for r in range(repeats):
        t0 = time.perf_counter()
        render_passes(mi, scene, passes, [s + 1000 * (r + 1) for s in seeds])
        times.append(time.perf_counter() - t0)
    seconds = statistics.median(times)
    return seconds, resolution * resolution * spp / seconds / 1e6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--max-depth", type=int, default=8)
    args = ap.parse_args()
    load_mitsuba()
    machine = f"{platform.machine()}, {os.cpu_count()} cores, {platform.system()}"
    print(
        "| scene | material | resolution | spp | max_depth | variant | median s | Mpaths/s "
        "| machine | load (1 min) |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for resolution in (256, 512):
        for material in MATERIALS:
            seconds, mpaths = bench(resolution, material, args.spp, args.max_depth, args.repeats)
            print(
                f"| sphere_env | {material} | {resolution}x{resolution} | {args.spp} | "
                f"{args.max_depth} | {active_variant()} | {seconds:.3f} | {mpaths:.1f} | "
                f"{machine} | {os.getloadavg()[0]:.1f} |",
                flush=True,
            )
    print(
        f"\nreproduce: .venv/bin/python benchmarks/bench_render.py --repeats {args.repeats} "
        f"--spp {args.spp} --max-depth {args.max_depth}"
    )


if __name__ == "__main__":
    main()
