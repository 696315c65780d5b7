"""The glint BSDF's two samplers, ``ggx_mix`` (the default) and ``pndf`` (the footprint's
P-NDF itself): the spread of the per-sample weight ``f cos / pdf`` (coefficient of variation,
green channel), the albedo it estimates, and the wall time per ``sample`` call.

Setup: the anisotropic-noise 16^2 example (R = 48), Al, wi at 28.6 degrees, 64 texels per uv,
a footprint of ``duv`` per pixel along both axes; 200,000 draws per seed, 3 seeds; time the
median of 5 calls on 2^16 lanes after a warm-up (kernel compilation excluded).

Run: ``nice -n 5 .venv/bin/python benchmarks/bench_glint_sampling.py``
"""

from __future__ import annotations

import math
import os
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from evaluators.render.bsdfs.glint import (  # noqa: E402
    GLINT_BSDF_NAME,
    GlintLayer,
    put_layers,
    register_glint_bsdf,
)
from materials.backend import load_mitsuba  # noqa: E402
from materials.glints.examples import procedural_example  # noqa: E402
from materials.glints.lobes import make_lobes  # noqa: E402
from materials.glints.ndf_maps import auto_extent, ndf_maps  # noqa: E402
from materials.glints.pndf_drjit import jit_lobes, jit_map_sampler, jit_maps  # noqa: E402
from materials.microfacet import NAMED_CONDUCTORS  # noqa: E402

WI = (math.sin(0.5), 0.0, math.cos(0.5))


def main() -> None:
    import drjit as dr

    print(f"load average {os.getloadavg()}")
    mi = load_mitsuba()
    register_glint_bsdf(mi)
    normals = procedural_example("anisotropic_noise", 16, np.random.default_rng(9))
    lobes = make_lobes(normals, rate=2, sigma_r=0.03)
    e = auto_extent(lobes)
    maps = ndf_maps(lobes, 48, e)
    eta, k = NAMED_CONDUCTORS["Al"]
    print("| method | duv | footprint sigma (texels) | sampling | CV of weight (3 seeds) "
          "| albedo estimate | ms per 2^16 samples |")  # fmt: skip
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for method, duv in (("tiny_example", 0.02), ("tiny_example", 0.08), ("tiny_example", 0.3),
                        ("yan", 0.02), ("yan", 0.1)):  # fmt: skip
        for sampling in ("ggx_mix", "pndf"):
            tiny = method == "tiny_example"
            layer = GlintLayer(
                method=method, lobes=jit_lobes(mi, lobes),
                maps=jit_maps(mi, maps, e) if tiny else None,
                transform=(np.eye(2), np.zeros(2)), texel_scale=1.0,
                fresnel=("conductor", eta, k), alpha=0.3, fallback_texels=16.0,
                sampling=sampling, sampler=jit_map_sampler(mi, maps, e) if tiny else None,
            )  # fmt: skip
            key = put_layers(f"bench-{method}-{sampling}", layer)
            bsdf = mi.load_dict({"type": GLINT_BSDF_NAME, "layers": key, "texels_per_uv": 64.0})

            def draw(n: int, seed: int, bsdf: Any = bsdf, duv: float = duv) -> np.ndarray:
                si = dr.zeros(mi.SurfaceInteraction3f, n)
                si.wi = mi.Vector3f(*WI)
                si.uv = mi.Point2f(0.37, 0.61)
                si.duv_dx = mi.Vector2f(duv, 0.0)
                si.duv_dy = mi.Vector2f(0.0, duv)
                u = np.random.default_rng(seed).random((n, 3)).astype(np.float32)
                _, w = bsdf.sample(
                    mi.BSDFContext(), si, mi.Float(u[:, 0]), mi.Point2f(u[:, 1], u[:, 2])
                )
                return np.asarray(w.numpy())[1]

            cvs, means = [], []
            for seed in (1, 2, 3):
                w = draw(200_000, seed)
                cvs.append(float(w.std() / w.mean()))
                means.append(float(w.mean()))
            draw(1 << 16, 9)
            times = []
            for r in range(5):
                t0 = time.perf_counter()
                draw(1 << 16, 10 + r)
                times.append(time.perf_counter() - t0)
            sigma = 0.5 * duv * 64.0
            print(
                f"| {method} | {duv:g} | {sigma:.2f} | {sampling} | "
                f"{statistics.mean(cvs):.2f} ({min(cvs):.2f}-{max(cvs):.2f}) | "
                f"{statistics.mean(means):.4f} | {1e3 * statistics.median(times):.1f} |"
            )


if __name__ == "__main__":
    main()
