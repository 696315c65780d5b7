"""Result rows of ``train.brdf`` (:mod:`jobapi.rows`).

One row per material and metric of ``metrics.json`` (``smape``, ``smape_floor``, ``mae``
and, for models with an analytic part, ``smape_analytic``, ``smape_floor_analytic`` and
``mae_analytic``), named in BRDF space (``brdf.smape``, ...: :mod:`jobapi.metric_names`),
each with its material's ``split``: ``train`` for a material the network was fitted to,
``test`` for a held-out one (``holdout_families``: ``metrics.json``'s ``heldout``). Then the
same metrics of the mean over each split's materials (``material`` ``"mean"``, its
``split``; without held-out materials, the mean over all of them, ``train``), and the
trained size's speed
(``fused_kernel_ns``, ``fused_ns``, ``torch_ns`` of the speed document: the manifest's
``timings.measured.speed``, or the ``speed.json`` artifact of a job run before timings moved
to the manifest). Every row carries the
configuration (``candidate`` ``"hybrid 32x3"`` as :class:`models.brdf.study.Run` names it),
the dataset (the ``generate.merl`` job) and the costs: ``ns_per_eval`` is the trained
size's ``fused_kernel_ns``, bytes per material 4 x the per-material floats, bytes per
network from the speed document, ``train_seconds`` the job's wall time, ``runtime``
``drjit-fused``, and the counts that do not depend on the machine, ``macs_per_eval`` and
``bytes_per_eval`` (:func:`models.brdf.fused.brdf_counts`, from the architecture).
``config.model_file`` is the job's ``model.json`` ref: ``report.pareto`` and ``select``
re-time the model from it in their own timing pass (the ``ns_per_eval`` here is the
training job's own diagnostic).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from jobapi.documents import read_typed
from jobapi.metric_names import qualified
from jobapi.rows import ResultRow, RowSource, base_row, dataset_of, number
from models.brdf.document import (
    BrdfMaterialScores,
    BrdfScoreMeans,
    TrainBrdfMaterials,
    TrainBrdfMetrics,
)
from models.brdf.fused import brdf_counts

#: The metrics of a material's row in ``metrics.json``.
METRICS = (
    "smape", "smape_floor", "mae", "smape_analytic", "smape_floor_analytic", "mae_analytic"
)  # fmt: skip
#: The split of a result row per ``metrics.json`` split.
SPLITS = {"train": "train", "heldout": "test"}
#: Every metric name of its rows (:attr:`jobapi.kinds.Kind.metrics`).
ROW_METRICS = (*(qualified("brdf", m) for m in METRICS), "fused_kernel_ns", "fused_ns",
               "torch_ns")  # fmt: skip
#: What evaluates a train.brdf model (its ``ns_per_eval`` is the fused kernel's).
RUNTIME = "drjit-fused"
#: The speed metrics of the speed document's trained-size row.
SPEED_METRICS = ("fused_kernel_ns", "fused_ns", "torch_ns")


def config_label(model: str, width: int, depth: int) -> str:
    """``"analytic"`` or ``"<model> <width>x<depth>"``: a configuration's name."""
    return "analytic" if model == "analytic" else f"{model} {width}x{depth}"


def _trained_speed(doc: Any) -> Mapping[str, Any] | None:
    if not isinstance(doc, Mapping):
        return None
    return next((r for r in doc.get("rows") or [] if isinstance(r, Mapping) and r.get("trained")),
                None)  # fmt: skip


def _scores(scores: BrdfMaterialScores | BrdfScoreMeans) -> dict[str, float]:
    """The :data:`METRICS` of a material's scores or of their means that are numbers."""
    values = {"smape": scores["smape"], "smape_floor": scores["smape_floor"],
              "mae": scores["mae"], "smape_analytic": scores["smape_analytic"],
              "smape_floor_analytic": scores["smape_floor_analytic"],
              "mae_analytic": scores["mae_analytic"]}  # fmt: skip
    return {qualified("brdf", k): v for k in METRICS if (v := number(values[k])) is not None}


def train_brdf_rows(src: RowSource) -> list[ResultRow]:
    """The rows of a finished ``train.brdf`` job (see the module docstring; its
    ``metrics.json`` and ``materials.json`` read typed: none for a job without them, or
    with another shape)."""
    metrics = read_typed(src.read("metrics.json"), TrainBrdfMetrics)
    info = read_typed(src.read("materials.json"), TrainBrdfMaterials)
    if metrics is None or info is None:
        return []
    arch = info["architecture"]
    model, width, depth = info["model"], arch["width"], arch["depth"]
    floats = info["per_material_params"]
    params = src.job.params
    config = {
        "model": model,
        "width": width,
        "depth": depth,
        "latent_dim": arch["latent_dim"],
        "per_material_params": floats,
        "preset": params.get("preset"),
        "steps": params.get("steps"),
        # the trained model itself, so that a comparison can time it in its own pass
        "model_file": f"job:{src.job.id}/model.json",
    }
    speed = _trained_speed(src.job.measured.get("speed") or src.read("speed.json"))
    common: dict[str, Any] = {
        "candidate": config_label(model, width, depth),
        "dataset": dataset_of(params, "dataset"),
        "config": config,
        "ns_per_eval": number(speed.get("fused_kernel_ns")) if speed else None,
        "bytes_per_material": 4.0 * floats,
        "bytes_per_network": number(speed.get("bytes_per_network")) if speed else None,
        "train_seconds": src.job.run_seconds,
        "runtime": RUNTIME,
        **brdf_counts(model, width, depth),
    }
    rows: list[ResultRow] = []
    for m in metrics["materials"]:
        fields = {**common, "material": m["name"], "family": m["family"],
                  "split": SPLITS.get(m["split"], m["split"]),
                  "config": {**config, "split": m["split"]}}  # fmt: skip
        rows += [base_row(src, k, v, **fields) for k, v in _scores(m).items()]
    splits = metrics["splits"]
    means = (
        [(SPLITS[s], splits[s]) for s in ("heldout", "train") if s in splits]
        if "heldout" in splits
        else [("train", metrics["mean"])]
    )
    for split, mean in means:
        rows += [base_row(src, k, v, material="mean", split=split, **common)
                 for k, v in _scores(mean).items()]  # fmt: skip
    if speed:
        rows += [base_row(src, k, v, **common)
                 for k in SPEED_METRICS if (v := number(speed.get(k))) is not None]  # fmt: skip
    return rows
