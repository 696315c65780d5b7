"""Where Eq. 6 (SMAPE, eps 0) pays its maximum: exact zeros of a table against a model's value.

For every finished ``train.brdf`` job in ``--data-dir`` (e.g. one of
``bench_train_brdf.py --data-dir D``) and every material whose name contains one of
``--materials``: at the scoring pairs of ``metrics.json`` (2^18, ``PAIRS_SEED``, pairs
without table data left out) the fraction of pairs where the table is exactly 0, the
table's mean, the model's median value at those pairs (1/sr, mean over RGB), Eq. 6, and
:func:`evaluators.metrics.brdf.smape_floor` at floors of 1 % (the default), 10 % and 100 %
of the table's mean.

    .venv/bin/python tools/diag_brdf_zeros.py --data-dir D --materials TiC Ta
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from evaluators.metrics.brdf import (  # noqa: E402
    PAIRS_SEED,
    TableSampler,
    direction_pairs,
    sample_brdf,
    smape,
    smape_floor,
)
from models.brdf.portable import load_checkpoint  # noqa: E402
from models.brdf.report import model_values  # noqa: E402
from storage.formats.merl import merl_from_bytes  # noqa: E402
from tools.store import open_data_dir, succeeded  # noqa: E402

FRACTIONS = (0.01, 0.1, 1.0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data-dir", type=Path, required=True)
    ap.add_argument("--materials", nargs="+", required=True, help="substrings of table names")
    ap.add_argument("--pairs", type=int, default=1 << 18)
    args = ap.parse_args()
    queue, store = open_data_dir(args.data_dir)
    arts: dict[str, dict[str, str]] = {}
    kinds: dict[str, tuple[str, dict]] = {}
    for job in succeeded(queue):
        arts[job.id] = {a.name: a.digest for a in job.artifacts}
        kinds[job.id] = (job.kind, job.spec)
    tables = {
        name.removesuffix(".binary"): digest
        for jid, (kind, _) in kinds.items()
        if kind == "generate.merl"
        for name, digest in arts[jid].items()
        if name.endswith(".binary")
    }
    wi_all, wo_all = direction_pairs(args.pairs, seed=PAIRS_SEED, distribution="cosine")
    floors = " | ".join(f"floor {f:g}" for f in FRACTIONS)
    print(
        f"| model | material | zero pairs | table mean | model median at zeros | Eq. 6 | {floors} |"
    )
    print("| --- " * (6 + len(FRACTIONS)) + "|")
    for jid, (kind, spec) in kinds.items():
        if kind != "train.brdf":
            continue
        model, names, _ = load_checkpoint(store.read(arts[jid]["model.pt"]))
        label = spec["params"].get("model", "?")
        for i, name in enumerate(names):
            if not any(m in name for m in args.materials) or name not in tables:
                continue
            ref = sample_brdf(
                TableSampler(merl_from_bytes(store.read(tables[name]))), wi_all, wo_all
            )
            keep = ~np.any(ref < 0, axis=1)
            ref = ref[keep]
            f, _ = model_values(model, i, wi_all[keep], wo_all[keep])
            zero = np.all(ref == 0, axis=1)
            median = float(np.median(f[zero].mean(axis=1))) if zero.any() else float("nan")
            fl = " | ".join(f"{smape_floor(ref, f, fraction=x):.4f}" for x in FRACTIONS)
            print(f"| {label} | {name} | {zero.mean():.1%} | {ref.mean():.4f} | {median:.4f} "
                  f"| {smape(ref, f):.4f} | {fl} |", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
