"""Mean SMAPE against training steps, from ``bench_train_brdf.py --out`` folders.

Each ``--runs STEPS=DIR`` names a folder of ``metrics.json`` copies written by
``bench_train_brdf.py --out DIR`` with ``--steps STEPS`` (the ``small`` preset's default is
5000). For collection seed ``--collection`` it prints one markdown row per configuration
(mean Eq. 6 and mean ``smape_floor`` at each step count) and writes ``--png``: both SMAPEs
against steps, log x axis, one line per configuration.

    .venv/bin/python benchmarks/plot_brdf_convergence.py --runs 5000=OUT5k 10000=OUT10k \
        --collection 0 --png convergence.png
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from evaluators.metrics.figures import figure_png  # noqa: E402


def load(runs: list[str], collection: int) -> dict[str, dict[int, dict[str, float]]]:
    """``{configuration: {steps: {"smape", "smape_floor"}}}`` (train seed 0 files only)."""
    out: dict[str, dict[int, dict[str, float]]] = {}
    for spec in runs:
        steps_text, folder = spec.split("=", 1)
        for path in sorted(Path(folder).glob(f"c{collection}-*-s0.json")):
            label = path.name[len(f"c{collection}-") : -len("-s0.json")].rstrip("-")
            mean = json.loads(path.read_text())["mean"]
            out.setdefault(label.replace("-", " "), {})[int(steps_text)] = {
                "smape": float(mean["smape"]),
                "smape_floor": float(mean.get("smape_floor", mean["smape"])),
            }
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", nargs="+", required=True, help="STEPS=DIR, one per step count")
    ap.add_argument("--collection", type=int, default=0)
    ap.add_argument("--png", type=Path, required=True)
    args = ap.parse_args()
    data = load(args.runs, args.collection)
    steps = sorted({s for by in data.values() for s in by})
    print("| configuration | " + " | ".join(f"{s} steps: Eq. 6 / floor" for s in steps) + " |")
    print("| --- " * (1 + len(steps)) + "|")
    for label, by in sorted(data.items()):
        cells = [
            f"{by[s]['smape']:.4f} / {by[s]['smape_floor']:.4f}" if s in by else "-" for s in steps
        ]
        print(f"| {label} | " + " | ".join(cells) + " |")

    def draw(fig: Any, ax: Any) -> None:
        for i, (label, by) in enumerate(sorted(data.items())):
            xs = sorted(by)
            color = f"C{i}"
            ax.plot(xs, [by[s]["smape"] for s in xs], "o-", color=color, label=f"{label} Eq. 6")
            ax.plot(xs, [by[s]["smape_floor"] for s in xs], "s--", color=color,
                    label=f"{label} smape_floor")  # fmt: skip
        ax.set_xscale("log")
        ax.set_xlabel("training steps")
        ax.set_ylabel(f"mean SMAPE, small collection seed {args.collection}")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7)

    args.png.write_bytes(figure_png(draw))
    print(f"\nwrote {args.png}")


if __name__ == "__main__":
    main()
