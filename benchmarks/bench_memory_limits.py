"""Which kernel memory limit the job runtimes tolerate: ``RLIMIT_AS`` or ``RLIMIT_DATA``.

Each row runs, in a fresh child process under one limit, what a worker's jobs do: a
Mitsuba ``llvm_ad_rgb`` render (the Cornell box, 64 x 64, 16 spp), five torch training
steps of a 32x3 MLP on 65,536 rows and an onnxruntime session run on 2^18 rows, with
``--threads`` threads in each runtime (Dr.Jit, torch, onnxruntime's intra-op pool), as a
machine with that many cores would have. It prints the child's address space at its peak
(``VmPeak``, what ``RLIMIT_AS`` counts), its data segment (``VmData``, what ``RLIMIT_DATA``
counts), its peak RSS (``VmHWM``) and whether the work ran. Address space grows with the
threads (each thread's stack, each malloc arena's reservation), memory in use barely does:
the measure behind ``MATFORGE_JOB_MEMORY_MB`` being an ``RLIMIT_DATA``.

Run: ``nice -n 10 .venv/bin/python benchmarks/bench_memory_limits.py [--threads 2 16]``
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys

CHILD = r"""
import json, resource, sys
kind, mib, threads = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
if mib:
    lim = mib << 20
    resource.setrlimit(getattr(resource, kind), (lim, lim))

def status():
    keys = ("VmPeak", "VmData", "VmHWM")
    out = {}
    for line in open("/proc/self/status"):
        k = line.split(":")[0]
        if k in keys:
            out[k] = int(line.split()[1]) // 1024
    return out

try:
    import numpy as np
    import drjit as dr
    import mitsuba as mi
    mi.set_variant("llvm_ad_rgb")
    dr.set_thread_count(threads)
    scene = mi.load_dict(mi.cornell_box())
    np.asarray(mi.render(scene, spp=16))
    import torch
    torch.set_num_threads(threads)
    net = torch.nn.Sequential(
        torch.nn.Linear(10, 32), torch.nn.ReLU(), torch.nn.Linear(32, 32), torch.nn.ReLU(),
        torch.nn.Linear(32, 6))
    opt = torch.optim.AdamW(net.parameters())
    x = torch.randn(65536, 10)
    for _ in range(5):
        loss = net(x).square().mean()
        opt.zero_grad(); loss.backward(); opt.step()
    import onnxruntime as ort
    from onnx import TensorProto, helper
    graph = helper.make_graph(
        [helper.make_node("Relu", ["x"], ["y"])], "g",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, ["N", 3])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, ["N", 3])])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    so = ort.SessionOptions()
    so.intra_op_num_threads = threads
    sess = ort.InferenceSession(model.SerializeToString(), so, providers=["CPUExecutionProvider"])
    sess.run(None, {"x": np.ones((1 << 18, 3), np.float32)})
    print(json.dumps({"ok": True, **status()}))
except BaseException as exc:
    print(json.dumps({"ok": False, "error": f"{type(exc).__name__}: {exc}"[:120], **status()}))
"""


def run(kind: str, mib: int, threads: int) -> dict[str, object]:
    env = {**os.environ, "OMP_NUM_THREADS": str(threads)}
    proc = subprocess.run(
        [sys.executable, "-c", CHILD, kind, str(mib), str(threads)],
        capture_output=True,
        text=True,
        timeout=600,
        env=env,
    )
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("{")]
    if not lines:
        return {"ok": False, "error": f"exit {proc.returncode}", "signal": -proc.returncode}
    return dict(json.loads(lines[-1]))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--threads", type=int, nargs="+", default=[2, 16])
    ap.add_argument(
        "--limits",
        nargs="+",
        default=["none:0", "RLIMIT_AS:1536", "RLIMIT_AS:3072", "RLIMIT_DATA:1024"],
        help="KIND:MiB pairs (none:0 for no limit)",
    )
    a = ap.parse_args()
    print("| threads | limit | ran | VmPeak MiB | VmData MiB | VmHWM MiB | error |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for threads in a.threads:
        for spec in a.limits:
            kind, _, mib = spec.partition(":")
            r = run(kind if kind != "none" else "RLIMIT_DATA", int(mib or 0), threads)
            label = "none" if kind == "none" else f"{kind} {mib} MiB"
            print(
                f"| {threads} | {label} | {'yes' if r.get('ok') else 'no'} | "
                f"{r.get('VmPeak', '-')} | {r.get('VmData', '-')} | {r.get('VmHWM', '-')} | "
                f"{r.get('error', '')} |",
                flush=True,
            )
    load = os.getloadavg()
    print(f"machine: {platform.node()}, {os.cpu_count()} cores, load average {load[0]:.2f}")
    cmd = "nice -n 10 .venv/bin/python benchmarks/bench_memory_limits.py"
    print(f"command: {cmd} --threads {' '.join(map(str, a.threads))} --limits {' '.join(a.limits)}")


if __name__ == "__main__":
    main()
