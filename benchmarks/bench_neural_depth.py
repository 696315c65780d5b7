"""Render time per frame against ``neural_max_depth``: the analogue of the paper's Table 5.

De Oliveira et al., Sec. 5.3 / Table 5: the network is evaluated up to a bounce and the
analytic GGX + Lambert part after it. Here: the ``neural_depth`` integrator
(:mod:`evaluators.render.integrators.neural_depth`) with ``neural_max_depth`` in {0 (analytic
only), 1, 2, inf}, plus Mitsuba's C++ ``path`` integrator with the full model as a reference
for the Python integrator's own cost. Two scenes, both with every surface in the model's
material: ``sphere_env`` as the ``render`` kind builds it (a convex sphere: no path hits it
twice, so only the first bounce can use the network), and ``sphere_env`` with a 8x8 floor
under the sphere (interreflections, so deeper bounces exist).

The material is one of a trained ``model.json`` (``--model``, ``--material``) or, by
default, a hybrid 32x3 model (l = 4) with freshly initialised weights (speed does not depend
on the values). Each configuration is rendered once to compile its kernel, then
``--repeats`` times, configurations interleaved; a row is the median seconds per frame (host
read-back of the image, so Dr.Jit's laziness hides nothing) and the 1-minute load average.

Run: ``.venv/bin/python benchmarks/bench_neural_depth.py [--size 256] [--spp 64]
[--max-depth 8] [--repeats 5] [--model model.json --material NAME]``
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

from evaluators.render.bsdfs.brdf_model import MODEL_BSDF_NAME, register_model_bsdf  # noqa: E402
from evaluators.render.integrators.neural_depth import (  # noqa: E402
    NEURAL_DEPTH_INTEGRATOR,
    register_neural_depth_integrator,
)
from evaluators.render.scenes import SceneSetup, build_scene, floor_under_sphere  # noqa: E402
from materials.backend import load_mitsuba  # noqa: E402

DEPTHS: tuple[tuple[str, int], ...] = (("0 (analytic)", 0), ("1", 1), ("2", 2), ("inf", -1))


def default_model(path: Path) -> str:
    """Write a fresh hybrid 32x3 ``model.json`` to ``path``; returns its material's name."""
    import torch

    from models.brdf.networks import Architecture, build_model
    from models.brdf.portable import to_portable

    model = build_model(Architecture("hybrid", 32, 3, 4), 1, torch.Generator().manual_seed(0))
    doc = to_portable(model, ["bench"], ["bench"])
    doc["materials"][0].update(kd=[0.2, 0.45, 0.7], eta=[1.5, 1.5, 1.5], alpha=0.15)
    path.write_text(json.dumps(doc))
    return "bench"


def scene(mi: Any, bsdf: Any, integrator: dict[str, Any], setup: SceneSetup, floor: bool) -> Any:
    d = build_scene("sphere_env", mi, bsdf, setup)
    d["integrator"] = integrator
    if floor:
        d["floor"] = floor_under_sphere(mi, bsdf)
    return mi.load_dict(d)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=256)
    parser.add_argument("--spp", type=int, default=64)
    parser.add_argument("--max-depth", type=int, default=8)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--model", type=Path)
    parser.add_argument("--material")
    args = parser.parse_args()

    mi = load_mitsuba()
    if not mi.variant().startswith("llvm_"):
        sys.exit(f"needs Mitsuba's LLVM variant, got {mi.variant()}")
    register_model_bsdf(mi)
    register_neural_depth_integrator(mi)
    tmp = tempfile.TemporaryDirectory()
    if args.model is None:
        model_path = Path(tmp.name) / "model.json"
        material = default_model(model_path)
    else:
        model_path = args.model
        material = args.material or json.loads(model_path.read_text())["materials"][0]["name"]
    bsdf = mi.load_dict(
        {"type": MODEL_BSDF_NAME, "filename": str(model_path), "material": material}
    )
    setup = SceneSetup(resolution=(args.size, args.size), spp=args.spp, max_depth=args.max_depth)
    configs: dict[tuple[str, str], Any] = {}
    for floor in (False, True):
        name = "sphere_env + floor" if floor else "sphere_env"
        for label, depth in DEPTHS:
            integ = {
                "type": NEURAL_DEPTH_INTEGRATOR,
                "max_depth": args.max_depth,
                "neural_max_depth": depth,
            }
            configs[(name, label)] = scene(mi, bsdf, integ, setup, floor)
        path = {"type": "path", "max_depth": args.max_depth}
        configs[(name, "inf, C++ path")] = scene(mi, bsdf, path, setup, floor)

    times: dict[tuple[str, str], list[float]] = {k: [] for k in configs}
    for rep in range(args.repeats + 1):
        for key, sc in configs.items():
            start = time.perf_counter()
            mi.render(sc, seed=rep).numpy()  # host read-back: the frame has really run
            if rep:
                times[key].append(time.perf_counter() - start)
    load = os.getloadavg()[0]

    print("| scene | neural until bounce | s/frame | vs analytic | Mpaths/s | load |")
    print("| --- | --- | --- | --- | --- | --- |")
    for (name, label), ts in times.items():
        t = statistics.median(ts)
        base = statistics.median(times[(name, DEPTHS[0][0])])
        mpaths = args.size * args.size * args.spp / t / 1e6
        print(f"| {name} | {label} | {t:.3f} | {t / base:.2f}x | {mpaths:.2f} | {load:.2f} |")
    src = f"--model {args.model}" if args.model else "fresh hybrid 32x3"
    print(
        f"\n{args.size}x{args.size}, {args.spp} spp, max_depth {args.max_depth}, "
        f"median of {args.repeats}; material {material!r} of {src}\n"
        f"reproduce: .venv/bin/python benchmarks/bench_neural_depth.py --size {args.size} "
        f"--spp {args.spp} --max-depth {args.max_depth} --repeats {args.repeats}"
    )
    tmp.cleanup()


if __name__ == "__main__":
    main()
