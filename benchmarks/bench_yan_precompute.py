"""Precompute of the glint evaluators as the Table 3 analogue builds them (the paper's
Table 2 compares both): the tiny model's lobes plus NDF maps (``generate.glint``: a 32 x 32
example, 2 x 2 lobes per texel, R = 64) against the brute-force Yan reference's export plus
lobes (``render`` with ``method: yan``: the surface exported at ``texels_per_uv`` texels,
``yan_rate`` x ``yan_rate`` lobes per texel). Yan here has no hierarchy over normals (its
paper's min-max tree is not built): the figure is the export and the lobes only.

Median of ``--repeats`` runs of each, seconds, one process.

Run: ``.venv/bin/python benchmarks/bench_yan_precompute.py [--texels 2048] [--repeats 3]``
"""

from __future__ import annotations

import argparse
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from materials.glints.examples import procedural_example  # noqa: E402
from materials.glints.lobes import LOBE_BYTES, make_lobes  # noqa: E402
from materials.glints.ndf_maps import auto_extent, ndf_maps  # noqa: E402
from materials.glints.surface import Distribution, Surface, export_normal_map  # noqa: E402

SIGMA_R = 0.02


def _median(fn: object, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()  # type: ignore[operator]
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--texels", type=int, default=2048, help="texels per uv of the export")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--rates", default="1,2", help="Yan lobe rates, comma separated")
    args = parser.parse_args()
    normals = procedural_example("scratches", 32, np.random.default_rng(3))

    def tiny() -> None:
        lobes = make_lobes(normals, rate=2, sigma_r=SIGMA_R)
        ndf_maps(lobes, 64, auto_extent(lobes))

    surface = Surface(normals, Distribution())
    print(f"# {platform.processor() or platform.machine()}; command: {' '.join(sys.argv)}")
    print("| evaluator | precompute s (median) | lobes | MiB |")
    print("| --- | --- | --- | --- |")
    t = _median(tiny, args.repeats)
    print(f"| tiny model (32x32, rate 2, R 64) | {t:.3f} | {32 * 32 * 4} | (stats.json) |")
    for rate in (int(r) for r in args.rates.split(",")):

        def yan(rate: int = rate) -> None:
            make_lobes(export_normal_map(surface, args.texels), rate=rate, sigma_r=SIGMA_R)

        t = _median(yan, args.repeats)
        n = args.texels * args.texels * rate * rate
        print(
            f"| brute-force Yan ({args.texels}^2, rate {rate}) | {t:.2f} | {n} "
            f"| {n * LOBE_BYTES / 2**20:.0f} |"
        )


if __name__ == "__main__":
    main()
