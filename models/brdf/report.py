"""Reports of ``train.brdf``: ``metrics.json`` (BRDF-space errors) and ``curves.png``.

Metrics: every material of a trained model is scored as ``score`` scores MERL tables
(:mod:`evaluators.score.brdf`): plain RGB BRDF values at the fixed-seed pairs of
:func:`evaluators.metrics.brdf.direction_pairs` (seed ``PAIRS_SEED``, cosine-weighted, the
same for every job: never the training pairs, which come from the job's own seed), the
reference through :class:`~evaluators.metrics.brdf.TableSampler` (multilinear lookup), pairs
where the table has no data left out, ``smape`` (Eq. 6 of the hybrid-BRDF paper, eps 0),
``smape_floor`` (the same with denominators floored at 1 % of the table's mean per channel,
:func:`~evaluators.metrics.brdf.smape_floor`: Eq. 6 pays its maximum 2 at every pair where
a synthetic table is exactly 0) and ``mae`` (1/sr). Models with an analytic part also get
``smape_analytic``, ``smape_floor_analytic`` and ``mae_analytic``: the same scores of ``f_a``
alone (the figure the paper quotes beside each dataset in Fig. 4). Means are plain means
over materials: overall, per family and per split (``train`` or ``heldout``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import torch

from evaluators.metrics.brdf import (
    DISTRIBUTIONS,
    PAIRS_SEED,
    SMAPE_FLOOR_FRACTION,
    TableSampler,
    brdf_mae,
    direction_pairs,
    sample_brdf,
    smape,
    smape_floor,
)
from evaluators.metrics.figures import figure_png, loss_axes
from jobapi.errors import JobFailed
from models.brdf.data import MaterialTable
from models.brdf.networks import BrdfModel
from models.brdf.train import Curves

#: Rows per torch evaluation chunk.
EVAL_CHUNK = 1 << 16
#: Threads of the table lookups (numpy releases the GIL).
TABLE_THREADS = 2


def model_values(
    model: BrdfModel, index: int, wi: np.ndarray, wo: np.ndarray
) -> tuple[np.ndarray, np.ndarray | None]:
    """``(f, f_a)`` of material ``index`` at ``(N, 3)`` pairs, float64 ``(N, 3)`` arrays
    (``f_a`` is ``None`` for the neural model)."""
    f = np.empty((len(wi), 3))
    f_a = np.empty((len(wi), 3)) if model.arch.model != "neural" else None
    idx = torch.tensor([index])
    dtype = next(model.parameters()).dtype
    with torch.no_grad():
        for start in range(0, len(wi), EVAL_CHUNK):
            rows = slice(start, start + EVAL_CHUNK)
            a = torch.from_numpy(wi[rows]).to(dtype)[None]
            b = torch.from_numpy(wo[rows]).to(dtype)[None]
            out = model(a, b, idx)
            f[rows] = out.f[0].double().numpy()
            if f_a is not None and out.f_a is not None:
                f_a[rows] = out.f_a[0].double().numpy()
    return f, f_a


def _mean(rows: Sequence[dict[str, Any]], key: str) -> float | None:
    vals = [r[key] for r in rows if r.get(key) is not None]
    return float(np.mean(vals)) if vals else None


def _summary(rows: Sequence[dict[str, Any]]) -> dict[str, Any]:
    keys = (
        "smape", "smape_floor", "mae", "smape_analytic", "smape_floor_analytic", "mae_analytic"
    )  # fmt: skip
    return {"count": len(rows), **{k: _mean(rows, k) for k in keys}}


def evaluate(
    model: BrdfModel,
    materials: Sequence[MaterialTable],
    splits: Sequence[str],
    pairs: int,
    *,
    check_cancelled: Callable[[], None] | None = None,
) -> dict[str, Any]:
    """``metrics.json``: per-material scores and their means (see the module docstring;
    its type is :class:`models.brdf.document.TrainBrdfMetrics`).

    ``materials[i]`` is the model's material ``i``; ``splits[i]`` is ``"train"`` or
    ``"heldout"``. Raises :class:`JobFailed` if the model gives non-finite values.
    """
    wi_all, wo_all = direction_pairs(pairs, seed=PAIRS_SEED, distribution="cosine")
    rows: list[dict[str, Any]] = []
    for i, (mat, split) in enumerate(zip(materials, splits, strict=True)):
        if check_cancelled is not None:
            check_cancelled()
        ref = sample_brdf(TableSampler(mat.table), wi_all, wo_all, workers=TABLE_THREADS)
        keep = ~np.any(ref < 0, axis=1)
        if not keep.any():
            raise JobFailed(f"material {mat.name!r}: its table has no data at the scoring pairs")
        wi, wo, ref = wi_all[keep], wo_all[keep], ref[keep]
        f, f_a = model_values(model, i, wi, wo)
        if not (np.all(np.isfinite(f)) and (f_a is None or np.all(np.isfinite(f_a)))):
            raise JobFailed(f"material {mat.name!r}: the trained model gives non-finite values")
        rows.append(
            {
                "name": mat.name,
                "family": mat.family,
                "split": split,
                "pairs": int(keep.sum()),
                "smape": smape(ref, f),
                "smape_floor": smape_floor(ref, f),
                "mae": brdf_mae(ref, f),
                "smape_analytic": smape(ref, f_a) if f_a is not None else None,
                "smape_floor_analytic": smape_floor(ref, f_a) if f_a is not None else None,
                "mae_analytic": brdf_mae(ref, f_a) if f_a is not None else None,
            }
        )
    families = sorted({r["family"] for r in rows})
    return {
        "materials": rows,
        "mean": _summary(rows),
        "families": {fam: _summary([r for r in rows if r["family"] == fam]) for fam in families},
        "splits": {
            s: _summary([r for r in rows if r["split"] == s])
            for s in ("train", "heldout")
            if any(r["split"] == s for r in rows)
        },
        "settings": {
            "pairs": pairs,
            "seed": PAIRS_SEED,
            "distribution": DISTRIBUTIONS["cosine"],
            "reference": "MERL table, multilinear lookup (TableSampler); pairs without "
            "data excluded",
            "smape": "Eq. 6, eps 0, mean over R, G, B",
            "smape_floor": f"Eq. 6 with each channel's denominator floored at "
            f"{SMAPE_FLOOR_FRACTION} x the table's mean there (smape_floor): stable where the "
            "table is exactly 0",
            "mae": "mean |f - f^| over pairs and channels, 1/sr",
        },
    }


def curves_png(curves: dict[str, Curves | None], title: str) -> bytes:
    """Loss against step (log scale) of each phase, as deterministic PNG bytes."""

    def draw(fig: Any, ax: Any) -> None:
        for phase, c in curves.items():
            if c is None or not c.step:
                continue
            ax.plot(c.step, c.loss, label=f"{phase}: total")
            if any(v is not None for v in c.loss_analytic) and any(
                v is not None for v in c.loss_hybrid
            ):
                l_a = [float("nan") if v is None else v for v in c.loss_analytic]
                l_t = [float("nan") if v is None else v for v in c.loss_hybrid]
                ax.plot(c.step, l_a, "--", label=f"{phase}: L_a (analytic)")
                ax.plot(c.step, l_t, ":", label=f"{phase}: L_t (hybrid)")
        loss_axes(ax, "loss (Eq. 4, mean per pair)", title)

    return figure_png(draw)
