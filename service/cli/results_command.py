"""``matforge results [JOB|BATCH...] [--out x.csv|x.json]``: the long-format results table.

Each argument is a job id or a batch file (the YAML/JSON that ``matforge batch`` ran): a
job gives its rows, a batch its steps' rows in step order (each row names its ``step``),
arguments in the order given. No argument: every succeeded job's rows (the newest 1,000
jobs). Rows come from the server (``GET /api/results``, ``POST /api/results/batch``), or
with ``--data-dir`` from a local store; the columns are :data:`jobapi.rows.COLUMNS`, one
row per measured value, easy to pivot. The terminal shows a condensed table; ``--out``
writes every column, ``--json`` prints the rows as one JSON list.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import typer
from rich.table import Table
from rich.text import Text

from service.cli.client import BadInput
from service.cli.state import (
    EXIT_BAD_INPUT,
    err_console,
    error,
    print_json,
    state_of,
    table_console,
)

#: Columns of the terminal table (``--out`` writes all of them).
SHOWN = (
    "job",
    "step",
    "kind",
    "candidate",
    "material",
    "split",
    "scene",
    "metric",
    "value",
    "spp",
    "render_seconds",
    "ns_per_eval",
    "train_seconds",
)
JOB_ID_CHARS = frozenset("0123456789abcdef")


def is_batch_file(arg: str) -> bool:
    """Whether ``arg`` names a batch file (an existing ``.yaml``/``.yml``/``.json`` file)."""
    return Path(arg).suffix.lower() in (".yaml", ".yml", ".json") and Path(arg).is_file()


def check_job_arg(arg: str) -> str:
    """A job id argument or a prefix of one (git-style short id), lower-cased;
    :class:`BadInput` for anything else. Resolve a prefix with :func:`full_job_id`."""
    job = arg.strip().lower().removeprefix("job:")
    if not 1 <= len(job) <= 32 or not set(job) <= JOB_ID_CHARS:
        raise BadInput(
            f"{arg!r}: neither a job id (32 hex digits, or a unique prefix of one) "
            "nor a batch file (.yaml/.json)"
        )
    return job


def full_job_id(arg: str, lookup: Any) -> str:
    """The full id of job argument ``arg`` (a whole id or a unique prefix); ``lookup(prefix)``
    returns the full id or raises (``NotFoundError``, ``AmbiguousIdError``: exit 2)."""
    job = check_job_arg(arg)
    return job if len(job) == 32 else str(lookup(job))


def _filters(
    kind: str | None,
    dataset: str | None,
    metric: list[str],
    candidate: str | None,
    scene: str | None,
) -> dict[str, Any]:
    out: dict[str, Any] = {
        "kind": kind,
        "dataset": dataset,
        "candidate": candidate,
        "scene": scene,
        "metric": metric or None,
    }
    return {k: v for k, v in out.items() if v}


def _check_options(filters: dict[str, Any], by: str | None) -> None:
    """Refuse (exit 2, before any job is read) an unknown ``--kind`` or ``--metric`` and,
    with ``--pivot``, a ``--by`` that is not a row column, each with the closest known
    names: a misspelt option is never an empty table."""
    import difflib

    from jobapi.rows import KEY_COLUMNS
    from service.results import RowFilter, check_row_filter

    check_row_filter(
        RowFilter(kind=filters.get("kind"), metric=tuple(filters.get("metric") or ())),
        {"kind": "--kind", "metric": "--metric"},
    )
    if by is not None and by not in KEY_COLUMNS:
        close = difflib.get_close_matches(by, KEY_COLUMNS, n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        raise BadInput(f"--by {by}: not a row column{hint} (one of: {', '.join(KEY_COLUMNS)})")


def _batch_steps(path: Path, variables: dict[str, str] | None = None) -> list[dict[str, Any]]:
    from service.cli.batch import load_batch

    plan = load_batch(path, variables=variables)
    return [{"name": s.name, "spec": s.spec} for s in plan.steps]


def _var_values(template: Any, spec: Any, found: dict[str, Any]) -> None:
    """Into ``found``: the value at each place where ``template`` (a step's spec as the
    batch file writes it) holds a whole ``var:<name>`` string, read from ``spec`` (the
    job's stored spec, same shape)."""
    if isinstance(template, str) and template.startswith("var:"):
        found.setdefault(template[4:], spec)
    elif isinstance(template, dict) and isinstance(spec, dict):
        for key, sub in template.items():
            if key in spec:
                _var_values(sub, spec[key], found)
    elif isinstance(template, list) and isinstance(spec, list):
        for sub, got in zip(template, spec, strict=False):
            _var_values(sub, got, found)


def last_run_vars(
    path: Path, given: dict[str, str], client: Any
) -> tuple[dict[str, str], str | None]:
    """The batch's variables for reading its results: ``given``, and each variable that
    has neither a value there nor a default taken from the jobs of the file's latest run
    on the server (``matforge batch`` labels them ``<file name> <UTC time>``), where a
    step's spec holds it; and that run's label (``None``: none was needed or found)."""
    from service.spec_text import parse_spec_text

    try:
        doc = parse_spec_text(path.read_text(encoding="utf-8"), str(path))
    except (OSError, ValueError):
        return given, None
    declared = doc.get("vars") if isinstance(doc, dict) else None
    if not isinstance(declared, dict):
        return given, None
    missing = {k for k, v in declared.items() if v is None and k not in given}
    steps = doc.get("steps") if isinstance(doc, dict) else doc
    if not missing or not isinstance(steps, list):
        return given, None
    prefix = f"{path.name} "
    found: dict[str, Any] = {}
    label: str | None = None
    for step in steps:
        spec = step.get("spec") if isinstance(step, dict) else None
        if not isinstance(spec, dict) or not isinstance(spec.get("kind"), str):
            continue
        wanted: dict[str, Any] = {}
        _var_values(spec, spec, wanted)
        if not set(wanted) & (missing - set(found)):
            continue
        jobs, _ = client.list_page(kind=spec["kind"], limit=200)
        runs = [j for j in jobs if str(j.get("batch") or "").startswith(prefix)
                and (label is None or j.get("batch") == label)
                and ("name" not in spec or j.get("name") == spec["name"])]  # fmt: skip
        if not runs:
            continue
        job = runs[0]  # newest first
        label = str(job.get("batch"))
        _var_values(spec, client.get(str(job["id"])).get("spec"), found)
    recovered = {k: str(v) for k, v in found.items() if k in missing and isinstance(v, str | int)}
    return {**given, **recovered}, label if recovered else None


def _warn_missing(source: str, steps: list[dict[str, Any]]) -> None:
    missing = [str(s.get("step")) for s in steps if s.get("state") != "succeeded"]
    if missing:
        err_console.print(
            f"{source}: no succeeded job for step(s) {', '.join(missing)} (run the batch first)",
            markup=False,
            highlight=False,
        )


def collect_local(
    data_dir: Path,
    args: list[str],
    filters: dict[str, Any],
    variables: dict[str, str] | None = None,
) -> list[dict[str, Any]]:
    """The rows of ``args`` from the local store in ``data_dir``."""
    from service.cli.artifacts import open_local
    from service.results import RowFilter, batch_rows, select_rows
    from storage.job_queries import resolve_job_id

    jobs, store = open_local(data_dir)
    where = RowFilter(
        kind=filters.get("kind"),
        dataset=filters.get("dataset"),
        metric=tuple(filters.get("metric") or ()),
        candidate=filters.get("candidate"),
        scene=filters.get("scene"),
    )
    if not args:
        return [r.document() for r in select_rows(jobs, store, where=where)]
    rows: list[dict[str, Any]] = []
    for arg in args:
        if is_batch_file(arg):
            result = batch_rows(_batch_steps(Path(arg), variables), jobs, store, where)
            _warn_missing(arg, result.steps)
            rows += [r.document() for r in result.rows]
        else:
            rows += [
                r.document()
                for r in select_rows(
                    jobs,
                    store,
                    job_ids=[full_job_id(arg, lambda p: resolve_job_id(jobs, p))],
                    where=where,
                )
            ]
    return rows


def collect_remote(
    ctx: typer.Context,
    args: list[str],
    filters: dict[str, Any],
    variables: dict[str, str] | None = None,
) -> list[dict[str, Any]]:
    """The rows of ``args`` from the server."""
    rows: list[dict[str, Any]] = []
    with state_of(ctx).client() as client:
        if not args:
            return client.results(filters)
        for arg in args:
            if is_batch_file(arg):
                # a recipe's variables need not be repeated: its last run's are read
                values, label = last_run_vars(Path(arg), dict(variables or {}), client)
                if label is not None:
                    given = " ".join(f"--var {k}={v}" for k, v in values.items()
                                     if k not in (variables or {}))  # fmt: skip
                    err_console.print(f"{arg}: {given} (its run {label!r})", markup=False,
                                      highlight=False, soft_wrap=True)  # fmt: skip
                doc = client.batch_results(_batch_steps(Path(arg), values), filters)
                _warn_missing(arg, list(doc.get("steps") or []))
                rows += list(doc.get("rows") or [])
            else:
                job = full_job_id(arg, lambda p: client.get(p)["id"])
                rows += client.results({**filters, "job": [job]})
    return rows


def write_rows(path: Path, rows: list[dict[str, Any]]) -> None:
    """``.csv`` (columns :data:`jobapi.rows.COLUMNS`, config as JSON) or ``.json`` (a list)."""
    from jobapi.rows import ResultRow
    from service.results import rows_csv

    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix.lower() == ".json":
        path.write_text(json.dumps(rows, indent=2) + "\n", encoding="utf-8")
    else:
        path.write_text(rows_csv(ResultRow(**r) for r in rows), encoding="utf-8")


def _cell(col: str, value: Any) -> str:
    if value is None:
        return ""
    if col == "job":
        return str(value)[:12]
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value)


def rows_table(rows: list[dict[str, Any]]) -> Table:
    """A condensed Rich table: the :data:`SHOWN` columns that have a value."""
    cols = [c for c in SHOWN if any(r.get(c) is not None for r in rows)]
    table = Table(title=f"{len(rows)} result rows")
    for col in cols:
        numeric = col in ("value", "spp") or col.endswith(("_seconds", "_eval"))
        table.add_column(col, justify="right" if numeric else "left", overflow="fold")
    for r in rows:
        table.add_row(*(Text(_cell(c, r.get(c))) for c in cols))
    return table


def register(app: typer.Typer) -> None:
    """Add ``results`` to the app."""

    @app.command()
    def results(
        ctx: typer.Context,
        args: list[str] = typer.Argument(
            None, metavar="[JOB|BATCH]...", help="Job ids and batch files (default: all jobs)."
        ),
        out: Path | None = typer.Option(
            None, "--out", "-o", help="Write the rows to this .csv or .json file."
        ),
        kind: str | None = typer.Option(None, "--kind", help="Only rows of this job kind."),
        dataset: str | None = typer.Option(None, "--dataset", help="Only this dataset."),
        metric: list[str] = typer.Option([], "--metric", help="Only this metric (repeatable)."),
        candidate: str | None = typer.Option(None, "--candidate", help="Only this candidate."),
        scene: str | None = typer.Option(None, "--scene", help="Only this scene."),
        data_dir: Path | None = typer.Option(
            None, "--data-dir", show_default=False, help="Read a local store, not the server."
        ),
        as_json: bool = typer.Option(False, "--json", help="Print the rows as one JSON list."),
        pivot: bool = typer.Option(
            False,
            "--pivot",
            help="A method x metric table instead: per method the mean (and spread) of each "
            "metric and its costs, the best per column marked (--by names the method).",
        ),
        var: list[str] = typer.Option(
            [],
            "--var",
            help="NAME=VALUE for a batch file's vars, as given to `matforge batch`.",
        ),
        by: str = typer.Option(
            "candidate",
            "--by",
            help="With --pivot: the row column that names a method (candidate, material, "
            "scene, step, kind, ...).",
        ),
    ) -> None:
        """Every measured value as one row (job, kind, dataset, scene, candidate, config,
        metric, value, lower-is-better, seed, costs); a batch's rows in step order.

        ``--pivot``: one row per method instead, as nerfbaselines tables are (``--json``:
        the ``matforge.pivot/1`` document; ``--out``: its CSV or JSON)."""
        if out is not None and out.suffix.lower() not in (".csv", ".json"):
            error(f"--out {out}: must end in .csv or .json")
            raise typer.Exit(EXIT_BAD_INPUT)
        from service.cli.batch import parse_vars

        filters = _filters(kind, dataset, metric, candidate, scene)
        _check_options(filters, by if pivot else None)
        local = state_of(ctx).local_dir(data_dir)
        arg_list = list(args or [])
        if local is not None:
            rows = collect_local(local, arg_list, filters, parse_vars(var))
        else:
            rows = collect_remote(ctx, arg_list, filters, parse_vars(var))
        if pivot:
            show_pivot(rows, by, out, as_json)
            return
        if out is not None:
            write_rows(out, rows)
            err_console.print(f"{len(rows)} rows written to {out}", markup=False, highlight=False)
        if as_json:
            print_json(rows)
        else:
            table_console(to_stderr=out is not None).print(rows_table(rows))


def show_pivot(rows: list[dict[str, Any]], by: str, out: Path | None, as_json: bool) -> None:
    """Print (and with ``out``, write) the method x metric table of ``rows``."""
    import csv

    from jobapi.rows import KEY_COLUMNS
    from service.results_pivot import pivot, pivot_csv_rows

    if by not in KEY_COLUMNS:  # checked with the other options (_check_options)
        raise BadInput(f"--by {by}: not a row column (one of: {', '.join(KEY_COLUMNS)})")
    doc = pivot(rows, by)
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        if out.suffix.lower() == ".json":
            out.write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")
        else:
            header, flat = pivot_csv_rows(doc)
            with open(out, "w", newline="", encoding="utf-8") as fh:
                writer = csv.DictWriter(fh, fieldnames=header)
                writer.writeheader()
                for r in flat:
                    writer.writerow({k: "" if v is None else v for k, v in r.items()})
        err_console.print(
            f"{len(doc['methods'])} methods written to {out}", markup=False, highlight=False
        )
    if as_json:
        print_json(doc)
    else:
        console = table_console(to_stderr=out is not None)
        for table in pivot_tables(doc, console.width):
            console.print(table)


def pivot_tables(doc: dict[str, Any], width: int) -> list[Table]:
    """The pivot document as Rich tables that fit in ``width`` characters: ``mean ± std``
    per metric, the median per cost, the best of each column in bold with a ``*``,
    lower/higher-is-better arrows in the header.

    Methods that share no column (a render's image statistics, a MERL collection's table
    quality, a trained model's scores) get a table each (:func:`service.cli.tables.blocks`).
    A table too wide for ``width`` is split by columns, each part repeating the method
    column (:func:`service.cli.tables.fitted_tables`), or transposed, a row per column and
    a column per method, when that makes fewer parts (one method of many columns). No
    header or number is cut."""
    from service.cli.tables import blocks, chunk_count, fitted_tables

    header = {
        col["name"]: col["name"]
        + {True: " \u2193", False: " \u2191"}.get(col["lower_is_better"], "")
        for col in doc["columns"]
    }
    roles = {col["name"]: col["role"] for col in doc["columns"]}
    order = [col["name"] for col in doc["columns"]]
    cells: dict[str, dict[str, Text]] = {}
    for meth in doc["methods"]:
        cells[meth] = {}
        for name, got in doc["cells"][meth].items():
            if got is None or name not in roles:
                continue
            if roles[name] == "metric":
                text = f"{got['mean']:.4g}"
                if got["std"] is not None:
                    text += f" \u00b1 {got['std']:.2g}"
            else:
                text = f"{got['median']:.4g}"
            best = doc["best"].get(name) == meth
            cells[meth][name] = Text(text + (" *" if best else ""), style="bold" if best else "")
    groups = blocks([(m, [c for c in order if c in cells[m]]) for m in doc["methods"]])
    if not groups:
        groups = [(list(doc["methods"]), [])]
    tables: list[Table] = []
    for n, (methods, columns) in enumerate(groups, start=1):
        title = f"{len(doc['methods'])} methods by {doc['by']}"
        if len(groups) > 1:
            names = ", ".join(methods[:3]) + (f" and {len(methods) - 3} more" * (len(methods) > 3))
            title = f"{title}, group {n}/{len(groups)}: {names}"
        heads = [header[c] for c in columns]
        rows = [(m, [cells[m].get(c, Text("")) for c in columns]) for m in methods]
        flipped = [(header[c], [cells[m].get(c, Text("")) for m in methods]) for c in columns]
        wide = chunk_count(heads, rows, doc["by"], width)
        tall = chunk_count(methods, flipped, "column", width)
        if len(methods) > 1 and tall >= wide or wide == 1:
            tables += fitted_tables(title, doc["by"], heads, rows, width)
        else:
            tables += fitted_tables(title, "column", methods, flipped, width)
    unranked = doc.get("unranked") or {}
    if unranked and tables:
        tables[-1].caption = f"not ranked: {', '.join(unranked)}: {next(iter(unranked.values()))}"
    return tables
