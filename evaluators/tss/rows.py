"""Result rows of ``evaluate.tss`` (:mod:`jobapi.rows`): per radiance-texture resolution
``R`` and update interval ``N`` (candidate ``"<R>/N=<N>"``), the FLIP and PSNR of
``metrics.json`` and the relative cost of ``timing.json``, each row with its
``ms_per_frame`` (kernel seconds per frame x 1000) and the model it shaded (dataset)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from jobapi.rows import ResultRow, RowSource, base_row, dataset_of, number

#: The metrics of a ``metrics.json`` row.
METRICS = ("flip_mean", "flip_max", "psnr_mean", "psnr_min")


def tss_rows(src: RowSource) -> list[ResultRow]:
    """The rows of a finished ``evaluate.tss`` job."""
    doc = src.read("metrics.json")
    if not isinstance(doc, Mapping):
        return []
    timing = src.read("timing.json")
    costs: Mapping[str, Any] = (
        (timing or {}).get("rows") or {} if isinstance(timing, Mapping) else {}
    )
    dataset = dataset_of(src.job.params, "model")
    given = src.job.params.get("model")
    if dataset is None and isinstance(given, Mapping):  # a user's model: its file
        dataset = (given.get("external") or {}).get("model")
    found_info = doc.get("model")
    info: Mapping[str, Any] = found_info if isinstance(found_info, Mapping) else {}
    rows: list[ResultRow] = []
    for r in doc.get("rows") or []:
        if not isinstance(r, Mapping):
            continue
        label = str(r.get("label"))
        found = costs.get(label)
        cost: Mapping[str, Any] = found if isinstance(found, Mapping) else {}
        spf = number(cost.get("seconds_per_frame"))
        fields = {
            "candidate": label,
            "dataset": dataset,
            "config": {k: r.get(k) for k in ("resolution", "interval", "pass", "shading_passes")},
            "ms_per_frame": None if spf is None else 1000.0 * spf,
            "runtime": str(info.get("runtime") or "drjit-fused"),
        }
        rows += [
            base_row(src, k, v, **fields) for k in METRICS if (v := number(r.get(k))) is not None
        ]
        if (rel := number(cost.get("relative_cost"))) is not None:
            rows.append(base_row(src, "relative_cost", rel, **fields))
    return rows
