"""Result rows of ``train.fabric`` (:mod:`jobapi.rows`): the held-out errors of
``metrics.json``, one row per material (and the mean, ``material`` ``"mean"``) and metric,
each of the ``test`` split (the material's held-out queries, never trained on).

Metrics are the flattened keys of a material's row: ``loss`` (Eq. 11), ``rgb.rel``,
``rgb.mse``, ``C_warp.rel``, ... The per-material mean predictor's errors (``baseline.*``)
are rows of their own candidate, ``"baseline"``, beside the network's, ``"network"``.
The network's rows carry its multiply-adds and bytes read per evaluation
(:func:`models.fabric.counts.fabric_counts`, from ``model.json``).
Then ``rgb.rel`` per footprint-size case (``footprints``), with the case's name as its
``material`` and ``family`` (the tiny footprints are a failure case of issue 13).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from jobapi.documents import read_typed
from jobapi.results import flatten
from jobapi.rows import ResultRow, RowSource, base_row, dataset_of, number
from models.fabric.counts import fabric_counts
from models.fabric.document import TrainFabricMetrics

#: The machine-independent cost columns, the network's only.
COUNT_COLUMNS = ("macs_per_eval", "bytes_per_eval")
#: Keys of a material's row that are counts, not measurements.
NOT_METRICS = frozenset({"queries", "count"})
#: Params of the spec that describe the network, in ``config``.
CONFIG_KEYS = ("preset", "steps", "encoder_width", "decoder_width", "latent_dim", "map_resolution")


def _rows_of(src: RowSource, values: Mapping[str, Any], fields: dict[str, Any]) -> list[ResultRow]:
    rows = []
    for key, raw in flatten(values).items():
        value = number(raw)
        if value is None or key in NOT_METRICS:
            continue
        candidate, metric = (
            ("baseline", key[9:]) if key.startswith("baseline.") else ("network", key)
        )
        own = (
            fields
            if candidate == "network"
            else {k: v for k, v in fields.items() if k not in COUNT_COLUMNS}
        )  # the mean predictor has no decoder
        rows.append(base_row(src, metric, value, candidate=candidate, **own))
    return rows


def train_fabric_rows(src: RowSource) -> list[ResultRow]:
    """The rows of a finished ``train.fabric`` job (see the module docstring; its
    ``metrics.json`` read typed: none for a job without it, or with another shape)."""
    doc = read_typed(src.read("metrics.json"), TrainFabricMetrics)
    if doc is None:
        return []
    params = src.job.params
    common: dict[str, Any] = {
        "split": "test",  # every error is over held-out queries, never trained on
        "dataset": dataset_of(params, "dataset"),
        "config": {k: params[k] for k in CONFIG_KEYS if params.get(k) is not None},
        "train_seconds": src.job.run_seconds,
    }
    model = src.read("model.json")
    if isinstance(model, dict):  # the network's counts (models.fabric.counts)
        common.update({k: v for k, v in fabric_counts(model).items() if v is not None})
    rows: list[ResultRow] = []
    # A material's row and the footprint cases are trees of error measures, typed as objects
    # (models.fabric.document): their names and keys are read as the report writes them.
    for m in doc["materials"]:
        fields = {**common, "material": str(m.get("name")), "family": m.get("pattern")}
        rows += _rows_of(src, {k: v for k, v in m.items() if k not in ("name", "pattern")},
                         fields)  # fmt: skip
    rows += _rows_of(src, doc["mean"], {**common, "material": "mean"})
    for case in doc["footprints"]:
        if not case.get("case"):
            continue
        fields = {**common, "material": str(case["case"]), "family": str(case["case"])}
        for cand, key in (("network", "rgb_rel"), ("baseline", "baseline_rgb_rel")):
            own = (
                fields
                if cand == "network"
                else {k: v for k, v in fields.items() if k not in COUNT_COLUMNS}
            )
            if (value := number(case.get(key))) is not None:
                rows.append(base_row(src, "rgb.rel", value, candidate=cand, **own))
    return rows
