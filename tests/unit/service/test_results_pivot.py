"""The method x metric table (``matforge results --pivot``): means, spreads and best marks
checked against numpy over the same hand-made rows (the reference), and the tie, direction
and fallback rules of :mod:`service.results_pivot`."""

from __future__ import annotations

import numpy as np
import pytest

from service.results_pivot import method_of, pivot, pivot_csv_rows


def _row(candidate: str | None, metric: str, value: float, lib: bool | None, **kw):
    return {"job": "a" * 32, "kind": "score", "candidate": candidate, "metric": metric,
            "value": value, "lower_is_better": lib, **kw}  # fmt: skip


ROWS = [
    _row("hybrid", "smape", 0.10, True, seed=0, ns_per_eval=30.0, bytes_per_network=800.0),
    _row("hybrid", "smape", 0.14, True, seed=1, ns_per_eval=34.0, bytes_per_network=800.0),
    _row("hybrid", "psnr", 31.0, False, seed=0, ns_per_eval=30.0, bytes_per_network=800.0),
    _row("neural", "smape", 0.20, True, seed=0, ns_per_eval=12.0, bytes_per_network=600.0),
    _row("neural", "psnr", 33.0, False, seed=0, ns_per_eval=12.0, bytes_per_network=600.0),
    _row("neural", "mean", 0.5, None),
    _row("lambert", "mean", 0.7, None),
]


def test01_means_spread_and_best_match_numpy() -> None:
    doc = pivot(ROWS)
    assert doc["methods"] == ["hybrid", "neural", "lambert"]
    smape = doc["cells"]["hybrid"]["smape"]
    assert smape["mean"] == pytest.approx(np.mean([0.10, 0.14]))
    assert smape["std"] == pytest.approx(np.std([0.10, 0.14], ddof=1))
    assert smape["n"] == 2 and doc["cells"]["neural"]["smape"]["std"] is None
    assert doc["cells"]["hybrid"]["ns_per_eval"]["median"] == pytest.approx(np.median([30, 34, 30]))
    # lower smape wins, higher psnr wins, every cost is lower-is-better, no best for "mean";
    # ns_per_eval is each job's own timing: shown, not ranked, and the table says why
    assert doc["best"] == {"smape": "hybrid", "psnr": "neural", "bytes_per_network": "neural"}
    assert list(doc["unranked"]) == ["ns_per_eval"] and "one pass" in doc["unranked"]["ns_per_eval"]
    roles = {c["name"]: (c["role"], c["lower_is_better"]) for c in doc["columns"]}
    assert roles["psnr"] == ("metric", False) and roles["ns_per_eval"] == ("cost", True)


def test02_csv_rows_and_fallback_names() -> None:
    header, flat = pivot_csv_rows(pivot(ROWS))
    assert header[:4] == ["method", "smape", "smape.std", "smape.n"] and header[-1] == "best"
    assert flat[0]["best"] == "smape" and flat[1]["best"] == "psnr bytes_per_network"
    assert method_of({"kind": "render", "job": "b" * 32, "candidate": None}) == "render bbbbbbbb"
    assert method_of({"step": "gt", "candidate": ""}) == "gt"
    assert method_of({"material": "gold", "candidate": "x"}, by="material") == "gold"


def test03_one_method_has_no_best_and_nonfinite_values_are_dropped() -> None:
    doc = pivot([_row("a", "flip", 0.1, True), _row("a", "flip", float("nan"), True)])
    assert doc["best"] == {} and doc["cells"]["a"]["flip"]["n"] == 1


def test04_a_cost_that_is_also_a_metric_keeps_both_columns() -> None:
    rows = [
        {"step": "gt", "kind": "render", "metric": "render_seconds", "value": 2.0,
         "lower_is_better": True, "render_seconds": 2.0},
        _row("spp1", "flip", 0.2, True, render_seconds=0.5),
        _row("spp2", "flip", 0.1, True, render_seconds=0.9),
    ]  # fmt: skip
    doc = pivot(rows)
    names = [c["name"] for c in doc["columns"]]
    assert names == ["render_seconds", "flip", "cost.render_seconds"]
    assert doc["cells"]["spp1"]["cost.render_seconds"]["median"] == 0.5
    assert doc["best"] == {"flip": "spp2"}  # render times: each render's own, not ranked
    assert set(doc["unranked"]) == {"cost.render_seconds"}


def test05_the_cli_table_names_the_unranked_timings() -> None:
    from service.cli.results_command import pivot_tables

    table = pivot_tables(pivot(ROWS), 200)[-1]
    assert table.caption is not None and "not ranked: ns_per_eval" in str(table.caption)
    (quiet,) = pivot_tables(
        pivot([_row("a", "flip", 0.1, True), _row("b", "flip", 0.2, True)]), 200
    )
    assert quiet.caption is None


def test_train_and_test_splits_are_two_methods_and_a_training_error_is_never_best() -> None:
    """A model's training and held-out rows are one method each, named by their split; the
    training error (lower than any test error here) is not marked best."""
    rows = [
        _row("hybrid", "brdf.smape", 0.02, True, split="train"),
        _row("hybrid", "brdf.smape", 0.30, True, split="test"),
        _row("neural", "brdf.smape", 0.20, True, split="test"),
        _row("hybrid", "fused_kernel_ns", 30.0, True),  # the model's speed: both splits'
    ]
    doc = pivot(rows)
    assert doc["methods"] == ["hybrid (train)", "hybrid (test)", "neural (test)"]
    assert doc["cells"]["hybrid (test)"]["fused_kernel_ns"]["mean"] == pytest.approx(30.0)
    assert doc["cells"]["hybrid (train)"]["fused_kernel_ns"]["mean"] == pytest.approx(30.0)
    assert doc["cells"]["hybrid (train)"]["brdf.smape"]["mean"] == pytest.approx(0.02)
    assert doc["best"]["brdf.smape"] == "neural (test)"
    assert method_of(rows[0], "split") == "train"  # by split itself: no suffix
    # training errors alone (a study of fits): the best of them is marked
    alone = pivot([_row("a", "brdf.smape", 0.2, True, split="train"),
                   _row("b", "brdf.smape", 0.1, True, split="train")])  # fmt: skip
    assert alone["best"] == {"brdf.smape": "b (train)"}
