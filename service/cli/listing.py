"""``matforge ls`` (jobs on the server) and ``matforge kinds`` (the registry)."""

from __future__ import annotations

from typing import Any

import typer
from rich.table import Table
from rich.text import Text

from service.cli.results import STATE_STYLE
from service.cli.state import err_console, out_console, print_json, print_line, state_of

JsonOpt = typer.Option(False, "--json", help="Print one JSON document on stdout.")


#: Characters a column of a Rich table takes beyond its cells: one space of padding each
#: side and its border; a table has one more border.
_OVERHEAD = 3
#: The fewest characters of a message column (narrower, the message is left out).
_MIN_MESSAGE = 10


def _clip(text: str, width: int) -> str:
    return text if len(text) <= width else text[: max(0, width - 1)] + "\u2026"


def jobs_table(
    docs: list[dict[str, Any]],
    width: int = 120,
    columns: list[tuple[str, str]] | None = None,
) -> Table:
    """Jobs as a table of at most ``width`` characters: short ids (any unique prefix works
    as an id; the 12 characters are never cut), kind, state and progress at their full
    width; then the name, the creation time and the message. The name and the message
    wrap, never cut: when the message has no room for 40 characters on a line, the
    creation time is left out, then the name narrows, down to 10 characters.

    ``columns``: extra ``(header, cell)`` columns after ``done``, each cell taken from the
    job's params or metrics (:func:`service.job_columns.cell_text`), e.g.
    ``("params.model", ...)``; they keep their full width as well."""
    from service.job_columns import cell_text

    extra = columns or []
    rows = []
    for d in docs:
        state = str(d.get("state"))
        message = d.get("error") if state == "failed" else d.get("message")
        rows.append(
            {
                "id": str(d.get("id"))[:12],
                "kind": str(d.get("kind")),
                "state": state,
                "done": f"{100 * float(d.get('progress') or 0):.0f}%",
                **{h: cell_text(d, key) for h, key in extra},
                "name": " ".join(
                    [*str(d.get("name") or "").split(), *(f"#{t}" for t in d.get("tags") or [])]
                ),
                "created (UTC)": str(d.get("created_at") or "")[:19].replace("T", " "),
                "message": " ".join(str(message or "").split()),
            }
        )
    fixed = ["id", "kind", "state", "done", *(h for h, _ in extra)]

    def natural(col: str) -> int:
        return max([len(col), *(len(r[col]) for r in rows)])

    widths = {c: natural(c) for c in fixed}
    name_w = min(natural("name"), 32)
    created_w = natural("created (UTC)")
    message_need = min(natural("message"), 40)
    shown_created = True

    def room() -> int:  # what is left for the message
        cols = len(fixed) + 2 + shown_created
        used = sum(widths.values()) + name_w + (created_w if shown_created else 0)
        return width - 1 - _OVERHEAD * (cols + 1) - used + _OVERHEAD

    # The message and the name wrap rather than being cut to a few characters: the
    # creation time is left out first, then the name narrows (to 10 characters).
    if room() < message_need:
        shown_created = False
    if room() < message_need:
        name_w = max(min(natural("name"), 10), name_w - (message_need - room()))
    if room() > message_need:  # room to spare: the whole name on one line
        name_w += max(0, min(natural("name") - name_w, room() - message_need))
    message_w = max(room(), 0)
    layout = [(c, widths[c]) for c in fixed] + [("name", name_w)]
    if shown_created:
        layout.append(("created (UTC)", created_w))
    if message_w >= _MIN_MESSAGE:
        layout.append(("message", message_w))
    wraps = {"name", "message"}
    table = Table(title=None, expand=False)
    for col, w in layout:
        table.add_column(
            col,
            no_wrap=col not in wraps,
            overflow="fold" if col in wraps else "ellipsis",
            min_width=w,
            max_width=w,
            justify="right" if col == "done" else "left",
        )
    for r in rows:
        cells = []
        for col, w in layout:
            style = STATE_STYLE.get(r[col], "") if col == "state" else ""
            cells.append(Text(r[col] if col in wraps else _clip(r[col], w), style=style))
        table.add_row(*cells)
    return table


def ls(
    ctx: typer.Context,
    kind: str | None = typer.Option(None, "--kind", show_default=False, help="Only this kind."),
    state: str | None = typer.Option(
        None,
        "--state",
        show_default=False,
        help="Only jobs in this state (queued, running, succeeded, failed, cancelled).",
    ),
    name: str | None = typer.Option(
        None, "--name", show_default=False, help="Only jobs whose name contains this (any case)."
    ),
    limit: int = typer.Option(20, "--limit", "-n", min=1, max=1000, help="At most this many."),
    column: list[str] = typer.Option(
        [],
        "--column",
        "-c",
        help="Also show this value (repeatable or comma-separated): params.<path> "
        "(e.g. params.model) or metric.<name> (the mean of its results, e.g. metric.image.psnr).",
    ),
    filters: list[str] = typer.Option(
        [],
        "--filter",
        "-f",
        help="Only jobs whose value passes, e.g. params.model=hybrid or "
        "'metric.brdf.smape<0.1' (ops = != < <= > >=; repeatable: all must pass).",
    ),
    tag: str | None = typer.Option(None, "--tag", show_default=False, help="Only this tag."),
    batch: str | None = typer.Option(
        None, "--batch", show_default=False, help="Only jobs of this batch run (its label)."
    ),
    as_json: bool = JsonOpt,
) -> None:
    """List jobs on the server, newest first (ids shortened; any unique prefix is an id)."""
    from service.job_columns import parse_filters, parse_keys

    keys = parse_keys(column, "--column")
    parse_filters(filters, "--filter")  # exit 2 here, before asking the server
    with state_of(ctx).client() as client:
        docs, total = client.list_page(
            state=state,
            kind=kind,
            name=name,
            limit=limit,
            columns=keys,
            filters=filters,
            tag=tag,
            batch=batch,
        )
    if as_json:
        print_json(docs)
        return
    if not docs:
        err_console.print("no jobs match", markup=False, highlight=False)
        return
    console = out_console()
    console.print(jobs_table(docs, console.width, [(k, k) for k in keys]))
    if total is not None and total > len(docs):
        err_console.print(
            f"showing {len(docs)} of {total} jobs; use --limit to see more",
            markup=False,
            highlight=False,
        )


def kinds(
    kind: str | None = typer.Argument(None, metavar="[KIND]", help="Show this kind's params."),
    as_json: bool = JsonOpt,
) -> None:
    """The job kinds (from the registry): what each makes; with KIND, its params."""
    from service import kinds as registry
    from service.cli.client import BadInput
    from service.kind_docs import kind_document, nested_models, param_forms, param_rows

    known = registry.all_kinds()
    for p in registry.plugins():  # on stderr: --json's document stays one list
        if p.error is not None:
            err_console.print(
                f"plugin {p.name!r} ({p.value}, from {p.distribution or 'unknown package'}) "
                f"not loaded: {p.error}",
                markup=False,
                highlight=False,
            )
    if kind is not None and kind not in known:
        import difflib

        close = difflib.get_close_matches(kind, list(known), n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        raise BadInput(f"unknown kind {kind!r}{hint} (see 'matforge kinds')")
    console = out_console()
    if kind is None:
        if as_json:
            print_json([kind_document(k) for k in known.values()])
            return
        table = Table(title="job kinds (matforge kinds KIND: its params)")
        table.add_column("kind", no_wrap=True)
        table.add_column("what it makes", overflow="fold", ratio=2)
        table.add_column("artifacts", overflow="fold", ratio=1)
        for k in known.values():
            origin = registry.plugin_of(k.name)
            what = k.description + (f" [plugin: {origin}]" if origin else "")
            table.add_row(k.name, Text(what), Text(", ".join(k.artifacts)))
        console.print(table)
        return
    k = known[kind]
    if as_json:
        print_json(kind_document(k))
        return
    origin = registry.plugin_of(k.name)
    console.print(Text(k.name, style="bold"), Text(k.description))
    if origin:
        console.print(Text(f"plugin: {origin} (entry point group matforge.kinds)"))
    if k.artifacts:
        console.print(Text("artifacts: " + ", ".join(k.artifacts)))
    table = Table(title=f"params of {k.name}")
    for col in ("param", "type", "default"):
        table.add_column(col, overflow="fold")
    table.add_column("description", overflow="fold", ratio=1)
    for name, type_, default, desc in param_rows(k):
        table.add_row(Text(name), Text(type_), Text(default), Text(desc))
    console.print(table)
    for param, forms in param_forms(k):  # a material's sources: the keys it may have
        sub = Table(title=f"{param}: an object of one of these forms (its one key)")
        sub.add_column("form", overflow="fold")
        sub.add_column("description", overflow="fold", ratio=1)
        for form, desc in forms:
            sub.add_row(Text(form), Text(desc))
        console.print(sub)
    for model, about, rows in nested_models(k):  # what a param's type names by model name
        sub = Table(title=f"{model}: {about}" if about else model)
        for col in ("field", "type", "default"):
            sub.add_column(col, overflow="fold")
        sub.add_column("description", overflow="fold", ratio=1)
        for name, type_, default, desc in rows:
            sub.add_row(Text(name), Text(type_), Text(default), Text(desc))
        console.print(sub)


def tag(
    ctx: typer.Context,
    job_id: str = typer.Argument(..., metavar="JOB", help="Job id, or a unique prefix of it."),
    tags: list[str] = typer.Argument(..., metavar="TAG...", help="Tags to add."),
    remove: bool = typer.Option(False, "--remove", "-r", help="Remove these tags instead."),
    as_json: bool = JsonOpt,
) -> None:
    """Add tags to a job (``ls --tag T`` finds it); with --remove, take them off."""
    with state_of(ctx).client() as client:
        doc = client.tag(job_id, remove=tags) if remove else client.tag(job_id, add=tags)
    if as_json:
        print_json(doc)
    else:
        print_line(f"{doc.get('id')} tags: {', '.join(doc.get('tags') or []) or '(none)'}")


def rename(
    ctx: typer.Context,
    job_id: str = typer.Argument(..., metavar="JOB", help="Job id, or a unique prefix of it."),
    name: str = typer.Argument(..., help="The new name ('' for none)."),
    as_json: bool = JsonOpt,
) -> None:
    """Give a job a new name (its spec's identity is unchanged: a name is a label)."""
    with state_of(ctx).client() as client:
        doc = client.rename(job_id, name or None)
    if as_json:
        print_json(doc)
    else:
        print_line(f"{doc.get('id')} name: {doc.get('name') or '(none)'}")


def register(app: typer.Typer) -> None:
    """Add ``ls``, ``kinds``, ``tag`` and ``rename`` to the app."""
    app.command("ls")(ls)
    app.command("kinds")(kinds)
    app.command("tag")(tag)
    app.command("rename")(rename)
