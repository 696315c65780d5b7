"""Fused Dr.Jit kernel against torch eager: ns per evaluation, all rows in one run.

Writes ``speed.json`` (:func:`models.speed.speed_report`) and prints one table row per
measurement: the bare MLP of the hybrid model (10 inputs, 6 outputs) at the paper's Table 4
sizes, and the whole BRDF (analytic, hybrid, neural) of one material, baked into the kernel,
against the torch model's forward; plus the trained model's own size when ``--model`` is
given. 2 threads for both back ends, 2^20 cosine-weighted pairs, median of ``--repeats``
runs after a warm-up; kernel compile time is reported separately (``compile_s``).

Then a breakdown of the hybrid model at ``--breakdown`` (default 32x3, fresh weights, one
material baked): its MLP alone (the 6 direction inputs live, the latent folded into the
first bias), the MLP with the output heads (exp, sigmoid), the analytic part alone, and the
whole BRDF; each in the current formulation of :mod:`models.fused_mlp` and, for the A/B in
the same run, the formulation before it (``--no-legacy`` drops those rows). Columns: FLOP
per evaluation (2 per multiply-add of the dense layers), kernel wall ns per evaluation,
CPU ns per evaluation on ``--threads`` dedicated cores (process CPU time / threads, frozen
kernels replayed: see :func:`models.speed.time_cpu`; on this shared machine the wall time
grows with the load average, the CPU time does not), the GFLOP/s per core that gives, and
its fraction of the FP32 FMA peak per core measured by ``benchmarks/fma_peak.c`` in the
same run (built with ``cc -O2 -march=native`` when a C compiler is found).

Run: ``.venv/bin/python benchmarks/bench_fused_mlp.py [--model model.json --material NAME]
[--repeats 7] [--batch 1048576] [--out speed.json] [--breakdown 32x3] [--no-table]``
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from materials.backend import load_mitsuba  # noqa: E402
from models.speed import (  # noqa: E402
    BATCH,
    REPEATS,
    cosine_pairs,
    mlp_flops,
    speed_report,
    time_cpu,
)

HERE = Path(__file__).resolve().parent


def fma_peak(threads: int) -> dict[str, float] | None:
    """Build and run ``fma_peak.c``: ``{"lanes", "gflops_per_core", "wall_gflops"}``, or
    ``None`` without a C compiler (or if it fails)."""
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        return None
    with tempfile.TemporaryDirectory() as tmp:
        exe = Path(tmp) / "fma_peak"
        src = HERE / "fma_peak.c"
        try:
            subprocess.run([cc, "-O2", "-march=native", "-pthread", str(src), "-o", str(exe)],
                           check=True, capture_output=True)  # fmt: skip
            out = subprocess.run([str(exe), str(threads), "30000000"], check=True,
                                 capture_output=True, text=True).stdout.split()  # fmt: skip
        except (OSError, subprocess.CalledProcessError):
            return None
    fields = dict(zip(out[::2], out[1::2], strict=True))
    return {
        "lanes": int(fields["lanes"]),
        "gflops_per_core": float(fields["gflops_per_cpu_second"]),
        "wall_gflops": float(fields["wall_gflops"]),
    }


def legacy_mlp(dr: Any, layers: Any, inputs: list[Any]) -> list[Any]:
    """The fused MLP as traced before this benchmark's breakdown was added (commit 3a4c258):
    four interleaved partial sums per output, each started by a multiply, the bias added
    after them, ReLU as ``dr.maximum(x, 0)``. For the A/B rows only."""
    from models.fused_mlp import _fold_constants, drjit_activation

    first, h = _fold_constants(layers[0], inputs)
    for layer in (first, *layers[1:]):
        act = (
            (lambda x: dr.maximum(x, 0.0))
            if layer.activation == "relu"
            else drjit_activation(dr, layer.activation)
        )
        out = []
        for j, row in enumerate(layer.weight.tolist()):
            chains: list[Any] = [None] * 4
            for i, x in enumerate(h):
                k = i % 4
                chains[k] = x * row[i] if chains[k] is None else dr.fma(x, row[i], chains[k])
            acc = chains[0]
            for c in chains[1:]:
                if c is not None:
                    acc = acc + c
            out.append(act(acc + float(layer.bias[j])))
        h = out
    return h


def breakdown(
    mi: Any, size: str, *, batch: int, repeats: int, threads: int, legacy: bool
) -> list[dict[str, Any]]:
    """The hybrid model's parts at ``size`` (``WxD``), fresh weights: one row per part."""
    import drjit as dr

    from models.brdf.fused import analytic_brdf, bake_material, model_brdf
    from models.fused_mlp import fused_mlp
    from models.speed import _fresh_model

    width, depth = (int(v) for v in size.split("x"))
    _, doc = _fresh_model("hybrid", width, depth, 4, 0)
    m = bake_material(doc, "bench")
    wi_np, wo_np = cosine_pairs(batch, 0)
    wi, wo = mi.Vector3f(*wi_np.T), mi.Vector3f(*wo_np.T)
    dr.eval(wi, wo)

    def mlp_of(kind: str) -> Callable[[Any, Any], list[Any]]:
        def run(wi: Any, wo: Any) -> list[Any]:
            inputs = [wi.x, wi.y, wi.z, wo.x, wo.y, wo.z, *m.z]
            if kind == "legacy":
                return legacy_mlp(dr, m.layers, inputs)
            return fused_mlp(m.layers, inputs)

        return run

    def heads_of(kind: str) -> Callable[[Any, Any], Any]:
        def run(wi: Any, wo: Any) -> Any:
            out = mlp_of(kind)(wi, wo)
            f_c = mi.Color3f(*(dr.exp(v) for v in out[:3]))
            f_g = mi.Color3f(*(dr.rcp(1.0 + dr.exp(-v)) for v in out[3:6]))
            return f_c, f_g

        return run

    def legacy_hybrid(wi: Any, wo: Any) -> Any:  # models.brdf.fused.model_brdf, legacy MLP
        f_c, f_g = heads_of("legacy")(wi, wo)
        return f_c + f_g * analytic_brdf(mi, m, wi, wo)

    flops = mlp_flops(m.layers, 6)
    parts: list[tuple[str, str, Callable[[Any, Any], Any], int]] = []
    for kind in ("legacy", "current") if legacy else ("current",):
        parts += [
            (f"MLP only ({width}x{depth}, z folded)", kind, mlp_of(kind), flops),
            ("MLP + heads (exp, sigmoid)", kind, heads_of(kind), flops),
        ]

    def analytic(wi: Any, wo: Any) -> Any:
        return analytic_brdf(mi, m, wi, wo)

    def hybrid(wi: Any, wo: Any) -> Any:
        return model_brdf(mi, m, wi, wo)

    parts.append(("analytic part (GGX + Lambert)", "current", analytic, 0))
    if legacy:
        parts.append(("hybrid BRDF (whole)", "legacy", legacy_hybrid, flops))
    parts.append(("hybrid BRDF (whole)", "current", hybrid, flops))
    rows = []
    for part, kind, fn, fl in parts:
        t = time_cpu(fn, [wi, wo], repeats)
        cpu_ns = t["cpu_s"] / threads / batch * 1e9
        rows.append(
            {
                "part": part,
                "formulation": kind,
                "flops": fl,
                "kernel_ns": round(t["kernel_s"] / batch * 1e9, 2),
                "cpu_ns": round(cpu_ns, 2),
                "gflops_per_core": round(fl / (cpu_ns * threads), 1) if fl else None,
            }
        )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", type=Path, help="a trained model.json (adds its size)")
    parser.add_argument("--material", help="the material of --model (default: its first)")
    parser.add_argument("--repeats", type=int, default=REPEATS)
    parser.add_argument("--batch", type=int, default=BATCH)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--out", type=Path, default=Path("speed.json"))
    parser.add_argument("--breakdown", default="32x3", help="hybrid size of the breakdown")
    parser.add_argument("--no-legacy", action="store_true", help="no before/after rows")
    parser.add_argument("--no-table", action="store_true", help="breakdown only")
    args = parser.parse_args()

    mi = load_mitsuba()
    if not mi.variant().startswith("llvm_"):
        sys.exit(f"needs Mitsuba's LLVM variant, got {mi.variant()}")
    if not args.no_table:
        table(mi, args)
    print_breakdown(mi, args)


def print_breakdown(mi: Any, args: argparse.Namespace) -> None:
    import os

    import drjit as dr

    old = dr.thread_count()
    dr.set_thread_count(args.threads)
    try:
        load0 = os.getloadavg()
        peak = fma_peak(args.threads)
        rows = breakdown(mi, args.breakdown, batch=args.batch, repeats=args.repeats,
                         threads=args.threads, legacy=not args.no_legacy)  # fmt: skip
        load1 = os.getloadavg()
    finally:
        dr.set_thread_count(old)
    per_core = peak["gflops_per_core"] if peak else None
    print(
        f"\n| part | formulation | FLOP/eval | kernel wall ns/eval | CPU ns/eval on "
        f"{args.threads} cores | GFLOP/s per core | fraction of FMA peak |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for r in rows:
        g = r["gflops_per_core"]
        frac = f"{g / per_core:.0%}" if g and per_core else "-"
        print(
            f"| {r['part']} | {r['formulation']} | {r['flops'] or '-'} | {r['kernel_ns']:.1f} "
            f"| {r['cpu_ns']:.2f} | {g if g else '-'} | {frac} |"
        )
    if peak:
        flops = max(r["flops"] for r in rows)
        best = 2 * flops / (args.threads * per_core)
        print(
            f"\nFP32 FMA peak (benchmarks/fma_peak.c, {peak['lanes']} lanes, {args.threads} "
            f"threads): {per_core:.1f} GFLOP/s per core (CPU time), {peak['wall_gflops']:.1f} "
            f"GFLOP/s wall; at that peak a {flops}-FLOP evaluation takes "
            f"{flops / (args.threads * per_core):.2f} ns on {args.threads} cores (half the "
            f"peak: {best:.2f} ns)"
        )
    else:
        print("\nFP32 FMA peak: not measured (no C compiler)")
    print(
        f"load average {' '.join(f'{v:.2f}' for v in load0)} -> "
        f"{' '.join(f'{v:.2f}' for v in load1)}; batch {args.batch}, median of {args.repeats}"
    )


def table(mi: Any, args: argparse.Namespace) -> None:
    doc = json.loads(args.model.read_text()) if args.model else None
    report = speed_report(
        mi,
        doc,
        args.material,
        batch=args.batch,
        repeats=args.repeats,
        threads=args.threads,
    )
    args.out.write_text(json.dumps(report, indent=2) + "\n")

    env = report["environment"]
    print(
        "| model | size | fused ns/eval | fused kernel ns/eval | fused CPU ns/eval "
        "| GFLOP/s per core | torch eager ns/eval | speedup | compile s | bytes/network "
        "| bytes/material |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for r in report["rows"]:
        label = r["model"] + (" (trained)" if r.get("trained") else "")
        g = r["gflops_per_core"]
        print(
            f"| {label} | {r['size']} | {r['fused_ns']:.1f} | {r['fused_kernel_ns']:.1f} "
            f"| {r['fused_cpu_ns']:.1f} | {'-' if g is None else f'{g:.1f}'} "
            f"| {r['torch_ns']:.1f} | {r['speedup']:.1f}x | {r['compile_s']:.2f} "
            f"| {r.get('bytes_per_network', 0)} | {r.get('bytes_per_material', '-')} |"
        )
    print(
        f"\n{env['processor']}, {env['threads']} threads, load average "
        f"{' '.join(map(str, env['load_average']))}; Dr.Jit {env['drjit']}, "
        f"torch {env['torch']}; batch {report['batch']}, median of {report['repeats']}"
    )
    cmd = "benchmarks/bench_fused_mlp.py"
    if args.model:
        cmd += f" --model {args.model}" + (f" --material {args.material}" if args.material else "")
    print(f"wrote {args.out}\nreproduce: .venv/bin/python {cmd} --repeats {args.repeats}")


if __name__ == "__main__":
    main()
