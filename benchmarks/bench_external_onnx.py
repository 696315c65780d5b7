"""ONNX materials against the fused Dr.Jit path for the same network: ns per evaluation, and
a render of ``sphere_env`` at 64 spp (issue 23, "Speed").

The network: a BRDF MLP ``(wi, wo) -> rgb`` of the hybrid's size (6 direction inputs,
``--size`` hidden layers, default 32x3, ReLU, softplus out), random He-initialised weights
(:func:`models.fused_mlp.random_layers`). The same :class:`~models.fused_mlp.DenseLayer`
list is (a) traced by :func:`models.fused_mlp.fused_mlp` into Dr.Jit, and (b) built into
torch (:func:`models.fused_mlp.torch_mlp`), exported with
:func:`matforge.export_onnx.brdf_onnx` and run by onnxruntime
(:mod:`models.external.onnx_model`, ``--threads`` intra-op threads).

Rows:

- ``eval``: ns per evaluation on ``--batch`` cosine-weighted pairs, median of
  ``--repeats`` after a warm-up, for the fused kernel and for onnxruntime;
- ``render``: ``sphere_env`` at ``--resolution`` and 64 spp (``render_passes``, as the
  ``render`` kind), median of ``--repeats`` after a warm-up, for (1) the fused MLP in a
  cosine-sampled Python BSDF, traced into Mitsuba's symbolic path loop; (2) the same BSDF
  in Dr.Jit's evaluated (wavefront) mode, the mode ONNX needs: the cost of the round trips
  alone; (3) the ``external_onnx`` BSDF, with the seconds spent inside onnxruntime and
  in numpy/Dr.Jit conversions split out (where the time goes).

Run: ``.venv/bin/python benchmarks/bench_external_onnx.py [--size 32x3] [--batch 1048576]
[--resolution 256] [--spp 64] [--repeats 3] [--threads 2]``
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from materials.backend import load_mitsuba  # noqa: E402
from models.fused_mlp import fused_mlp, random_layers, torch_mlp  # noqa: E402
from models.speed import cosine_pairs  # noqa: E402


def _median_time(fn: Any, repeats: int) -> float:
    fn()  # warm-up: kernel compilation, session start
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def fused_bsdf_class(mi: Any, layers: Any) -> type:
    """A cosine-sampled Python BSDF whose BRDF is the fused MLP (the fused path)."""
    import drjit as dr

    from evaluators.render.bsdfs.common import MixtureSampling, mixture_reflector_base

    flags = mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.FrontSide

    class FusedMlpBsdf(mixture_reflector_base(mi)):  # type: ignore[misc]
        def __init__(self, props: Any) -> None:
            super().__init__(props)
            self.sampling = MixtureSampling(1.0, 0.0)
            self.m_flags = flags
            self.m_components = [flags]

        def brdf(self, ctx: Any, wi: Any, wo: Any, active: Any) -> Any:
            out = fused_mlp(layers, [wi.x, wi.y, wi.z, wo.x, wo.y, wo.z])
            active = active & (wi.z > 0.0) & (wo.z > 0.0)
            return dr.select(active, mi.Color3f(*out), 0.0)

        def enabled(self, ctx: Any, active: Any) -> Any:
            return active & (
                ctx.is_enabled(mi.BSDFFlags.GlossyReflection, 0)
                or ctx.is_enabled(mi.BSDFFlags.DiffuseReflection, 0)
            )

    mi.register_bsdf("bench_fused_mlp", lambda props: FusedMlpBsdf(props))
    return FusedMlpBsdf


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--size", default="32x3")
    ap.add_argument("--batch", type=int, default=1 << 20)
    ap.add_argument("--resolution", type=int, default=256)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()

    mi = load_mitsuba()
    import drjit as dr

    from evaluators.render.bsdfs.external_onnx import external_onnx_plugin, wavefront_scope
    from evaluators.render.kind import PATHS_PER_PASS, plan_passes, render_passes
    from evaluators.render.scenes import SceneSetup, build_scene
    from matforge.export_onnx import brdf_onnx
    from models.external.onnx_model import load_onnx

    dr.set_thread_count(args.threads)
    width, depth = (int(v) for v in args.size.split("x"))
    layers = random_layers(np.random.default_rng(0), 6, width, depth, 3, last="softplus")

    import torch

    class Brdf(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.mlp = torch_mlp(layers)

        def forward(self, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
            return self.mlp(torch.cat([wi, wo], dim=1))

    tmp = Path(tempfile.mkdtemp(prefix="bench-onnx-"))
    path = brdf_onnx(Brdf(), tmp / "mlp.onnx")
    model = load_onnx(path, "brdf", threads=args.threads)

    # -- ns per evaluation ----------------------------------------------------------------
    wi_np, wo_np = cosine_pairs(args.batch, 0)
    wi, wo = mi.Vector3f(*wi_np.T), mi.Vector3f(*wo_np.T)
    dr.eval(wi, wo)

    def fused() -> None:
        out = fused_mlp(layers, [wi.x, wi.y, wi.z, wo.x, wo.y, wo.z])
        dr.eval(*out)
        dr.sync_thread()

    fused_s = _median_time(fused, args.repeats)
    onnx_s = _median_time(lambda: model.eval(wi_np, wo_np), args.repeats)
    ref = np.stack(
        [np.asarray(o) for o in fused_mlp(layers, [mi.Float(c) for c in (*wi_np.T, *wo_np.T)])], 1
    )
    agree = float(np.max(np.abs(model.eval(wi_np[:4096], wo_np[:4096]) - ref[:4096])))
    n = args.batch
    print(f"| eval {args.size} | fused Dr.Jit | {fused_s / n * 1e9:.2f} ns/eval |")
    print(f"| eval {args.size} | onnxruntime | {onnx_s / n * 1e9:.2f} ns/eval |")
    print(f"eval: onnxruntime / fused = {onnx_s / fused_s:.2f}x (max |diff| {agree:.2e})")

    # -- renders ----------------------------------------------------------------------------
    fused_bsdf_class(mi, layers)
    res = args.resolution
    passes = plan_passes(res, res, args.spp, PATHS_PER_PASS)
    seeds = list(range(len(passes)))
    setup = SceneSetup(resolution=(res, res), spp=passes[0], max_depth=3)

    def scene_of(bsdf: Any) -> Any:
        return mi.load_dict(build_scene("sphere_env", mi, bsdf, setup))

    fused_scene = scene_of({"type": "bench_fused_mlp"})
    t_fused = _median_time(lambda: render_passes(mi, fused_scene, passes, seeds), args.repeats)

    def fused_wavefront() -> None:
        with wavefront_scope(force=True):
            render_passes(mi, fused_scene, passes, seeds)

    t_wave = _median_time(fused_wavefront, args.repeats)
    # onnxruntime forced: a recognised MLP graph would otherwise run in the fused kernel
    # (benchmarks/bench_onnx_fused.py measures that path).
    forced = {"kind": "brdf", "runtime": "onnxruntime"}
    onnx_scene = scene_of(external_onnx_plugin(path, forced, None, mi))
    onnx_bsdf = onnx_scene.shapes()[0].bsdf()
    stats = onnx_bsdf.model.stats
    render_passes(mi, onnx_scene, passes, seeds)  # warm-up
    times, inside, rows, calls = [], [], [], []
    for _ in range(args.repeats):
        stats.reset()
        t = time.perf_counter()
        render_passes(mi, onnx_scene, passes, seeds)
        times.append(time.perf_counter() - t)
        inside.append(stats.seconds)
        rows.append(stats.rows)
        calls.append(stats.calls)
    t_onnx = statistics.median(times)
    i = times.index(t_onnx) if t_onnx in times else 0
    paths = res * res * args.spp
    for label, t in (
        ("fused, symbolic loop", t_fused),
        ("fused, wavefront", t_wave),
        ("onnxruntime, wavefront", t_onnx),
    ):
        rate = paths / t / 1e6
        print(
            f"| render sphere_env {res}x{res} {args.spp} spp | {label} | {t:.3f} s "
            f"| {rate:.2f} Mpaths/s |"
        )
    print(
        f"render: onnx speed / fused speed = {t_fused / t_onnx:.2f}x "
        f"(wavefront alone: {t_fused / t_wave:.2f}x); in onnxruntime {inside[i]:.3f} s "
        f"of {t_onnx:.3f} s ({rows[i] / 1e6:.1f} M evaluations in {calls[i]} calls, "
        f"{inside[i] / max(rows[i], 1) * 1e9:.1f} ns each); the rest: the evaluated path "
        f"loop and the host round trips"
    )
    print(
        f"command: .venv/bin/python benchmarks/bench_external_onnx.py --size {args.size} "
        f"--batch {args.batch} --resolution {res} --spp {args.spp} --repeats {args.repeats} "
        f"--threads {args.threads}"
    )


if __name__ == "__main__":
    main()
