"""BTF models per texel (Xu et al., Sec. 4.1 and 5): the coarse-to-fine student against the
25-wide NeuMIP through the same fused Dr.Jit path, and both against torch eager.

One texture-space shading pass (:meth:`models.btf.fused.FusedBtf.shade_texture`) over a
``--resolution``^2 texture (the paper's 400^2 by default) with per-texel directions from a
point light and a camera over the patch (the student reads its directions at each 2 x 2
block). Each row: median wall time of ``--repeats`` passes after a warm-up (kernel
compilation excluded and reported separately), in ns per texel; kernel time from Dr.Jit's
kernel history; torch eager on the same texels (``torch.inference_mode``, float32, the
student amortised the same way: coarse MLP per block, fine per texel). Weights are random
(speed does not depend on them). The issue's goal: the student at least 5x faster per texel
than the 25-wide NeuMIP through the same fused path.

Run: ``.venv/bin/python benchmarks/bench_btf_models.py [--resolution 400] [--repeats 7]``
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import torch  # noqa: E402

from materials.backend import load_mitsuba  # noqa: E402
from materials.btf.lafortune import PARAMS_PER_TEXEL, initial_params  # noqa: E402
from models.btf.fused import FusedBtf  # noqa: E402
from models.btf.networks import Architecture, build_network, texel_grid  # noqa: E402
from models.btf.portable import (  # noqa: E402
    model_document,
    network_layers,
    network_textures,
    read_model,
)
from models.speed import time_fused, time_torch  # noqa: E402


def directions(res: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-texel unit vectors to a point light and a camera above the unit patch."""
    jj, ii = np.meshgrid(np.arange(res), np.arange(res), indexing="ij")
    p = np.stack([(ii + 0.5) / res - 0.5, (jj + 0.5) / res - 0.5, np.zeros((res, res))], -1)
    light, cam = np.array([0.6, -0.4, 1.2]), np.array([-0.8, 0.9, 1.5])
    wi = light - p
    wo = cam - p
    wi /= np.linalg.norm(wi, axis=-1, keepdims=True)
    wo /= np.linalg.norm(wo, axis=-1, keepdims=True)
    return wi.reshape(-1, 3).astype(np.float32), wo.reshape(-1, 3).astype(np.float32)


def torch_pass(
    net: torch.nn.Module, model: str, res: int, wi: torch.Tensor, wo: torch.Tensor
) -> Callable[[], None]:
    """One texture-space pass in torch eager, amortised as the fused one."""
    grid = texel_grid(res, res)

    def run() -> None:
        if model == "c2f":
            blocks_i = wi.reshape(res, res, 3)[::2, ::2].reshape(-1, 3)
            blocks_o = wo.reshape(res, res, 3)[::2, ::2].reshape(-1, 3)
            zc, _ = net.coarse(texel_grid(res // 2, res // 2), blocks_i, blocks_o)
            jj, ii = torch.meshgrid(torch.arange(res), torch.arange(res), indexing="ij")
            net.fine(zc[((jj // 2) * (res // 2) + ii // 2).reshape(-1)], grid)
        else:
            net(grid, wi, wo)

    return run


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--resolution", type=int, default=400)
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args()
    res = args.resolution
    mi = load_mitsuba()
    torch.set_num_threads(os.cpu_count() or 1)
    cpu = platform.processor() or platform.machine()
    print(
        f"machine: {cpu}, {os.cpu_count()} cores; Mitsuba {mi.variant()}; torch "
        f"{torch.__version__} ({torch.get_num_threads()} threads); {res}x{res} texels"
    )
    wi, wo = directions(res)
    vec = lambda a: mi.Vector3f(*(mi.Float(a[:, k]) for k in range(3)))  # noqa: E731
    wi_v, wo_v = vec(wi), vec(wo)
    # the student's lanes are 2 x 2 blocks, its directions those of the block centres
    wi_c, wo_c = directions(res // 2)
    wi_b, wo_b = vec(wi_c), vec(wo_c)
    n = res * res
    rows = []
    for label, model, width in (("c2f (student, 8)", "c2f", 8), ("neumip (25)", "neumip", 25),
                                ("neumip (8)", "neumip", 8), ("neumip_max (128)", "neumip", 128),
                                ("lafortune (4 lobes)", "lafortune", 0)):  # fmt: skip
        if model == "lafortune":
            rng = np.random.default_rng(0)
            p = initial_params(rng.uniform(0.05, 0.3, (n, 3)))
            tex = {"params": p.reshape(res, res, PARAMS_PER_TEXEL).astype(np.float32)}
            arch = {"model": "lafortune", "width": 0, "resolution": [res, res]}
            port = read_model(model_document("lafortune", arch, {}, tex, {}), tex)
            net = None
        else:
            net = build_network(Architecture(model, width, (res, res)), 0).eval()
            tex = network_textures(net)
            doc = model_document(model, net.arch.as_dict(), network_layers(net), tex, {})
            port = read_model(doc, tex)
        lane_wi, lane_wo = (wi_b, wo_b) if model == "c2f" else (wi_v, wo_v)
        timings = {}
        for half in (False, True):
            fused = FusedBtf(port, mi, half=half)
            timings[half] = time_fused(
                lambda f=fused, a=lane_wi, b=lane_wo: f.shade_texture(a, b),
                repeats=args.repeats,
            )
        t, t16 = timings[False], timings[True]
        torch_ns = float("nan")
        if net is not None:
            run = torch_pass(net, model, res, torch.from_numpy(wi), torch.from_numpy(wo))
            torch_ns = time_torch(run, repeats=args.repeats) / n * 1e9
        rows.append((label, t["wall_s"] / n * 1e9, t["kernel_s"] / n * 1e9, t["compile_s"],
                     t16["wall_s"] / n * 1e9, t16["kernel_s"] / n * 1e9, torch_ns,
                     port.doc["storage"]["total_bytes"]))  # fmt: skip
    base = next(r for r in rows if r[0].startswith("neumip (25)"))
    print()
    print("| model | fused ns / texel (wall) | kernel ns / texel | compile s | fp16 textures: "
          "wall | fp16: kernel | torch eager ns / texel | fused vs torch | NeuMIP-25 / this: "
          "kernel (fp32, fp16) | storage MB |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|---|")
    for label, ns, kns, comp, ns16, kns16, tns, size in rows:
        print(f"| {label} | {ns:.2f} | {kns:.2f} | {comp:.2f} | {ns16:.2f} | {kns16:.2f} | "
              f"{tns:.1f} | {tns / ns:.1f}x | {base[2] / kns:.2f}x, {base[5] / kns16:.2f}x | "
              f"{size / 1e6:.2f} |")  # fmt: skip


if __name__ == "__main__":
    main()
