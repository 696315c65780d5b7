"""Result rows of ``evaluate.tss`` (:mod:`jobapi.rows`): per radiance-texture resolution
``R`` and update interval ``N`` (candidate ``"<R>/N=<N>"``), the FLIP and PSNR of
``metrics.json`` (named in image space: ``image.flip_mean``, ``image.flip_max``,
``image.psnr_mean``, ``image.psnr_min``, :mod:`jobapi.metric_names`) and the relative cost
of ``timing.json``, each row with its
``ms_per_frame`` (kernel seconds per frame x 1000) and the model it shaded (dataset)."""

from __future__ import annotations

from collections.abc import Mapping

from evaluators.tss.document import TssMetrics, TssTiming
from jobapi.documents import read_typed
from jobapi.metric_names import qualified
from jobapi.rows import ResultRow, RowSource, base_row, dataset_of, number

#: The metrics of a ``metrics.json`` row.
METRICS = ("flip_mean", "flip_max", "psnr_mean", "psnr_min")
#: Every metric name of its rows (:attr:`jobapi.kinds.Kind.metrics`).
ROW_METRICS = (*(qualified("image", m) for m in METRICS), "relative_cost")


def tss_rows(src: RowSource) -> list[ResultRow]:
    """The rows of a finished ``evaluate.tss`` job (its documents read typed: a job without
    them, or with another shape, has no rows; one without ``timing.json`` has no costs)."""
    doc = read_typed(src.read("metrics.json"), TssMetrics)
    if doc is None:
        return []
    timing = read_typed(src.read("timing.json"), TssTiming)
    costs = timing["rows"] if timing is not None else {}
    dataset = dataset_of(src.job.params, "model")
    external = doc["model"]["external"]
    if dataset is None and external is not None:  # a user's model: its file
        dataset = external.get("model")
    rows: list[ResultRow] = []
    for r in doc["rows"]:
        cost = costs.get(r["label"])
        spf = cost["seconds_per_frame"] if cost is not None else None
        fields = {
            "candidate": r["label"],
            "dataset": dataset,
            "config": {k: r[k] for k in ("resolution", "interval", "pass", "shading_passes")},
            "ms_per_frame": None if spf is None else 1000.0 * spf,
            "runtime": doc["model"]["runtime"],
        }
        values: Mapping[str, object] = r
        rows += [
            base_row(src, qualified("image", k), v, **fields)
            for k in METRICS
            if (v := number(values[k])) is not None
        ]
        if cost is not None and (rel := number(cost["relative_cost"])) is not None:
            rows.append(base_row(src, "relative_cost", rel, **fields))
    return rows
