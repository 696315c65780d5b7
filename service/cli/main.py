"""``matforge``: the command-line interface (Typer).

Commands follow the contract: ``serve``, ``run``, ``submit``, ``status``, ``wait``,
``cancel``, ``artifacts``, ``fetch``, ``import``, ``batch`` and ``store verify|gc``; and
``ls`` and ``kinds``. Wherever a job id is expected, any unique prefix of it works.

Exit codes: 0 success, 1 a job failed (or was cancelled), 2 bad input or usage, 3 server
unreachable or refused. ``--json`` prints exactly one JSON document on stdout; progress bars,
logs and errors go to stderr. Tracebacks are logged at debug level (``-v`` shows them).
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import typer

from service.cli.state import (
    EXIT_BAD_INPUT,
    EXIT_JOB_FAILED,
    CliState,
    err_console,
    error,
    exit_code_for,
    out_console,
    print_json,
    print_line,
    setup_logging,
    state_of,
    table_console,
)
from service.settings import Settings

app = typer.Typer(
    name="matforge",
    help="matforge: dataset generation and evaluation jobs for real-time material models.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    context_settings={"help_option_names": ["-h", "--help"]},
)

JsonOpt = typer.Option(False, "--json", help="Print one JSON document on stdout.")
DataDirOpt = typer.Option(
    None,
    "--data-dir",
    help="Data directory (default: MATFORGE_DATA or ./matforge-data).",
    show_default=False,
)


def _print_version(value: bool) -> None:
    """``--version``: the one version (:mod:`jobapi.version`, also ``matforge.__version__``)."""
    if value:
        from jobapi.version import __version__

        print_line(f"matforge {__version__}")
        raise typer.Exit(0)


@app.callback()
def _global(
    ctx: typer.Context,
    server: str | None = typer.Option(
        None,
        "--server",
        show_default=False,
        help="Server URL (default: MATFORGE_SERVER or http://127.0.0.1:8000).",
    ),
    data_dir: Path | None = typer.Option(
        None,
        "--data-dir",
        show_default=False,
        help="Data directory; for artifacts, fetch and import it means: use this local store.",
    ),
    verbose: bool = typer.Option(
        False, "--verbose", "-v", help="Debug logs (and tracebacks) on stderr."
    ),
    version: bool = typer.Option(
        False,
        "--version",
        is_eager=True,
        callback=_print_version,
        help="Print matforge's version and exit.",
    ),
) -> None:
    """Global options. The token comes from MATFORGE_TOKEN."""
    setup_logging(verbose)
    settings = Settings.from_env()
    if server:
        settings = settings.with_(server=server.rstrip("/"))
    if data_dir is not None:
        settings = settings.with_(data_dir=data_dir)
    ctx.obj = CliState(settings=settings, data_dir_given=data_dir)


def load_spec(source: str) -> Any:
    """A spec document from a JSON/YAML file, or from stdin when ``source`` is ``-``."""
    from service.specs import load_spec_file, parse_spec_text

    if source == "-":
        return parse_spec_text(sys.stdin.read(), "<stdin>")
    return load_spec_file(source)


def _summary(doc: dict[str, Any]) -> None:
    """A human summary of a job document on stdout."""
    from rich.table import Table
    from rich.text import Text

    console = out_console()
    grid = Table.grid(padding=(0, 2))
    grid.add_column(style="bold")
    grid.add_column(overflow="fold")
    timings = doc.get("timings") or {}
    run_s = timings.get("run_seconds")
    rows = [
        ("id", doc.get("id")),
        ("kind", doc.get("kind")),
        ("name", doc.get("name")),
        ("state", doc.get("state")),
        ("progress", f"{100 * float(doc.get('progress') or 0):.0f}%"),
        ("message", doc.get("message")),
        ("error", doc.get("error")),
        ("worker", doc.get("worker")),
        ("attempts", doc.get("attempts")),
        ("created", doc.get("created_at")),
        ("finished", doc.get("finished_at")),
        ("run time", None if run_s is None else f"{run_s:.2f} s"),
    ]
    for key, value in rows:
        if value not in (None, ""):
            grid.add_row(key, Text(str(value)))
    console.print(grid)
    arts = doc.get("artifacts") or []
    if arts:
        from service.cli.artifacts import artifacts_table

        console.print(artifacts_table(arts))


def _finish(doc: dict[str, Any], as_json: bool, *, line: str | None = None) -> int:
    """Print a finished job (JSON, or ``line`` on stdout and its error on stderr) and return
    the exit code: 0 if it succeeded, 1 otherwise."""
    if as_json:
        print_json(doc)
    elif line is not None:
        print_line(line)
    state = doc.get("state")
    if state == "succeeded":
        return 0
    if doc.get("error"):
        error(f"job {doc.get('id')} {state}: {doc['error']}")
    else:
        error(f"job {doc.get('id')} {state}")
    return EXIT_JOB_FAILED


@app.command()
def serve(
    ctx: typer.Context,
    host: str = typer.Option("127.0.0.1", "--host", help="Address to listen on."),
    port: int = typer.Option(8000, "--port", min=0, max=65535, help="Port to listen on."),
    data_dir: Path | None = DataDirOpt,
    workers: int | None = typer.Option(
        None,
        "--workers",
        min=0,
        show_default=False,
        help="Worker processes (default: MATFORGE_WORKERS or 1).",
    ),
    http_workers: int = typer.Option(
        1,
        "--http-workers",
        min=1,
        envvar="MATFORGE_HTTP_WORKERS",
        help="Web processes sharing the port (MATFORGE_HTTP_WORKERS).",
    ),
) -> None:
    """Serve the REST API, the dashboard and N workers (blocks until stopped)."""
    from service.server import serve as run_server

    setup_logging(ctx.find_root().params.get("verbose", False), server=True)
    settings = state_of(ctx).settings_for(data_dir)
    run_server(
        settings,
        host=host,
        port=port,
        workers=settings.workers if workers is None else workers,
        http_workers=http_workers,
    )


@app.command()
def run(
    ctx: typer.Context,
    spec: str = typer.Argument(..., help="Spec file (JSON or YAML), or - for stdin."),
    data_dir: Path | None = DataDirOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Run one job in this process (no server); prints its id, or the job document."""
    from service.submission import run_in_process

    raw = load_spec(spec)
    settings = state_of(ctx).settings_for(data_dir)
    # run_in_process makes each job's work directory inside <data>/scratch, which a fresh
    # data directory does not have yet (``serve`` creates it for its workers).
    (settings.data_dir / "scratch").mkdir(parents=True, exist_ok=True)
    kind = raw.get("kind") if isinstance(raw, dict) else None
    with err_console.status(f"running {kind or 'job'} in process"):
        job = run_in_process(raw, settings)
    doc = job.document()
    if not as_json and job.state == "succeeded":
        run_s = (doc.get("timings") or {}).get("run_seconds")
        err_console.print(
            f"job {job.id} succeeded"
            + (f" in {run_s:.2f} s" if run_s else "")
            + f", {len(job.artifacts)} artifact(s) in {settings.store_dir}",
            markup=False,
            highlight=False,
        )
    raise typer.Exit(_finish(doc, as_json, line=job.id))


@app.command()
def submit(
    ctx: typer.Context,
    spec: str = typer.Argument(..., help="Spec file (JSON or YAML), or - for stdin."),
    wait: bool = typer.Option(False, "--wait", help="Wait for the job with a progress bar."),
    as_json: bool = JsonOpt,
) -> None:
    """Queue a job on the server; prints its id (or, with --json, the job document)."""
    from service.cli.follow import wait_with_bar
    from service.cli.resubmit import reuse_notices

    raw = load_spec(spec)
    with state_of(ctx).client() as client:
        doc, created = client.submit_created(raw)
        for line in reuse_notices(raw, doc, created):
            err_console.print(line, markup=False, highlight=False)
        if not wait:
            if as_json:
                print_json(doc)
            else:
                print_line(str(doc["id"]))
            return
        if created:
            err_console.print(f"submitted {doc['id']}", markup=False, highlight=False)
        doc = wait_with_bar(client, str(doc["id"]), err_console, label=str(doc.get("kind")))
    raise typer.Exit(_finish(doc, as_json, line=str(doc["id"])))


@app.command()
def status(
    ctx: typer.Context,
    job_id: str = typer.Argument(..., metavar="ID", help="Job id, or a unique prefix of it."),
    as_json: bool = JsonOpt,
) -> None:
    """Show a job: state, progress, message, error, worker, attempts, artifacts, and the
    result table of a finished job whose kind makes one (a score job's metrics)."""
    with state_of(ctx).client() as client:
        doc = client.get(job_id)
        table = client.summary(str(doc["id"])) if doc.get("state") == "succeeded" else None
    if as_json:
        print_json(doc)
        return
    _summary(doc)
    if table:
        from jobapi.results import ResultTable
        from service.cli.results import result_table_views

        console = out_console()
        result = ResultTable.from_document(table)
        for view in result_table_views(result, result.title.lower(), console.width):
            console.print(view)


@app.command()
def wait(
    ctx: typer.Context,
    job_id: str = typer.Argument(..., metavar="ID", help="Job id, or a unique prefix of it."),
    as_json: bool = JsonOpt,
    poll: float = typer.Option(0.5, "--poll", min=0.05, help="Seconds between polls."),
) -> None:
    """Wait for a job with a progress bar; exit 0 if it succeeded, 1 if not."""
    from service.cli.follow import wait_with_bar

    with state_of(ctx).client() as client:
        doc = wait_with_bar(client, job_id, err_console, poll_seconds=poll)
    raise typer.Exit(_finish(doc, as_json, line=f"{doc.get('id')} {doc.get('state')}"))


@app.command()
def cancel(
    ctx: typer.Context,
    job_id: str = typer.Argument(..., metavar="ID", help="Job id, or a unique prefix of it."),
    as_json: bool = JsonOpt,
) -> None:
    """Cancel a queued or running job (a finished job stays as it is)."""
    with state_of(ctx).client() as client:
        doc = client.cancel(job_id)
    if as_json:
        print_json(doc)
    else:
        print_line(f"{doc.get('id')} {doc.get('state')}")


@app.command()
def logs(
    ctx: typer.Context,
    job_id: str = typer.Argument(..., metavar="ID", help="Job id, or a unique prefix of it."),
    tail: int | None = typer.Option(
        None, "--tail", "-n", min=0, help="Only the last N lines.", show_default=False
    ),
    data_dir: Path | None = typer.Option(
        None,
        "--data-dir",
        show_default=False,
        help="Read the log from this local data directory, not the server.",
    ),
) -> None:
    """Print a job's log: each attempt's start and end, its progress lines and the worker's
    log records while it ran (empty before a worker started it)."""
    local = state_of(ctx).local_dir(data_dir)
    if local is not None:
        from service.cli.artifacts import open_local
        from storage.job_logs import JobLog, log_dir
        from storage.job_queries import resolve_job_id

        jobs, _ = open_local(local)
        text = JobLog(log_dir(local), resolve_job_id(jobs, job_id)).read(tail)
    else:
        with state_of(ctx).client() as client:
            text = client.logs(job_id, tail)
    sys.stdout.write(text)


@app.command()
def batch(
    ctx: typer.Context,
    file: Path = typer.Argument(..., help="Batch file (YAML or JSON) of named steps."),
    out: Path | None = typer.Option(
        None, "--out", "-o", help="Also write the results table to this .csv or .json file."
    ),
    as_json: bool = typer.Option(
        False,
        "--json",
        help="Print the result rows as one JSON document on stdout (the table goes to stderr).",
    ),
    poll: float = typer.Option(0.5, "--poll", min=0.05, help="Seconds between polls."),
    parallel: int = typer.Option(
        1,
        "--parallel",
        "-j",
        min=1,
        max=64,
        help="Run up to N steps at once (a step still waits for the steps it refers to).",
    ),
    continue_on_error: bool = typer.Option(
        False,
        "--continue-on-error",
        help="After a step fails, skip only the steps that need it and run the rest.",
    ),
    tables: bool = typer.Option(
        False,
        "--verbose",
        "-v",
        help="Also print each step's whole result table (by default one summary line a step).",
    ),
    var: list[str] = typer.Option(
        [],
        "--var",
        help="NAME=VALUE for a variable of the batch's vars (its specs' 'var:NAME' strings), "
        "e.g. --var model=sha256:...; repeatable.",
    ),
) -> None:
    """Run a batch of steps on the server, in order; later steps may use step: refs.

    Prints one line per step (its state, time and headline result); ``-v`` adds each step's
    result table. ``--out`` writes the batch's result rows, one per measured value, as
    ``matforge results FILE`` does; ``--json`` prints the steps (job ids, states, metrics).
    """
    from service.cli.batch import load_batch, parse_vars
    from service.cli.batch_run import run_batch
    from service.cli.results import metrics_tables, result_rows, results_table
    from service.cli.results_command import write_rows

    if out is not None and out.suffix.lower() not in (".csv", ".json"):
        error(f"--out {out}: must end in .csv or .json")
        raise typer.Exit(EXIT_BAD_INPUT)
    plan = load_batch(file, variables=parse_vars(var))
    with state_of(ctx).client() as client:
        outcome = run_batch(
            plan,
            client,
            err_console,
            poll_seconds=poll,
            parallel=parallel,
            continue_on_error=continue_on_error,
        )
        if out is not None:
            steps = [{"name": s.name, "spec": s.spec} for s in plan.steps]
            write_rows(out, list(client.batch_results(steps, {}).get("rows") or []))
    columns, rows = result_rows(outcome.results)
    console = table_console(to_stderr=as_json)
    table = results_table(
        columns, rows, title=f"batch {file}", results=outcome.results, width=console.width
    )
    console.print(table)
    if tables:
        for metrics_table in metrics_tables(outcome.results, console.width):
            console.print(metrics_table)
    if as_json:
        print_json(rows)
    for r in outcome.results:
        if r.state not in ("succeeded", "skipped"):
            error(f"step {r.step!r} {r.state}: {r.error or ''}".rstrip(": "))
    if out is not None:
        err_console.print(f"results written to {out}", markup=False, highlight=False)
    raise typer.Exit(outcome.exit_code)


def _register_subcommands() -> None:
    from service.cli import artifacts as cli_artifacts
    from service.cli import listing as cli_listing
    from service.cli import results_command as cli_results
    from service.cli import store as cli_store

    cli_artifacts.register(app)
    cli_listing.register(app)
    cli_results.register(app)
    app.add_typer(cli_store.store_app, name="store")


_register_subcommands()


def main(argv: list[str] | None = None) -> None:
    """Console-script entry point: run the app and map errors to exit codes (never a
    traceback for the user)."""
    try:
        app(args=argv, prog_name="matforge")
    except SystemExit:
        raise
    except KeyboardInterrupt:
        error("interrupted")
        raise SystemExit(130) from None
    except Exception as exc:
        code, message = exit_code_for(exc)
        error(message)
        raise SystemExit(code) from None


if __name__ == "__main__":
    main()
