"""An MLP handed in as ONNX against the same weights as an MLP document: render time, one run,
interleaved.

The network: a BRDF MLP ``(wi, wo) -> rgb`` of the hybrid's size (6 direction inputs,
``--size`` hidden layers, default 32x3, ReLU, softplus out), random He-initialised weights
(:func:`models.fused_mlp.random_layers`). The same layers are written (a) as a
``matforge.mlp-brdf/1`` document, rendered by ``external_mlp``, and (b) built into torch,
exported with :func:`matforge.export_onnx.brdf_onnx` and rendered by ``external_onnx``,
which recognises the graph and compiles it into the fused Dr.Jit kernel
(:mod:`models.external.onnx_mlp`); (c) the same ONNX file forced into onnxruntime
(``runtime: onnxruntime``, in Dr.Jit's evaluated mode), for scale. All three sample the
cosine lobe.

Protocol: ``sphere_env`` at ``--resolution`` and ``--spp`` (``render_passes`` as the
``render`` kind), one warm-up render each (kernel compilation), then ``--repeats`` rounds in
which the three renders run round-robin (so a change of load hits all of them), ``--threads``
Dr.Jit threads; medians and min-max per runtime, the ratios of the medians, and the load
average before and after. The images of (a) and (b) are first checked to agree (rtol 1e-4).

Run: ``nice -n 10 .venv/bin/python benchmarks/bench_onnx_fused.py [--size 32x3]
[--resolution 128] [--spp 64] [--repeats 5] [--threads 2] [--skip-onnxruntime]``
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import tempfile
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from materials.backend import load_mitsuba  # noqa: E402
from models.fused_mlp import random_layers, torch_mlp  # noqa: E402


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--size", default="32x3")
    ap.add_argument("--resolution", type=int, default=128)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--skip-onnxruntime", action="store_true")
    args = ap.parse_args()

    mi = load_mitsuba()
    import drjit as dr
    import torch

    from evaluators.render.bsdfs.external_mlp import EXTERNAL_MLP_NAME, register_external_mlp_bsdf
    from evaluators.render.bsdfs.external_onnx import external_onnx_plugin, wavefront_scope
    from evaluators.render.kind import PATHS_PER_PASS, plan_passes, render_passes
    from evaluators.render.scenes import SceneSetup, build_scene
    from matforge.export_onnx import brdf_onnx

    dr.set_thread_count(args.threads)
    width, depth = (int(v) for v in args.size.split("x"))
    layers = random_layers(np.random.default_rng(0), 6, width, depth, 3, last="softplus")

    class Brdf(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.mlp = torch_mlp(layers)

        def forward(self, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
            return self.mlp(torch.cat([wi, wo], dim=1))

    tmp = Path(tempfile.mkdtemp(prefix="bench-onnx-fused-"))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        onnx_path = brdf_onnx(Brdf(), tmp / "mlp.onnx")
    json_path = tmp / "mlp.json"
    json_path.write_text(
        json.dumps(
            {
                "format": "matforge.mlp-brdf/1",
                "inputs": ["wi", "wo"],
                "layers": [
                    {
                        "weight": ly.weight.tolist(),
                        "bias": ly.bias.tolist(),
                        "activation": ly.activation,
                    }
                    for ly in layers
                ],  # fmt: skip
                "output": {"combine": "network", "activation": "identity"},
            }
        )
    )

    res = args.resolution
    passes = plan_passes(res, res, args.spp, PATHS_PER_PASS)
    seeds = list(range(len(passes)))
    setup = SceneSetup(resolution=(res, res), spp=passes[0], max_depth=3)
    register_external_mlp_bsdf(mi)

    def scene_of(bsdf: Any) -> Any:
        return mi.load_dict(build_scene("sphere_env", mi, bsdf, setup))

    scenes = {
        "json MLP, drjit-fused": scene_of({"type": EXTERNAL_MLP_NAME, "filename": str(json_path)}),
        "ONNX MLP, drjit-fused": scene_of(
            external_onnx_plugin(onnx_path, {"kind": "brdf"}, None, mi)
        ),
    }
    runtimes = {k: type(s.shapes()[0].bsdf()).__name__ for k, s in scenes.items()}
    if not args.skip_onnxruntime:
        forced = {"kind": "brdf", "runtime": "onnxruntime"}
        scenes["ONNX MLP, onnxruntime"] = scene_of(
            external_onnx_plugin(onnx_path, forced, None, mi)
        )
        runtimes["ONNX MLP, onnxruntime"] = "OnnxBrdf"

    def render(label: str) -> np.ndarray:
        with wavefront_scope():
            return np.asarray(render_passes(mi, scenes[label], passes, seeds))

    load_before = os.getloadavg()
    images = {k: render(k) for k in scenes}  # warm-up: compilation
    a, b = images["json MLP, drjit-fused"], images["ONNX MLP, drjit-fused"]
    np.testing.assert_allclose(b, a, rtol=1e-4, atol=1e-5)
    times: dict[str, list[float]] = {k: [] for k in scenes}
    for _ in range(args.repeats):
        for label in scenes:
            t = time.perf_counter()
            render(label)
            times[label].append(time.perf_counter() - t)
    load_after = os.getloadavg()

    base = statistics.median(times["json MLP, drjit-fused"])
    paths = res * res * args.spp
    print(f"machine: {_cpu_model()}, {os.cpu_count()} cpus, {args.threads} Dr.Jit threads, "
          f"{mi.variant()}; load average before {load_before[0]:.2f}, after "
          f"{load_after[0]:.2f}")  # fmt: skip
    print("| render sphere_env | model | BSDF | median s | min-max s | Mpaths/s | / json |")
    for label, ts in times.items():
        med = statistics.median(ts)
        print(
            f"| {res}x{res} {args.spp} spp | {label} | {runtimes[label]} | {med:.3f} "
            f"| {min(ts):.3f}-{max(ts):.3f} | {paths / med / 1e6:.2f} | {med / base:.2f}x |"
        )
    ratio = statistics.median(times["ONNX MLP, drjit-fused"]) / base
    print(f"ONNX (fused) / JSON = {ratio:.2f}x (goal <= 1.5x), n = {args.repeats} each")
    print(
        f"command: nice -n 10 .venv/bin/python benchmarks/bench_onnx_fused.py --size {args.size} "
        f"--resolution {res} --spp {args.spp} --repeats {args.repeats} --threads {args.threads}"
        + (" --skip-onnxruntime" if args.skip_onnxruntime else "")
    )


if __name__ == "__main__":
    main()
