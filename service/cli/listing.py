"""``matforge ls`` (jobs on the server) and ``matforge kinds`` (the registry)."""

from __future__ import annotations

from typing import Any

import typer
from rich.table import Table
from rich.text import Text

from service.cli.results import STATE_STYLE
from service.cli.state import err_console, out_console, print_json, state_of

JsonOpt = typer.Option(False, "--json", help="Print one JSON document on stdout.")


def jobs_table(docs: list[dict[str, Any]]) -> Table:
    """Jobs as a table that fits the console: short ids (any unique prefix works as an
    id), kind, name, state, progress, creation time, and the message cut to what fits."""
    table = Table(title=None, expand=False)
    table.add_column("id", no_wrap=True)
    table.add_column("kind", no_wrap=True)
    table.add_column("name", overflow="ellipsis", no_wrap=True, max_width=32)
    table.add_column("state", no_wrap=True)
    table.add_column("done", justify="right", no_wrap=True)
    table.add_column("created (UTC)", no_wrap=True)
    table.add_column("message", overflow="ellipsis", no_wrap=True, ratio=1)
    for d in docs:
        state = str(d.get("state"))
        created = str(d.get("created_at") or "")[:19].replace("T", " ")
        message = d.get("error") if state == "failed" else d.get("message")
        table.add_row(
            str(d.get("id"))[:12],
            Text(str(d.get("kind"))),
            Text(str(d.get("name") or "")),
            Text(state, style=STATE_STYLE.get(state, "")),
            f"{100 * float(d.get('progress') or 0):.0f}%",
            created,
            Text(" ".join(str(message or "").split())),
        )
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
    as_json: bool = JsonOpt,
) -> None:
    """List jobs on the server, newest first (ids shortened; any unique prefix is an id)."""
    with state_of(ctx).client() as client:
        docs, total = client.list_page(state=state, kind=kind, name=name, limit=limit)
    if as_json:
        print_json(docs)
        return
    if not docs:
        err_console.print("no jobs match", markup=False, highlight=False)
        return
    out_console().print(jobs_table(docs))
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
    from service.kind_docs import kind_document, nested_models, param_rows

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
    for model, about, rows in nested_models(k):  # what a param's type names by model name
        sub = Table(title=f"{model}: {about}" if about else model)
        for col in ("field", "type", "default"):
            sub.add_column(col, overflow="fold")
        sub.add_column("description", overflow="fold", ratio=1)
        for name, type_, default, desc in rows:
            sub.add_row(Text(name), Text(type_), Text(default), Text(desc))
        console.print(sub)


def register(app: typer.Typer) -> None:
    """Add ``ls`` and ``kinds`` to the app."""
    app.command("ls")(ls)
    app.command("kinds")(kinds)
