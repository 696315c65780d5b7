"""The results of a batch run: one flat row per step, written as CSV or JSON and shown as
a Rich table.

A row has ``step``, ``kind``, ``job_id``, ``state``, ``seconds`` (the job's run time) and
``error``, then, for every step whose kind has a result table (its summary hook), the
table's numeric cells as ``<label>.<column>`` columns. One row per step (skipped steps
included) keeps a CSV's rows in step order and the same shape for every batch: a score step
with several candidates widens its row instead of adding rows.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

from rich.table import Table
from rich.text import Text

from jobapi.results import ResultTable
from service.cli.batch import StepResult
from service.cli.tables import fitted_tables

BASE_COLUMNS = ("step", "kind", "job_id", "state", "seconds", "error")


def result_rows(results: list[StepResult]) -> tuple[list[str], list[dict[str, Any]]]:
    """The columns and one flat row per step (metric columns in order of first use)."""
    metric_cols: list[str] = []
    for r in results:
        metric_cols.extend(k for k in r.metrics if k not in metric_cols)
    columns = [*BASE_COLUMNS, *metric_cols]
    rows = []
    for r in results:
        row: dict[str, Any] = {
            "step": r.step,
            "kind": r.kind,
            "job_id": r.job_id,
            "state": r.state,
            "seconds": None if r.seconds is None else round(r.seconds, 3),
            "error": r.error,
        }
        row.update({c: r.metrics.get(c) for c in metric_cols})
        rows.append(row)
    return columns, rows


def write_rows(path: Path, columns: list[str], rows: list[dict[str, Any]]) -> None:
    """Write the rows as CSV (``.csv``) or as a JSON list of objects (``.json``)."""
    suffix = path.suffix.lower()
    if suffix not in (".csv", ".json"):
        raise ValueError(f"{path}: --out must end in .csv or .json")
    path.parent.mkdir(parents=True, exist_ok=True)
    if suffix == ".json":
        path.write_text(json.dumps(rows, indent=2) + "\n", encoding="utf-8")
        return
    with open(path, "w", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, fieldnames=columns)
        writer.writeheader()
        for row in rows:
            writer.writerow({k: "" if v is None else v for k, v in row.items()})


def _cell(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value)


STATE_STYLE = {
    "succeeded": "green",
    "failed": "red",
    "error": "red",
    "cancelled": "yellow",
    "skipped": "dim",
}


def metrics_tables(results: list[StepResult], width: int = 1000) -> list[Table]:
    """For the terminal: each step's result table (its kind's summary hook), a row per
    label and a column per value (the flat ``<label>.<column>`` columns are too wide),
    split into several tables when its columns do not fit in ``width`` characters."""
    tables = []
    for r in results:
        doc = r.table
        if doc is None or not doc.rows:
            continue
        tables.extend(result_table_views(doc, f"{r.step}: {doc.title.lower()}", width))
    return tables


def result_table_views(doc: ResultTable, title: str, width: int) -> list[Table]:
    """A kind's result table as Rich tables that fit in ``width`` characters."""
    rows = [
        (label, [_cell(values.get(m)) for m in doc.columns]) for label, values in doc.rows.items()
    ]
    return fitted_tables(title, doc.label_header.lower(), list(doc.columns), rows, width)


def results_table(columns: list[str], rows: list[dict[str, Any]], title: str) -> Table:
    """A Rich table of the steps (job ids shortened to 12 characters; the ``error`` column
    only when a step has an error; metrics are shown by :func:`metrics_tables`)."""
    shown = [c for c in BASE_COLUMNS if c != "error" or any(r.get("error") for r in rows)]
    table = Table(title=title)
    for col in shown:
        table.add_column(
            col,
            overflow="fold",
            max_width=48 if col == "error" else None,
            justify="right" if col == "seconds" or "." in col else "left",
        )
    for row in rows:
        cells = []
        for col in shown:
            value = row.get(col)
            text = _cell(value[:12] if col == "job_id" and value else value)
            style = STATE_STYLE.get(text, "") if col == "state" else ""
            cells.append(Text(text, style=style))
        table.add_row(*cells)
    return table
