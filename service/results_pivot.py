"""A method x metric table of result rows, as nerfbaselines prints one: a row per method,
its mean metrics (with their spread and count) and its costs, the best per column marked.

The rows are the tidy ones of :mod:`jobapi.rows` (``GET /api/results``, ``matforge
results``). A *method* is the value of the ``by`` column (default ``candidate``); a row
without one is named by its ``step`` (a batch's) or its kind and short job id, so a
render's or a training job's own rows get a line too. For each method and metric:

- ``mean``: the mean of the values (over seeds, materials, scenes: whatever the rows hold),
  ``std``: their sample standard deviation (``None`` for one value), ``n``: how many;
- each cost (:data:`jobapi.rows.COST_COLUMNS`): the median of the method's rows that have
  it (a cost is repeated on every row it belongs to, so the median is that cost when it is
  one, and a robust middle when timings of several jobs mix). A cost that is also a metric
  of some row (a render's own ``render_seconds`` row) is the column ``cost.<name>``.

``best[column]`` is the method with the lowest mean (or highest, for a metric where higher
is better, from the rows' ``lower_is_better``; every cost is lower-is-better), among the
methods that are not training errors (a ``train`` split's) where a metric's column has any
other.
A metric without a better direction (``lower_is_better`` null) has no best. Ties go to the method
named first. Methods keep the order of their first row. A method's rows of the ``train``
and ``test`` splits are two methods (``"hybrid 32x3 (train)"``, ``"hybrid 32x3 (test)"``);
its rows without a split (its speed, measured once for the model) belong to both.
Metric columns are the rows' names, which say their space where it is ambiguous
(``brdf.mae``, ``image.mae``: :mod:`jobapi.metric_names`): two units never share a column.

Timings (:data:`jobapi.rows.TIMED_COLUMNS`: ``ns_per_eval``, ``render_seconds``,
``fused_kernel_ns``, ...) are each job's own, taken at its own moment and load: the table
shows them but ranks none, and ``unranked[column]`` says why (``report.pareto`` and
``select`` time every model in one pass of their own, beside a reference kernel).
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Iterable, Mapping
from typing import Any

from jobapi.rows import COST_COLUMNS, TIMED_COLUMNS

#: The schema name of the pivot document (``matforge results --pivot --json``).
FORMAT = "matforge.pivot/1"


def method_of(row: Mapping[str, Any], by: str = "candidate") -> str:
    """The method a row belongs to: its ``by`` value, else its step, else ``kind job[:8]``;
    a row with a ``split`` (``train``, ``test``) names it after the method (``"hybrid 32x3
    (test)"``), so that training and held-out errors are never one mean."""
    name = next((str(row[k]) for k in (by, "step") if row.get(k) not in (None, "")), None)
    if name is None:
        name = f"{row.get('kind')} {str(row.get('job') or '')[:8]}".strip()
    split = row.get("split")
    return f"{name} ({split})" if split and by != "split" else name


def _finite(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    v = float(value)
    return v if math.isfinite(v) else None


def pivot(rows: Iterable[Mapping[str, Any]], by: str = "candidate") -> dict[str, Any]:
    """The pivot document of ``rows``: ``{"format", "by", "methods", "columns", "cells",
    "best", "unranked"}``; ``columns`` are ``{"name", "role": "metric" | "cost",
    "lower_is_better"}``, ``cells[method][column]`` is ``{"mean", "std", "n"}`` for a
    metric and ``{"median", "n"}`` for a cost (absent where the method has none);
    ``unranked[column]`` why a timing column has no best."""
    methods: list[str] = []
    values: dict[str, dict[str, list[float]]] = {}
    costs: dict[str, dict[str, list[float]]] = {}
    direction: dict[str, bool | None] = {}
    trained: set[str] = set()  # methods of training rows: not "best" beside test ones
    rows = list(rows)
    # A model's rows without a split (its speed, measured once) belong to each of its splits.
    splits: dict[str, list[str]] = {}
    for row in rows:
        if row.get("split") and by != "split":
            got = splits.setdefault(method_of({**row, "split": None}, by), [])
            if method_of(row, by) not in got:
                got.append(method_of(row, by))
    for row in rows:
        own = method_of(row, by)
        for method in [own] if row.get("split") else splits.get(own, [own]):
            if method not in values:
                methods.append(method)
                values[method], costs[method] = {}, {}
                if method.endswith(" (train)") and by != "split":
                    trained.add(method)
            _add(row, values[method], costs[method], direction)
    return _document(methods, values, costs, direction, trained, by)


def _add(
    row: Mapping[str, Any],
    values: dict[str, list[float]],
    costs: dict[str, list[float]],
    direction: dict[str, bool | None],
) -> None:
    """One row's value and costs into its method's lists."""
    metric, value = row.get("metric"), _finite(row.get("value"))
    if isinstance(metric, str) and value is not None:
        values.setdefault(metric, []).append(value)
        lib = row.get("lower_is_better")
        direction.setdefault(metric, lib if isinstance(lib, bool) else None)
    for cost in COST_COLUMNS:
        amount = _finite(row.get(cost))
        if amount is not None and cost != metric:  # a cost reported as the metric is one
            costs.setdefault(cost, []).append(amount)


def _document(
    methods: list[str],
    values: dict[str, dict[str, list[float]]],
    costs: dict[str, dict[str, list[float]]],
    direction: dict[str, bool | None],
    trained: set[str],
    by: str,
) -> dict[str, Any]:
    """The pivot document of the methods' gathered values (see :func:`pivot`)."""
    metric_names = list(dict.fromkeys(m for meth in methods for m in values[meth]))
    # A cost that is also some row's metric (a render's own row is its render_seconds)
    # keeps both columns: the cost one is named "cost.<name>".
    cost_key = {c: f"cost.{c}" if c in metric_names else c for c in COST_COLUMNS}
    cost_names = [c for c in COST_COLUMNS if any(c in costs[m] for m in methods)]
    columns: list[dict[str, Any]] = [
        {"name": m, "role": "metric", "lower_is_better": direction.get(m)} for m in metric_names
    ] + [{"name": cost_key[c], "role": "cost", "lower_is_better": True} for c in cost_names]
    cells: dict[str, dict[str, dict[str, Any]]] = {}
    for meth in methods:
        cell: dict[str, dict[str, Any]] = {}
        for m, vs in values[meth].items():
            std = statistics.stdev(vs) if len(vs) > 1 else None
            cell[m] = {"mean": statistics.fmean(vs), "std": std, "n": len(vs)}
        for cost, vs in costs[meth].items():
            cell[cost_key[cost]] = {"median": statistics.median(vs), "n": len(vs)}
        cells[meth] = cell
    best: dict[str, str] = {}
    unranked: dict[str, str] = {}
    for col in columns:
        name, lib = col["name"], col["lower_is_better"]
        if lib is None:
            continue
        if name.removeprefix("cost.") in TIMED_COLUMNS:
            if sum(name in cells[m] for m in methods) > 1:
                unranked[name] = (
                    "timed by each job at its own moment and load: not ranked; "
                    "report.pareto and select time the models in one pass"
                )
            continue
        key = "mean" if col["role"] == "metric" else "median"
        scored = [(cells[m][name][key], m) for m in methods if name in cells[m]]
        if col["role"] == "metric" and any(m not in trained for _, m in scored):
            # beside a test error, a training error is no score
            scored = [(v, m) for v, m in scored if m not in trained]
        if len(scored) < 2:
            continue
        pick = min if lib else max
        target = pick(v for v, _ in scored)
        best[name] = next(m for v, m in scored if v == target)
    return {
        "format": FORMAT,
        "by": by,
        "methods": methods,
        "columns": columns,
        "cells": cells,
        "best": best,
        "unranked": unranked,
    }


def pivot_csv_rows(doc: Mapping[str, Any]) -> tuple[list[str], list[dict[str, Any]]]:
    """The pivot as flat CSV rows: ``method``, then per metric ``<m>``, ``<m>.std``,
    ``<m>.n``, per cost its median, and ``best``: the columns this method is best in."""
    header = ["method"]
    for col in doc["columns"]:
        name = col["name"]
        header += [name, f"{name}.std", f"{name}.n"] if col["role"] == "metric" else [name]
    header.append("best")
    out = []
    for meth in doc["methods"]:
        cell = doc["cells"][meth]
        row: dict[str, Any] = {"method": meth}
        for col in doc["columns"]:
            name, got = col["name"], cell.get(col["name"])
            if col["role"] == "metric":
                row[name] = got["mean"] if got else None
                row[f"{name}.std"] = got["std"] if got else None
                row[f"{name}.n"] = got["n"] if got else None
            else:
                row[name] = got["median"] if got else None
        row["best"] = " ".join(c for c, m in doc["best"].items() if m == meth)
        out.append(row)
    return header, out
