"""Result rows of ``train.btf`` (:mod:`jobapi.rows`): the model's L1 errors of
``metrics.json`` (``l1``, ``l1_train``, ``l1_heldout``, ``relative_l1``), each with its
storage (Table 1 of Xu et al. 2025): bytes per material are the textures', bytes per network
the decoder's; multiply-adds and bytes read per evaluation from ``model.json``
(:func:`models.btf.counts.btf_counts`). Their names say their slices (``l1_train``: the
training slices, ``l1_heldout``: the held-out ones, ``l1`` and ``relative_l1``: every slice),
so their rows have no ``split``. Then ``l1`` and ``relative_l1`` per failure case
(shadowing, specular, rest, and fine_detail: the paper's Fig. 15 failure, the detail within
2 x 2 blocks)."""

from __future__ import annotations

from jobapi.documents import read_typed
from jobapi.rows import ResultRow, RowSource, base_row, dataset_of, number
from models.btf.counts import btf_counts
from models.btf.document import TrainBtfMetrics

#: The metrics of ``metrics.json``.
METRICS = ("l1", "l1_train", "l1_heldout", "relative_l1")
#: The metrics of each failure case (``metrics.json``'s ``cases``,
#: :mod:`models.btf.cases`): rows whose ``material`` and ``family`` are the case's name, so
#: that ``report.pareto`` and ``report.stability`` break the errors down by case.
CASE_METRICS = ("l1", "relative_l1")
#: What renders a train.btf model (the fused ``btf_model`` BSDF and ``evaluate.tss``).
RUNTIME = "drjit-fused"
#: Params of the spec that describe the model, in ``config``.
CONFIG_KEYS = ("model", "preset", "width", "epochs", "distill")


def train_btf_rows(src: RowSource) -> list[ResultRow]:
    """The rows of a finished ``train.btf`` job (its ``metrics.json`` read typed: none for
    a job without it, or with another shape)."""
    doc = read_typed(src.read("metrics.json"), TrainBtfMetrics)
    if doc is None:
        return []
    params = src.job.params
    fields = {
        "candidate": doc["label"],
        "dataset": dataset_of(params, "data"),
        "config": {k: params[k] for k in CONFIG_KEYS if params.get(k) is not None},
        "bytes_per_material": float(doc["storage"]["texture_bytes"]),
        "bytes_per_network": float(doc["storage"]["network_bytes"]),
        "train_seconds": src.job.run_seconds,
        "runtime": RUNTIME,
    }
    model = src.read("model.json")
    if isinstance(model, dict):
        fields.update({k: v for k, v in btf_counts(model).items() if v is not None})
    values = {"l1": doc["l1"], "l1_train": doc["l1_train"], "l1_heldout": doc["l1_heldout"],
              "relative_l1": doc["relative_l1"]}  # fmt: skip
    rows = [base_row(src, k, v, **fields) for k in METRICS if (v := number(values[k])) is not None]
    for case in doc["cases"]:
        errors = {"l1": case["l1"], "relative_l1": case["relative_l1"]}
        for k in CASE_METRICS:
            if (v := number(errors[k])) is not None:
                rows.append(base_row(src, k, v, material=case["case"], family=case["case"],
                                     **fields))  # fmt: skip
    return rows
