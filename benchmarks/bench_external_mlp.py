"""An exported user MLP of the hybrid's size against the built-in hybrid's fused kernel.

Issue 23, "Speed, fused path": a ``matforge.mlp-brdf/1`` file evaluates within 1.2x of the
built-in hybrid. The built-in side is one material of a fresh ``train.brdf`` hybrid model
(``--size``, default 32x3, latent 8) baked by :func:`models.brdf.fused.bake_material` and
evaluated by :func:`models.brdf.fused.model_brdf`. The external side is the *same* network
as a ``matforge.mlp-brdf/1`` file (:func:`models.external.convert.brdf_material_as_mlp`:
inputs ``wi, wo``; the material's latent folded into the first bias in float64, as a user
exporting one material would; heads ``exp`` / ``sigmoid``; ``combine: hybrid`` with the
material's ``kd``, ``alpha``, ``eta``), read back and evaluated by
:class:`models.external.fused.FusedMlp`. Both outputs are first checked to agree (rtol 1e-4).

Timing: :func:`models.speed.time_cpu` (frozen kernels replayed; process CPU time per
evaluation on ``--threads`` dedicated cores, which a loaded machine does not inflate) and
the kernel wall time, medians of ``--repeats``, at ``--batch`` cosine-weighted pairs.

Run: ``.venv/bin/python benchmarks/bench_external_mlp.py [--size 32x3] [--batch 1048576]
[--repeats 7] [--threads 2]``
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from materials.backend import load_mitsuba  # noqa: E402
from models.speed import BATCH, REPEATS, cosine_pairs, time_cpu  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--size", default="32x3")
    parser.add_argument("--latent", type=int, default=8)
    parser.add_argument("--batch", type=int, default=BATCH)
    parser.add_argument("--repeats", type=int, default=REPEATS)
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    mi = load_mitsuba()
    if not mi.variant().startswith("llvm_"):
        sys.exit(f"needs Mitsuba's LLVM variant, got {mi.variant()}")
    import drjit as dr

    from models.brdf.fused import bake_material, model_brdf
    from models.external.convert import brdf_material_as_mlp
    from models.external.fused import FusedMlp
    from models.external.mlp import read_mlp
    from models.speed import _fresh_model

    width, depth = (int(v) for v in args.size.split("x"))
    _, doc = _fresh_model("hybrid", width, depth, args.latent, 0)
    baked = bake_material(doc, "bench")
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "hybrid-like.json"
        path.write_text(json.dumps(brdf_material_as_mlp(doc, "bench")), encoding="utf-8")
        size = path.stat().st_size
        ext = FusedMlp(read_mlp(path), mi)
    wi_np, wo_np = cosine_pairs(args.batch)
    wi, wo = mi.Vector3f(*wi_np.T), mi.Vector3f(*wo_np.T)
    dr.eval(wi, wo)
    a = np.asarray(model_brdf(mi, baked, wi, wo))
    b = np.asarray(ext.eval(wi, wo))
    np.testing.assert_allclose(b, a, rtol=1e-4, atol=1e-6)
    old = dr.thread_count()
    dr.set_thread_count(args.threads)
    try:
        load0 = os.getloadavg()[0]
        rows = {}
        for name, fn in (
            ("built-in hybrid", lambda x, y: model_brdf(mi, baked, x, y)),
            ("exported MLP", lambda x, y: ext.eval(x, y)),
        ):
            t = time_cpu(fn, [wi, wo], args.repeats, launches=2)
            rows[name] = (
                t["cpu_s"] / args.threads / args.batch * 1e9,
                t["kernel_s"] / args.batch * 1e9,
            )
        load1 = os.getloadavg()[0]
    finally:
        dr.set_thread_count(old)
    print(f"| model ({args.size}, latent {args.latent}) | CPU ns/eval | kernel wall ns/eval |")
    print("| --- | --- | --- |")
    for name, (cpu, wall) in rows.items():
        print(f"| {name} | {cpu:.2f} | {wall:.2f} |")
    ratio_cpu = rows["exported MLP"][0] / rows["built-in hybrid"][0]
    ratio_wall = rows["exported MLP"][1] / rows["built-in hybrid"][1]
    print(f"ratio exported / built-in: CPU {ratio_cpu:.3f}, wall {ratio_wall:.3f} (goal <= 1.2); "
          f"file {size} bytes; load {load0:.1f} -> {load1:.1f}")  # fmt: skip
    print(f"command: .venv/bin/python benchmarks/bench_external_mlp.py --size {args.size} "
          f"--batch {args.batch} --repeats {args.repeats} --threads {args.threads}")  # fmt: skip


if __name__ == "__main__":
    main()
