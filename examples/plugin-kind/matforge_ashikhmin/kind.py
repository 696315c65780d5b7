"""The ``fit.ashikhmin_shirley`` job kind: an analytic BRDF baseline from another package.

Written against ``jobapi`` exactly as matforge's built-in kinds are, and registered by the
last line of this module; ``pyproject.toml`` names this module in the entry-point group
``matforge.kinds``, so a server started with this package installed loads it.

For every table of a ``generate.merl`` job (``dataset``): fit the isotropic
Ashikhmin-Shirley BRDF (:mod:`matforge_ashikhmin.brdf`) at ``fit_pairs`` cosine-distributed
pairs, then score it against the table at ``train.brdf``'s scoring pairs (the same seed,
distribution and metrics: SMAPE, floored SMAPE, MAE in BRDF space, multilinear table
lookup; pairs without data excluded), so that its rows sit next to the built-in baselines
in ``report.pareto``. One shard per table, through ``ctx.map_shards`` (the worker's process
pool).

Artifacts:

- ``metrics.json``: ``materials`` (``name``, ``family``, ``pairs``, ``smape``,
  ``smape_floor``, ``mae``, ``rs``, ``rd``, ``n``), ``mean``, ``families``, ``settings``
  (the layout of ``train.brdf``'s ``metrics.json``);
- ``model.json``: format ``matforge-ashikhmin.fit/1``, the fitted ``rs``, ``rd``, ``n`` per
  material.
"""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Any

import numpy as np
from pydantic import Field

from evaluators.metrics.brdf import (
    PAIRS_SEED,
    TableSampler,
    brdf_mae,
    direction_pairs,
    sample_brdf,
    smape,
    smape_floor,
)
from jobapi.errors import JobFailed
from jobapi.kinds import Kind, register
from jobapi.metric_names import qualified
from jobapi.params import JobRef, StrictModel, job_id_of
from jobapi.results import ArtifactReader, ResultTable, per_material_table
from jobapi.rows import ResultRow, RowSource, base_row, dataset_of, number
from matforge_ashikhmin.brdf import FLOATS_PER_MATERIAL, fit
from storage.formats.merl import read_merl

if TYPE_CHECKING:
    from jobapi.context import JobContext

NAME = "fit.ashikhmin_shirley"
CANDIDATE = "ashikhmin-shirley"
MODEL_FORMAT = "matforge-ashikhmin.fit/1"
#: Seed of the fitting pairs: not the scoring pairs' seed, so the score is held out.
FIT_SEED = 7
METRICS = ("smape", "smape_floor", "mae")


class FitParams(StrictModel):
    """Parameters of ``fit.ashikhmin_shirley``.

    ==============  ==========  =========  ===============================================
    name            type        default    meaning
    ==============  ==========  =========  ===============================================
    ``dataset``     ``job:ID``  required   a finished ``generate.merl`` job
    ``fit_pairs``   int         65536      cosine-distributed pairs the fit uses
    ``eval_pairs``  int         262144     scoring pairs (``train.brdf``'s seed)
    ``exponents``   int         32         log-spaced exponents tried in [1, 10^4]
    ==============  ==========  =========  ===============================================
    """

    dataset: JobRef = Field(
        description="The generate.merl job whose tables are fitted: 'job:<id>'."
    )
    fit_pairs: int = Field(default=1 << 16, ge=256, le=1 << 20, description="Pairs the fit uses.")
    eval_pairs: int = Field(
        default=1 << 18, ge=256, le=1 << 21, description="Scoring pairs, train.brdf's seed."
    )
    exponents: int = Field(default=32, ge=4, le=256, description="Exponents tried, log-spaced.")


def fit_table(item: dict[str, Any]) -> dict[str, Any]:
    """One shard: fit and score one table (``item``: name, family, path, pair counts)."""
    table = read_merl(item["path"], item["name"])
    sampler = TableSampler(table)
    wi, wo = direction_pairs(item["fit_pairs"], seed=FIT_SEED, distribution="cosine")
    ref = sample_brdf(sampler, wi, wo, workers=1)
    keep = ~np.any(ref < 0, axis=1)
    if keep.sum() < 16:
        raise JobFailed(f"material {item['name']!r}: its table has no data at the fitting pairs")
    material, _ = fit(wi[keep], wo[keep], ref[keep], exponents=item["exponents"])
    wi, wo = direction_pairs(item["eval_pairs"], seed=PAIRS_SEED, distribution="cosine")
    ref = sample_brdf(sampler, wi, wo, workers=1)
    keep = ~np.any(ref < 0, axis=1)
    f = material.eval(wi[keep], wo[keep])
    return {
        "name": item["name"],
        "family": item["family"],
        "pairs": int(keep.sum()),
        "smape": smape(ref[keep], f),
        "smape_floor": smape_floor(ref[keep], f),
        "mae": brdf_mae(ref[keep], f),
        **material.document(),
    }


def _mean(rows: list[dict[str, Any]]) -> dict[str, Any]:
    return {"count": len(rows), **{k: float(np.mean([r[k] for r in rows])) for k in METRICS}}


def run_fit(params: FitParams, ctx: JobContext) -> None:
    """Fit every table of the dataset, one shard each, and write the artifacts."""
    job_id = job_id_of(params.dataset)
    ctx.input_job(job_id, "dataset", kind="generate.merl")
    doc = json.loads(ctx.read_ref(f"job:{job_id}/materials.json"))
    records = [r for r in doc.get("materials", []) if isinstance(r, dict)]
    if not records:
        raise JobFailed(f"dataset: job {job_id} lists no materials")
    items = [
        {
            "name": str(r["name"]),
            "family": str(r.get("family") or "custom"),
            "path": str(ctx.resolve(f"job:{job_id}/{r['artifacts']['table']}")),
            "fit_pairs": params.fit_pairs,
            "eval_pairs": params.eval_pairs,
            "exponents": params.exponents,
        }
        for r in records
    ]
    rows = ctx.map_shards(fit_table, items, label="table", progress_range=(0.0, 0.95))
    families = sorted({r["family"] for r in rows})
    ctx.put_json(
        "metrics.json",
        {
            "materials": rows,
            "mean": _mean(rows),
            "families": {f: _mean([r for r in rows if r["family"] == f]) for f in families},
            "settings": {
                "model": "Ashikhmin-Shirley 2000, isotropic, Schlick Fresnel",
                "fit": "bounded linear least squares in Rs and Rd(1-Rs) per channel, relative "
                "error weights; n shared, log grid then bounded search",
                "fit_pairs": params.fit_pairs,
                "fit_seed": FIT_SEED,
                "pairs": params.eval_pairs,
                "seed": PAIRS_SEED,
                "reference": "MERL table, multilinear lookup (TableSampler); pairs without "
                "data excluded",
            },
        },
    )
    ctx.put_json(
        "model.json",
        {
            "format": MODEL_FORMAT,
            "materials": {r["name"]: {k: r[k] for k in ("rs", "rd", "n")} for r in rows},
        },
    )
    ctx.progress(1.0, f"{len(rows)} tables; mean smape {_mean(rows)['smape']:.4f}")


def summarize(read: ArtifactReader) -> ResultTable | None:
    """``metrics.json``, one row per material then the mean."""
    return per_material_table(read("metrics.json"), (*METRICS, "n"), title="Ashikhmin-Shirley fit")


def rows(src: RowSource) -> list[ResultRow]:
    """One row per material and metric (BRDF space: ``brdf.smape``, ``brdf.smape_floor``,
    ``brdf.mae``), then the means (candidate ``ashikhmin-shirley``,
    the dataset job, 28 bytes per material, the job's wall seconds)."""
    doc = src.read("metrics.json")
    if not isinstance(doc, dict):
        return []
    common: dict[str, Any] = {
        "candidate": CANDIDATE,
        "dataset": dataset_of(src.job.params, "dataset"),
        "config": {"model": CANDIDATE, "fit_pairs": src.job.params.get("fit_pairs")},
        "bytes_per_material": 4.0 * FLOATS_PER_MATERIAL,
        "train_seconds": src.job.run_seconds,
    }
    out: list[ResultRow] = []
    for m in doc.get("materials") or []:
        if isinstance(m, dict):
            fields = {**common, "material": str(m.get("name")), "family": m.get("family")}
            out += [
                base_row(src, qualified("brdf", k), v, **fields)
                for k in METRICS
                if (v := number(m.get(k))) is not None
            ]
    mean = doc.get("mean")
    if isinstance(mean, dict):
        out += [base_row(src, qualified("brdf", k), v, material="mean", **common)
                for k in METRICS if (v := number(mean.get(k))) is not None]  # fmt: skip
    return out


register(
    Kind(
        name=NAME,
        params=FitParams,
        runner=run_fit,
        description="Fit the Ashikhmin-Shirley BRDF to every MERL table of a generate.merl job "
        "and score it in BRDF space (SMAPE, MAE) at train.brdf's pairs [plugin example].",
        artifacts=("metrics.json", "model.json"),
        smoke={"dataset": "step:generate.merl", "fit_pairs": 2048, "eval_pairs": 4096},
        summary=summarize,
        rows=rows,
        metrics=tuple(qualified("brdf", k) for k in METRICS),
    )
)
