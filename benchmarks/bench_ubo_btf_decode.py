"""Decoding slices from a Bonn ``.btf`` (DFMF): milliseconds per slice and peak memory.

Writes a synthetic DFMF of ``--size`` squared texels, 151 lights x ``--views`` views and
``--components`` random components per channel (half precision, colour model 11, as
UBO2014's files), then decodes ``--repeats`` groups of 16 slices with
:class:`storage.formats.ubo_btf.UboBtf` and prints the median time per slice and the
process's peak resident memory.

Run: ``.venv/bin/python benchmarks/bench_ubo_btf_decode.py [--size 400] [--components 32]``
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from storage.formats.ubo_btf import GROUP, UboBtf
from storage.formats.ubo_btf_write import write_dfmf


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=400)
    ap.add_argument("--views", type=int, default=2)
    ap.add_argument("--components", type=int, default=32)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    n_l, n_v, side, k = 151, args.views, args.size, args.components
    lights = np.column_stack([np.linspace(0, 1.3, n_l), np.linspace(-3, 3, n_l)])
    factors = [(rng.uniform(0, 0.3, (n_l * n_v, k)), rng.uniform(0, 0.3, (side * side, k)))
               for _ in range(3)]  # fmt: skip
    with tempfile.TemporaryDirectory() as tmp:
        path = write_dfmf(Path(tmp) / "bench.btf", lights=lights, views=lights[:n_v],
                          width=side, height=side, factors=factors, scalar=2,
                          color_model=11)  # fmt: skip
        del factors
        btf, times = UboBtf(path), []
        for r in range(args.repeats):
            t = time.perf_counter()
            btf.decode(range(GROUP * r, GROUP * (r + 1)))
            times.append((time.perf_counter() - t) / GROUP)
        mb = path.stat().st_size / 1e6
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3
    print(f"# {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"load {os.getloadavg()[0]:.1f}")  # fmt: skip
    print("| texels | components | file | ms per slice (median) | peak RSS |")
    print("| --- | --- | --- | --- | --- |")
    print(f"| {side}x{side} | {k} | {mb:.1f} MB | {1e3 * statistics.median(times):.1f} | "
          f"{rss:.0f} MB |")  # fmt: skip
    print(f"command: .venv/bin/python benchmarks/bench_ubo_btf_decode.py --size {side} "
          f"--views {n_v} --components {k} --repeats {args.repeats}")  # fmt: skip


if __name__ == "__main__":
    main()
