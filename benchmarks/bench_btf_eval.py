"""BTF evaluation (Xu et al. 2025, Sec. 5): Table 1, Fig. 11 and (with the render steps)
Fig. 17 analogues from ``scripts/btf_eval.yaml``.

Runs the recipe step by step in-process (each step through
:func:`service.submission.run_in_process`, ``step:`` refs resolved as ``matforge batch``
does; a step whose spec already ran in ``--data-dir`` is reused, so the recipe resumes), then
prints:

- **Table 1**: per model, the L1 over the whole BTF, over the held-out slices, relative to
  the mean BTF value, and the storage (float32) at our 32^2 texels and scaled to the
  paper's 400^2, beside the paper's figures;
- **Fig. 11**: held-out L1 against training step for the student with and without
  distillation (and the others), written to ``--figure``;
- **Fig. 17** (when the recipe has render and score steps): FLIP / PSNR / SSIM of each
  model's render against the path-traced surface and against the table render.

Writes everything as JSON to ``--out``.

Run: ``.venv/bin/python benchmarks/bench_btf_eval.py [--data-dir DIR] [--out btf_eval.json]``
(about 45 minutes on 2 cores; training dominates).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

RECIPE = Path(__file__).resolve().parent.parent / "scripts" / "btf_eval.yaml"
MODELS = ("lafortune", "neumip", "neumip8", "teacher", "c2f", "c2f_distill")
#: The paper's Table 1 (storage at 400^2; L1 range over its seven UBO2014 materials).
PAPER = {
    "lafortune": "35.2 MB; L1 0.011-0.046",
    "neumip": "4.48 MB; L1 0.008-0.028",
    "neumip8": "(Fig. 8: fails to keep the appearance)",
    "teacher": "(the paper's compromised reference)",
    "c2f": "(Fig. 11: converges worse than distilled)",
    "c2f_distill": "6.24 MB; L1 0.008-0.029",
}


def run_recipe(data_dir: Path, recipe: Path = RECIPE) -> dict[str, Any]:
    from service.cli.batch import load_batch
    from service.cli.batch_local import StepFailed, run_steps_in_process
    from service.settings import Settings

    settings = Settings.from_env({}).with_(data_dir=data_dir, pool_processes=2)

    def done(step: Any, job: Any, seconds: float) -> None:
        print(f"  {step.name}: {seconds:.0f} s; {job.message}", file=sys.stderr, flush=True)

    try:
        jobs = run_steps_in_process(load_batch(recipe).steps, settings, on_step=done)
    except StepFailed as exc:
        sys.exit(str(exc))
    return {"settings": settings, "jobs": jobs}


def read_json(settings: Any, job: Any, name: str) -> Any:
    from storage.artifacts import ArtifactStore

    (digest,) = [a.digest for a in job.artifacts if a.name == name]
    return json.loads(ArtifactStore(settings.store_dir).read(digest))


def curves_png(curves: dict[str, Any], path: Path) -> None:
    from evaluators.metrics.figures import figure_png, loss_axes

    def draw(fig: Any, ax: Any) -> None:
        for name, c in curves.items():
            ax.plot(c["step"], c["test_l1"], label=name, lw=2 if name.startswith("c2f") else 1)
        loss_axes(ax, "held-out L1", "BTF models: held-out L1 against step (Fig. 11 analogue)")

    path.write_bytes(figure_png(draw, size=(7, 4)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-dir", type=Path, default=Path("btf-eval-data"))
    parser.add_argument("--out", type=Path, default=Path("btf_eval.json"))
    parser.add_argument("--figure", type=Path, default=Path("btf_eval_curves.png"))
    args = parser.parse_args()
    ran = run_recipe(args.data_dir)
    settings, jobs = ran["settings"], ran["jobs"]
    rows, curves = [], {}
    for name in MODELS:
        m = read_json(settings, jobs[name], "metrics.json")
        rows.append({"step": name, "label": m["label"], "l1": m["l1"],
                     "l1_heldout": m["l1_heldout"], "relative_l1": m["relative_l1"],
                     "bytes": m["storage"]["total_bytes"],
                     "bytes_400": m["storage_at_400"]["total_bytes"],
                     "network_bytes": m["storage"]["network_bytes"],
                     "paper": PAPER[name]})  # fmt: skip
        if name != "lafortune":
            curves[m["label"]] = read_json(settings, jobs[name], "curves.json")
    print("| model | L1 (whole BTF) | held-out L1 | relative L1 | storage (32^2) | "
          "storage at 400^2 | network | paper (Table 1) |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['label']} | {r['l1']:.5f} | {r['l1_heldout']:.5f} | "
              f"{100 * r['relative_l1']:.1f} % | {r['bytes'] / 1e3:.1f} KB | "
              f"{r['bytes_400'] / 1e6:.2f} MB | {r['network_bytes'] / 1e3:.2f} KB | "
              f"{r['paper']} |")  # fmt: skip
    curves_png(curves, args.figure)
    scores = {}
    for step, job in jobs.items():
        if job.kind == "score":
            scores[step] = read_json(settings, job, "metrics.json")["metrics"]
    if scores:
        print()
        print("| comparison | candidate | FLIP | PSNR dB | SSIM |")
        print("|---|---|---|---|---|")
        for step, metrics in scores.items():
            for label, vals in metrics.items():
                print(f"| {step} | {label} | {vals.get('flip', float('nan')):.4f} | "
                      f"{vals.get('psnr', float('nan')):.2f} | "
                      f"{vals.get('ssim', float('nan')):.4f} |")  # fmt: skip
    doc = {
        "rows": rows,
        "scores": scores,
        "data_dir": str(args.data_dir),
        "curves": {k: {"step": v["step"], "test_l1": v["test_l1"]} for k, v in curves.items()},
    }
    args.out.write_text(json.dumps(doc, indent=2) + "\n")
    print(
        f"\nFig. 11 analogue: {args.figure}; command: .venv/bin/python "
        f"benchmarks/bench_btf_eval.py; data in {args.data_dir}"
    )


if __name__ == "__main__":
    main()
