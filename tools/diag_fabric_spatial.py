"""How much of the weave's spatial pattern a trained ``train.fabric`` network reproduces.

For one training material of a data directory that holds a finished ``generate.fabric`` and
``train.fabric`` job (e.g. the one ``benchmarks/bench_fabric_eval.py`` leaves), the decoder
and the Monte Carlo estimator (:func:`materials.fabric.aggregate.estimate`, 512 Sobol samples,
the independent reference) are evaluated on a grid of footprint centres over the tile, at a
few footprint sizes and direction pairs. Printed per case: the correlation over centres of the
two RGB means (1: the network places bright and dark where the weave does), the same with the
centre's axes swapped (a convention check: it should be lower), the ratio of the means, and
the coefficient of variation (spatial contrast) of each.

Run: ``.venv/bin/python tools/diag_fabric_spatial.py --data-dir /tmp/bench_eval/data``
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402

from materials.fabric.aggregate import FootprintQueries, estimate  # noqa: E402
from materials.fabric.params import FabricParams  # noqa: E402
from models.fabric.fused import decoder_numpy, load_fabric_model  # noqa: E402
from tools.store import latest_artifact, open_data_dir  # noqa: E402

DIRECTIONS = (
    ([0.3, 0.1, 0.95], [-0.2, 0.3, 0.93]),
    ([0.6, -0.2, 0.77], [0.0, 0.0, 1.0]),
)


def _artifact(data: Path, kind: str, name: str) -> bytes:
    """Artifact ``name`` of the newest succeeded ``kind`` job of ``data`` that has one."""
    jobs, store = open_data_dir(data)
    try:
        return latest_artifact(jobs, store, kind, name)
    finally:
        jobs.close()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data-dir", type=Path, required=True)
    ap.add_argument("--pattern", default="twill_3x3")
    ap.add_argument("--grid", type=int, default=24)
    args = ap.parse_args()
    model = load_fabric_model(_artifact(args.data_dir, "train.fabric", "model.json"))
    mats = json.loads(_artifact(args.data_dir, "generate.fabric", "materials.json"))["materials"]
    rec = next(m for m in mats if m["pattern"] == args.pattern and m["name"] in model.latents)
    params = FabricParams(**rec["params"])
    g = args.grid
    c = (np.arange(g) + 0.5) / g
    t, s = np.meshgrid(c, c, indexing="ij")
    n = g * g
    print(f"material {rec['name']}, {n} centres")
    print("size  wi                corr  swapped  mean ratio  cv MC  cv net")
    for size in (0.04, 0.125, 0.3):
        for wi_l, wo_l in DIRECTIONS:
            wi = np.array(wi_l) / np.linalg.norm(wi_l)
            wo = np.array(wo_l) / np.linalg.norm(wo_l)
            wis, wos, sizes = np.tile(wi, (n, 1)), np.tile(wo, (n, 1)), np.full(n, size)
            q = FootprintQueries(np.stack([s.ravel(), t.ravel()], 1), sizes, wis, wos)
            gt = estimate(params, q, samples=512, seed=3).recombine(params).mean(axis=1)

            pred, swapped = (
                (
                    decoder_numpy(model, rec["name"], x, y, sizes, wis, wos).astype(np.float64)
                    @ params.albedos()
                ).mean(axis=1)
                for x, y in ((s.ravel(), t.ravel()), (t.ravel(), s.ravel()))
            )
            corr = float(np.corrcoef(pred, gt)[0, 1])
            corr_sw = float(np.corrcoef(swapped, gt)[0, 1])
            print(
                f"{size:<5} {np.array2string(wi, precision=2):<17} {corr:5.3f}  {corr_sw:6.3f}"
                f"  {pred.mean() / gt.mean():10.3f}  {gt.std() / gt.mean():5.3f}"
                f"  {pred.std() / pred.mean():6.3f}"
            )


if __name__ == "__main__":
    main()
