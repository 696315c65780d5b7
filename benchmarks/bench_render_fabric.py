"""Render time per frame of a woven fabric: Monte Carlo aggregate at 1 and 256 spp, network.

Chen, Wang & Wang 2024, Sec. 6: the ground truth is the aggregated BSDF of each pixel's
footprint by Monte Carlo at 256 samples per pixel, the baseline the same at 1 spp, and the
network replaces the aggregate by one decoder evaluation. Here: ``cloth_plane`` (the
``render`` kind's scene: a 3x3 cloth under the studio environment and a point light) with
``{"fabric": ...}`` through the ``fabric_path`` integrator, at 1 and ``--spp`` samples per
pixel, and the ``fabric_model`` BSDF with a ``train.fabric`` network (``--model``, a
model.json or model.pt, its first training material; by default a freshly initialised
``small``-preset network: speed does not depend on the weights) at 1 and ``--spp`` spp.

Each configuration is rendered once to compile its kernel, then ``--repeats`` times (the
256-spp Monte Carlo frame once unless asked); a row is the median seconds per frame with a
host read-back of the image (Dr.Jit's laziness hides nothing) and the 1-minute load average.

Run: ``.venv/bin/python benchmarks/bench_render_fabric.py [--size 256] [--spp 256]
[--max-depth 4] [--repeats 3] [--model model.json]``
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from evaluators.render.bsdfs.fabric_aggregate import fabric_bsdf  # noqa: E402
from evaluators.render.bsdfs.fabric_model import (  # noqa: E402
    FABRIC_MODEL_BSDF_NAME,
    register_fabric_model_bsdf,
)
from evaluators.render.integrators import integrator_for  # noqa: E402
from evaluators.render.scenes import SceneSetup, build_scene  # noqa: E402
from materials.backend import load_mitsuba  # noqa: E402
from materials.fabric.params import (
    FabricParams,  # noqa: E402
    params_json,  # noqa: E402
)

MATERIAL = FabricParams(
    "twill_3x3",
    psi_deg=20.0,
    u_max_deg=25.0,
    alpha=0.3,
    beta=0.8,
    kd_warp=(0.7, 0.2, 0.15),
    kd_weft=(0.2, 0.3, 0.6),
    ks_warp=0.6,
    ks_weft=0.6,
)


def default_model(path: Path) -> None:
    """A fresh ``small``-preset network's model.json (decoder width 32) at ``path``."""
    import numpy as np

    from models.fabric.networks import Architecture, build_network
    from models.fabric.portable import to_portable

    net = build_network(Architecture(encoder_width=32, map_resolution=64, decoder_width=32), 0)
    z = np.zeros((1, net.arch.latent_dim), np.float32)
    doc = to_portable(net, ["bench"], ["twill_3x3"], [json.loads(params_json(MATERIAL))], z)
    path.write_text(json.dumps(doc))


def scene(mi: Any, bsdf: Any, size: int, max_depth: int) -> Any:
    d = build_scene("cloth_plane", mi, bsdf, SceneSetup((size, size), 1, max_depth))
    d["integrator"] = integrator_for(mi, bsdf, d["integrator"])
    return mi.load_dict(d)


def seconds(mi: Any, sc: Any, spp: int, repeats: int) -> float:
    import numpy as np

    np.asarray(mi.render(sc, spp=spp, seed=0))  # compile
    times = []
    for seed in range(1, repeats + 1):
        t0 = time.perf_counter()
        np.asarray(mi.render(sc, spp=spp, seed=seed))  # host read-back
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--max-depth", type=int, default=4)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--model", type=Path, default=None)
    args = ap.parse_args()
    mi = load_mitsuba()
    import numpy as np

    from models.fabric.fused import load_fabric_model

    with tempfile.TemporaryDirectory() as tmp:
        path = args.model or Path(tmp) / "model.json"
        if args.model is None:
            default_model(path)
        model = load_fabric_model(path.read_bytes())
        register_fabric_model_bsdf(mi)
        net = mi.load_dict(
            {
                "type": FABRIC_MODEL_BSDF_NAME,
                "filename": str(path),
                "latent": mi.TensorXf(np.asarray(next(iter(model.latents.values())))),
                "params": params_json(MATERIAL),
                "tiles_per_uv": 16.0,
            }
        )
        mc = fabric_bsdf(mi, MATERIAL, tiles_per_uv=16.0)
        rows = [
            ("Monte Carlo aggregate", mc, 1, args.repeats),
            ("Monte Carlo aggregate", mc, args.spp, 1),
            ("network (fused decoder)", net, 1, args.repeats),
            ("network (fused decoder)", net, args.spp, 1),
        ]
        print(f"cloth_plane {args.size}x{args.size}, max_depth {args.max_depth}, {mi.variant()}")
        print("| material | spp | s/frame | Mpaths/s | load |")
        print("| --- | --- | --- | --- | --- |")
        for label, bsdf, spp, reps in rows:
            sc = scene(mi, bsdf, args.size, args.max_depth)
            t = seconds(mi, sc, spp, reps)
            mpaths = args.size * args.size * spp / t / 1e6
            load = os.getloadavg()[0]
            print(f"| {label} | {spp} | {t:.3f} | {mpaths:.2f} | {load:.2f} |", flush=True)
    print(
        f"\n`.venv/bin/python benchmarks/bench_render_fabric.py --size {args.size} "
        f"--spp {args.spp} --max-depth {args.max_depth} --repeats {args.repeats}`"
    )


if __name__ == "__main__":
    main()
