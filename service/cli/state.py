"""What every CLI command shares: the resolved settings, the two consoles, JSON output, and
the mapping of errors to the contract's exit codes (0 ok, 1 job failed, 2 bad input or
usage, 3 server unreachable or refused)."""

from __future__ import annotations

import json
import logging
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import typer
from rich.console import Console

from service.cli.client import Client, ClientError
from service.settings import Settings

log = logging.getLogger("matforge.cli")

EXIT_OK, EXIT_JOB_FAILED, EXIT_BAD_INPUT, EXIT_UNREACHABLE = 0, 1, 2, 3


@dataclass
class CliState:
    """The global options, resolved once per invocation.

    ``settings`` come from the environment (:meth:`Settings.from_env`) with ``--server``
    and ``--data-dir`` applied; ``data_dir_given`` is the global ``--data-dir`` when it was
    given, which makes ``artifacts``, ``fetch`` and ``import`` use a local store.
    """

    settings: Settings
    data_dir_given: Path | None = None

    def client(self) -> Client:
        """A client of the configured server (with ``MATFORGE_TOKEN`` when set)."""
        return Client(self.settings.server, self.settings.token)

    def local_dir(self, option: Path | None) -> Path | None:
        """The explicit data directory of a command (its own ``--data-dir``, else the global
        one), or ``None`` to talk to the server."""
        return option if option is not None else self.data_dir_given

    def settings_for(self, data_dir: Path | None) -> Settings:
        """The settings with a command's ``--data-dir`` applied."""
        d = self.local_dir(data_dir)
        return self.settings if d is None else self.settings.with_(data_dir=d)


def state_of(ctx: typer.Context) -> CliState:
    """The :class:`CliState` the global callback stored on the context."""
    obj = ctx.find_root().obj
    if not isinstance(obj, CliState):  # a command invoked without the callback (tests)
        obj = CliState(Settings.from_env())
        ctx.find_root().obj = obj
    return obj


#: Width of text written to a pipe or file (``matforge kinds | less``): plain, narrow
#: lines. Tables of many value columns are split to fit it (:mod:`service.cli.tables`);
#: ``--json`` and ``--out`` give everything, unformatted.
PIPE_WIDTH = 100


def _width(stream: Any, piped: int) -> int | None:
    """A console's width: the terminal's (Rich measures it) on a terminal or when the user
    set ``COLUMNS`` (the terminal convention, which Rich reads), else ``piped``."""
    if stream.isatty() or os.environ.get("COLUMNS", "").isdigit():
        return None
    return piped


#: Progress bars, logs and error messages (120 columns when stderr is not a terminal).
err_console = Console(stderr=True, width=_width(sys.stderr, 120))


def out_console() -> Console:
    """A console on stdout (created per call so that tests capturing stdout see it)."""
    return Console(file=sys.stdout, width=_width(sys.stdout, PIPE_WIDTH))


def table_console(to_stderr: bool) -> Console:
    """A console for a results table, on stderr or stdout (:data:`PIPE_WIDTH` when piped)."""
    if not to_stderr:
        return out_console()
    return Console(stderr=True, width=_width(sys.stderr, PIPE_WIDTH))


def print_json(doc: Any) -> None:
    """Print exactly one JSON document on stdout."""
    sys.stdout.write(json.dumps(doc, indent=2, sort_keys=False, default=str) + "\n")
    sys.stdout.flush()


def print_line(text: str) -> None:
    """Print one plain line on stdout (ids, refs, paths: easy to capture in scripts)."""
    sys.stdout.write(text + "\n")
    sys.stdout.flush()


def error(text: str) -> None:
    """Print an error message (one line per line of ``text``) on stderr."""
    for line in str(text).splitlines() or [""]:
        sys.stderr.write(f"error: {line}\n")
    sys.stderr.flush()


class _Formatter(logging.Formatter):
    """Log lines without tracebacks unless verbose: users never see a traceback."""

    def __init__(self, verbose: bool, fmt: str) -> None:
        super().__init__(fmt)
        self.verbose = verbose

    def format(self, record: logging.LogRecord) -> str:
        if self.verbose:
            return super().format(record)
        saved = record.exc_info, record.exc_text, record.stack_info
        record.exc_info, record.exc_text, record.stack_info = None, None, None
        try:
            return super().format(record)
        finally:
            record.exc_info, record.exc_text, record.stack_info = saved


def setup_logging(verbose: bool, *, server: bool = False) -> None:
    """Logs go to stderr: warnings by default, everything (tracebacks too) with ``-v``.

    ``server``: the operator's log of ``matforge serve``: level info, timestamps, and
    tracebacks (they are for whoever runs the service, not for API users).
    """
    handler = logging.StreamHandler(sys.stderr)
    if server:
        handler.setFormatter(_Formatter(True, "%(asctime)s %(levelname)s %(name)s: %(message)s"))
    else:
        handler.setFormatter(_Formatter(verbose, "%(levelname)s %(name)s: %(message)s"))
    root = logging.getLogger()
    for h in list(root.handlers):
        if getattr(h, "_matforge_cli", False):
            root.removeHandler(h)
    handler._matforge_cli = True  # type: ignore[attr-defined]
    root.addHandler(handler)
    root.setLevel(logging.DEBUG if verbose else logging.INFO if server else logging.WARNING)


def exit_code_for(exc: BaseException) -> tuple[int, str]:
    """The exit code and the message for an exception that reached the top of a command."""
    from jobapi.errors import BackendUnavailable, ExecutorUnavailable, SpecError
    from service.cli.batch import BatchError
    from storage.errors import IntegrityError, StorageError

    if isinstance(exc, ClientError):
        return exc.exit_code, str(exc)
    if isinstance(exc, ExecutorUnavailable):  # MATFORGE_EXECUTOR=ray, no cluster there
        return EXIT_UNREACHABLE, str(exc)
    if isinstance(exc, BackendUnavailable):  # MATFORGE_VARIANT=cuda_ad_rgb, no CUDA here
        return EXIT_BAD_INPUT, str(exc)
    if isinstance(exc, BatchError | SpecError):
        return EXIT_BAD_INPUT, str(exc)
    if isinstance(exc, IntegrityError):
        return EXIT_JOB_FAILED, str(exc)
    if isinstance(exc, StorageError):  # FormatError, NotFoundError, TooLargeError
        return EXIT_BAD_INPUT, str(exc)
    if isinstance(exc, OSError) and exc.filename is not None:
        return EXIT_BAD_INPUT, f"{exc.filename}: {exc.strerror or exc}"
    if isinstance(exc, ValueError):
        return EXIT_BAD_INPUT, str(exc)
    log.debug("internal error", exc_info=exc)
    return EXIT_JOB_FAILED, (
        f"internal error: {type(exc).__name__}: {exc} (run with -v for the traceback)"
    )
