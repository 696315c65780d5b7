"""``evaluate.tss`` of the same Lambertian BTF in two runtimes: an MLP file
(``matforge.export.btf_mlp``, fused Dr.Jit kernel) and an ONNX graph (onnxruntime).

Both compute ``albedo / pi * cos(theta_i)`` (the tests show their images agree to float32
rounding), so the difference in ``ms_per_frame`` is the runtime's: the fused kernel traced
into each pass against a read-back, an onnxruntime call per light and pass, and a copy back.
Prints one table row per ``(R, N)`` and runtime.

Run: ``.venv/bin/python benchmarks/bench_tss_onnx.py [--frames 8] [--image 64]``
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

ALBEDO = (0.2, 0.5, 0.8)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--image", type=int, default=64)
    args = ap.parse_args()

    import torch

    import matforge.export
    from jobapi.row_sources import StoreSource
    from service import kinds
    from service.settings import Settings
    from service.submission import import_file, run_in_process
    from storage.artifacts import ArtifactStore
    from storage.jobs import JobStore
    from tests.helpers import onnx_models

    kinds.load_builtin()
    folder = Path(tempfile.mkdtemp(prefix="bench-tss-onnx-"))
    conf = Settings.from_env({}).with_(data_dir=folder / "data", pool_processes=1)
    jobs, store = JobStore(conf.db_path), ArtifactStore(conf.store_dir)
    net = torch.nn.Sequential(torch.nn.Linear(8, 4), torch.nn.ReLU(), torch.nn.Linear(4, 3))
    with torch.no_grad():
        for p in net.parameters():
            p.zero_()
        net[2].bias.copy_(torch.tensor(ALBEDO) / math.pi)
    tex = torch.randn(2, 32, 32, generator=torch.Generator().manual_seed(0))
    mlp = matforge.export.btf_mlp(net, folder / "m.json", textures=[tex], foreshortening="apply")
    onnx = onnx_models.save(onnx_models.lambert_model("btf", ALBEDO), folder / "l.onnx")
    from evaluators.tss.rows import tss_rows

    print("| model | runtime | R / N | FLIP mean | ms_per_frame | relative cost |")
    print("| --- | --- | --- | --- | --- | --- |")
    for name, path in (("Lambert MLP", mlp), ("Lambert ONNX", onnx)):
        ref = f"sha256:{import_file(path, jobs, store).digest}"
        spec = {"kind": "evaluate.tss", "seed": 0, "params": {
            "model": {"external": {"model": ref, "kind": "btf"}}, "frames": args.frames,
            "intervals": [0, 4], "image": [args.image, args.image],
            "resolutions": [64]}}  # fmt: skip
        job = run_in_process(spec, conf)
        if job.state != "succeeded":
            raise SystemExit(f"{name}: {job.error}")
        (digest,) = [a.digest for a in job.artifacts if a.name == "timing.json"]
        timing = json.loads(store.read(digest))
        rows = tss_rows(StoreSource(jobs.get(job.id), jobs, store))
        flips = {r.candidate: r.value for r in rows if r.metric == "image.flip_mean"}
        for label, t in timing["rows"].items():
            runtime = next(r.runtime for r in rows if r.candidate == label)
            print(f"| {name} | {runtime} | {label} | {flips[label]:.4f} | "
                  f"{1000 * t['seconds_per_frame']:.3f} | {t['relative_cost']:.3f} |")  # fmt: skip
        screen = timing["passes"]["screen_space"]
        print(f"| {name} | {runtime} | screen space | 0 | {1000 * screen['kernel_s']:.3f} | 1 |")
    print(f"command: .venv/bin/python benchmarks/bench_tss_onnx.py --frames {args.frames} "
          f"--image {args.image}")  # fmt: skip


if __name__ == "__main__":
    main()
