"""Fused Dr.Jit kernel against torch eager: ns per evaluation, all rows in one run.

Writes ``speed.json`` (:func:`models.speed.speed_report`) and prints one table row per
measurement: the bare MLP of the hybrid model (10 inputs, 6 outputs) at the paper's Table 4
sizes, and the whole BRDF (analytic, hybrid, neural) of one material, baked into the kernel,
against the torch model's forward; plus the trained model's own size when ``--model`` is
given. 2 threads for both back ends, 2^20 cosine-weighted pairs, median of ``--repeats``
runs after a warm-up; kernel compile time is reported separately (``compile_s``).

Run: ``.venv/bin/python benchmarks/bench_fused_mlp.py [--model model.json --material NAME]
[--repeats 7] [--batch 1048576] [--out speed.json]``
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from materials.backend import load_mitsuba  # noqa: E402
from models.speed import BATCH, REPEATS, speed_report  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", type=Path, help="a trained model.json (adds its size)")
    parser.add_argument("--material", help="the material of --model (default: its first)")
    parser.add_argument("--repeats", type=int, default=REPEATS)
    parser.add_argument("--batch", type=int, default=BATCH)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--out", type=Path, default=Path("speed.json"))
    args = parser.parse_args()

    mi = load_mitsuba()
    if not mi.variant().startswith("llvm_"):
        sys.exit(f"needs Mitsuba's LLVM variant, got {mi.variant()}")
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
        "| model | size | fused ns/eval | fused kernel ns/eval | torch eager ns/eval "
        "| speedup | compile s | bytes/network | bytes/material |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for r in report["rows"]:
        label = r["model"] + (" (trained)" if r.get("trained") else "")
        print(
            f"| {label} | {r['size']} | {r['fused_ns']:.1f} | {r['fused_kernel_ns']:.1f} "
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
