"""The steps of a batch run: one flat row per step, printed by ``batch --json`` and shown
as a Rich table (``batch --out`` writes the tidy result rows of ``matforge results``
instead, one per measured value: :func:`service.cli.results_command.write_rows`).

A row has ``step``, ``kind``, ``job_id``, ``state``, ``seconds`` (the job's run time) and
``error``, then, for every step whose kind has a result table (its summary hook), the
table's numeric cells as ``<label>.<column>`` columns. One row per step (skipped steps
included) keeps the rows in step order and the same shape for every batch: a score step
with several candidates widens its row instead of adding rows. On the terminal each step
shows one :func:`headline` of its result table; ``batch -v`` prints the whole tables.
"""

from __future__ import annotations

from typing import Any

from rich.table import Table
from rich.text import Text

from jobapi.results import ResultTable
from service.cli.batch import StepResult
from service.cli.tables import fitted_tables

BASE_COLUMNS = ("step", "kind", "job_id", "state", "seconds", "error")
#: The most characters of each column that a narrow table keeps whole.
KEPT_WIDTH = {"step": 24, "kind": 18, "job_id": 12, "state": 9, "seconds": 8}


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


def results_table(
    columns: list[str],
    rows: list[dict[str, Any]],
    title: str,
    results: list[StepResult] | None = None,
    width: int | None = None,
) -> Table:
    """A Rich table of the steps (job ids shortened to 12 characters; the ``error`` column
    only when a step has an error; with ``results``, a ``result`` column: each step's
    :func:`headline`; whole result tables are :func:`metrics_tables`). With ``width``, the
    table fits in it: the result line is cut to the room the other columns leave, and
    given below the table, a line per step, when that is under 12 characters."""
    shown = [c for c in BASE_COLUMNS if c != "error" or any(r.get("error") for r in rows)]
    table = Table(title=title)
    used = 1
    for col in shown:
        # the step, kind, id, state and time keep their width (a step name up to 24
        # characters): the result line gives way first, as in `matforge ls`
        texts = [col, *(_cell(r.get(col))[: 12 if col == "job_id" else None] for r in rows)]
        natural = max(len(t) for t in texts)
        keep = min(natural, KEPT_WIDTH.get(col, 0))
        used += min(natural, 48 if col == "error" else natural) + 3
        table.add_column(
            col,
            overflow="fold",
            min_width=keep or None,
            max_width=48 if col == "error" else None,
            justify="right" if col == "seconds" or "." in col else "left",
        )
    room = 60 if width is None else min(60, width - used - 3)
    lines = [headline(r.table, max(room, 12)) for r in results] if results is not None else []
    beside = any(lines) and room >= 12
    if beside:
        table.add_column("result", overflow="ellipsis", no_wrap=True, max_width=room)
    elif any(lines):  # under the table, each as wide as the table
        below = [
            f"{r.step}: {headline(r.table, max(20, used - len(r.step) - 2))}"
            for r in results or []
            if r.table is not None and r.table.rows
        ]
        table.caption = "\n".join(below)
        table.caption_justify = "left"
    for i, row in enumerate(rows):
        cells = []
        for col in shown:
            value = row.get(col)
            text = _cell(value[:12] if col == "job_id" and value else value)
            style = STATE_STYLE.get(text, "") if col == "state" else ""
            cells.append(Text(text, style=style))
        if beside:
            cells.append(Text(lines[i]))
        table.add_row(*cells)
    return table


def headline(doc: ResultTable | None, width: int = 60) -> str:
    """One line of a step's result table (cut at ``width`` characters, with an ellipsis):
    its first column that is an error or a score (a metric with a better direction,
    :func:`jobapi.rows.lower_is_better`), for its ``mean`` row when it has one, else for
    each label (``flip: rough 0.1234, same 0``; ``smape: mean 0.11 (3 materials)``); a
    table of no such column (a render's image, a dataset's materials) is counted and
    named (``1 scene: sphere_env``, ``12 materials: iridescent-000-Au, ...``)."""
    from jobapi.rows import lower_is_better

    if doc is None or not doc.rows:
        return ""
    numeric = [
        c
        for c in doc.columns
        if lower_is_better(c) is not None
        and any(
            isinstance(v.get(c), int | float) and not isinstance(v.get(c), bool)
            for v in doc.rows.values()
        )  # fmt: skip
    ]
    what = doc.label_header.lower() or "row"
    if numeric:
        col = numeric[0]
        mean = doc.rows.get("mean")
        if mean is not None and mean.get(col) is not None:
            n = len(doc.rows) - 1
            text = f"{col}: mean {_cell(mean.get(col))} ({n} {_plural(what, n)})"
        else:
            parts = [f"{label} {_cell(values.get(col))}" for label, values in doc.rows.items()]
            text = f"{col}: " + ", ".join(parts)
    else:
        n = len(doc.rows)
        text = f"{n} {_plural(what, n)}: " + ", ".join(doc.rows)
    return text if len(text) <= width else text[: width - 1] + "\u2026"


def _plural(word: str, n: int) -> str:
    return word if n == 1 or word.endswith("s") else word + "s"
