"""``generate.btf`` at the paper's scale: the measured slice rate of 400 x 400 slices of a
procedural surface, extrapolated to UBO2014's 151 x 151 pairs, with the Monte Carlo error
each setting leaves.

For each surface and setting (spp, max_depth, jitter), one :class:`SliceRenderer` renders
``--slices`` pairs spread over the ``ubo2014`` set (after one warm-up slice that compiles
Mitsuba's kernels). The table gives the median seconds per slice, the extrapolated hours
for 22801 slices (plus the mesh build, once per worker process), the stated error (the RMS
per-texel standard error the shards record, relative to the mean BTF value) and the
measured error: the RMS difference from a 256-spp render of the same slices (its own error
taken out), relative to the mean.

The issue's goal: a paper-scale material in at most 2 h on 2 cores.

Run: ``.venv/bin/python benchmarks/bench_btf_generate.py [--slices 9] [--quick]``
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

from evaluators.render.btf.patch import procedural_mesh  # noqa: E402
from evaluators.render.btf.slices import SliceRenderer  # noqa: E402
from materials.backend import load_mitsuba  # noqa: E402
from materials.btf.directions import preset_pairs  # noqa: E402
from materials.btf.surfaces import procedural_surface  # noqa: E402

PAPER_SLICES = 151 * 151
REFERENCE_SPP = 256
SETTINGS = ((4, 4, True), (4, 4, False), (4, 3, True), (2, 4, True), (8, 4, True))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--slices", type=int, default=8)
    ap.add_argument("--resolution", type=int, default=400)
    ap.add_argument("--quick", action="store_true", help="64 x 64 slices, 3 of them")
    args = ap.parse_args()
    res, count = (64, 3) if args.quick else (args.resolution, args.slices)
    mi = load_mitsuba()
    cpu = platform.processor() or platform.machine()
    print(f"machine: {cpu}, {os.cpu_count()} cores; Mitsuba {mi.variant()}; {res}x{res} slices")
    wi, wo = preset_pairs("ubo2014")
    picks = np.linspace(0, len(wi) - 1, count + 2).astype(int)[1:-1]
    print()
    print(
        "| surface | spp | max_depth | jitter | s / slice (median) | 22801 slices, h "
        "| stated error | measured error |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for kind in ("leather", "stone"):
        maps = procedural_surface(kind, res, np.random.default_rng(1), relief=0.02)
        t0 = time.perf_counter()
        mesh = procedural_mesh(mi, maps)
        build = time.perf_counter() - t0
        refs = {}
        for spp, depth, strat in SETTINGS:
            r = SliceRenderer(mi, mesh, max_depth=depth)
            r.render(wi[0], wo[0], res, spp, seed=0)  # warm-up: kernels
            times, stated, measured, means = [], [], [], []
            for k in picks:
                t0 = time.perf_counter()
                s = r.render(wi[k], wo[k], res, spp, seed=int(k), stratified=strat)
                times.append(time.perf_counter() - t0)
                if (k, depth) not in refs:
                    refs[k, depth] = r.render(wi[k], wo[k], res, REFERENCE_SPP, seed=10**6 + k)
                ref = refs[k, depth]
                err2 = float(np.mean((s.rgb.astype(np.float64) - ref.rgb) ** 2))
                measured.append(max(err2 - ref.stderr**2, 0.0))
                stated.append(s.stderr**2)
                means.append(float(ref.rgb.mean()))
            med = statistics.median(times)
            hours = (build + med * PAPER_SLICES) / 3600
            mean = float(np.mean(means))
            st = float(np.sqrt(np.mean(stated))) / mean
            me = float(np.sqrt(np.mean(measured))) / mean
            jit = "stratified" if strat else "independent"
            print(
                f"| {kind} | {spp} | {depth} | {jit} | {med:.3f} | {hours:.2f} | "
                f"{100 * st:.1f} % | {100 * me:.1f} % |"
            )
        print(f"| {kind}: mesh build {build:.1f} s | | | | | | | |")


if __name__ == "__main__":
    main()
