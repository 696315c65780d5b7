"""Trained fabric networks against Monte Carlo per footprint-size bucket, outside the scene.

A dataset drawn for one scene (``generate.fabric`` with ``scene``: every query at that
render's pixel footprints, views and lights) spends nothing on other footprints. This script
measures what that costs: for each ``--run DIR`` (the ``--data-dir`` of a
``benchmarks/bench_fabric_eval.py`` run) it loads the trained ``model.pt`` and compares it
with fresh Monte Carlo (:func:`tools.diag_fabric_network.reference`: drjit backend,
``--samples`` Sobol samples per query) on two query sets:

- ``design``: the Sec. 5.1 design (sizes over [0, 5] tiles, cosine-distributed directions on
  both sides), with the design seed of ``diag_fabric_network.py``, no dataset's;
- ``scene``: ``cloth_plane`` at 256 x 256, 16 tiles per uv, drawn by
  :func:`generators.fabric.scene_queries.scene_queries` with a seed no dataset uses.

Materials: the recipe's seen ``twill_3x3-t00-s00`` (from the run's ``materials.json``) and
the unseen twill 4x4. Per run, material, set and size bucket: the RGB ratio (``sum net /
sum MC``, Eq. 8 albedos; 1 is unbiased) and the relative L1 error of the RGB value.

Run: ``.venv/bin/python tools/diag_fabric_sizes.py --run NAME=DIR ... [--queries 4096]
[--samples 1024] [--out sizes.json]``
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402

#: Seed of the ``scene`` query set (no dataset uses it).
SCENE_SEED = 0x5CE7E


def _job_artifact(data: Path, kind: str, name: str) -> bytes:
    """Artifact ``name`` of the one succeeded ``kind`` job of the data directory ``data``."""
    from tools.store import open_data_dir, succeeded

    jobs, store = open_data_dir(data)
    try:
        (job,) = succeeded(jobs, kind)
        (digest,) = [a.digest for a in job.artifacts if a.name == name]
    finally:
        jobs.close()
    return store.read(digest)


def scene_set(n: int) -> np.ndarray:
    """``(n, 9)`` cx, cy, size, wi, wo of ``cloth_plane``'s queries (module docstring)."""
    from generators.fabric.params import FabricScene
    from generators.fabric.scene_queries import scene_queries

    design = FabricScene(name="cloth_plane").design()
    q = scene_queries(design, SCENE_SEED, 0, n)
    return np.concatenate([q.centre, q.size[:, None], q.wi, q.wo], axis=1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--run", action="append", required=True, metavar="NAME=DIR")
    ap.add_argument("--queries", type=int, default=4096)
    ap.add_argument("--samples", type=int, default=1024)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()

    from evaluators.render.sources.fabric import FabricSpec
    from models.fabric.fused import encode_material, load_fabric_model, material_maps
    from models.fabric.networks import components_numpy
    from models.fabric.portable import load_checkpoint
    from models.fabric.report import decode_raw
    from tools.diag_fabric_network import UNSEEN, query_sets, reference, stats

    runs = dict(item.split("=", 1) for item in args.run)
    first = Path(next(iter(runs.values())))
    mats = json.loads(_job_artifact(first, "generate.fabric", "materials.json"))
    seen = next(m for m in mats["materials"] if m["name"] == "twill_3x3-t00-s00")

    def to_params(rec: dict[str, Any]) -> Any:
        return FabricSpec.model_validate(rec, strict=False).to_params()

    materials = {"seen twill_3x3": to_params(seen["params"]), "unseen twill_4x4": to_params(UNSEEN)}
    sets = {"design": query_sets(args.queries)["design"], "scene": scene_set(args.queries)}
    targets = {
        (m, s): reference(p, q, args.samples) for m, p in materials.items() for s, q in sets.items()
    }
    result: dict[str, Any] = {"load": os.getloadavg()[0], "samples": args.samples, "runs": {}}
    print("| run | material | set | size bucket (tiles) | n | RGB ratio | RGB rel. L1 |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for run, data in runs.items():
        blob = _job_artifact(Path(data), "train.fabric", "model.pt")
        net, _ = load_checkpoint(blob)
        model = load_fabric_model(blob)
        result["runs"][run] = {}
        for mname, params in materials.items():
            normal, orient = material_maps(params, 256)
            z = encode_material(model, params, normal, orient)
            alb = params.albedos()
            for sname, q in sets.items():
                q8 = np.concatenate([q[:, :6], q[:, 6:8]], axis=1).astype(np.float32)
                pred = components_numpy(decode_raw(net, z, q8), q8[:, 5]).astype(np.float64)
                row = stats(pred, targets[(mname, sname)], q, alb)
                result["runs"][run][f"{mname} / {sname}"] = row
                for bucket, r in row.items():
                    print(f"| {run} | {mname} | {sname} | {bucket} | {r['n']} | "
                          f"{r['rgb']:.3f} | {r['rel_l1_rgb']:.3f} |")  # fmt: skip
    print(f"\nload {result['load']:.1f}; `.venv/bin/python tools/diag_fabric_sizes.py "
          + " ".join(f"--run {k}={v}" for k, v in runs.items()) + "`")  # fmt: skip
    if args.out is not None:
        args.out.write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
