"""Following a job on the server with a Rich progress bar (``wait``, ``submit --wait``,
``batch``). Bars and messages go to stderr; stdout stays for results.

The bar shows the job's state and its one-line message (shortened while it runs), and an
ETA once a running job has reported progress: its run time so far times the share left.
When the job finishes, its final message is printed in full on a line of its own, so that
logs and ``status`` never show it cut.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Any

from rich.console import Console
from rich.progress import (
    BarColumn,
    Progress,
    TaskID,
    TaskProgressColumn,
    TextColumn,
    TimeElapsedColumn,
)
from rich.table import Column
from rich.text import Text

from service.cli.client import Client, ServerRefused, ServerUnreachable

log = logging.getLogger("matforge.cli")

FINAL_STATES = frozenset({"succeeded", "failed", "cancelled"})
#: Below this share done, an extrapolated ETA is noise and is not shown.
ETA_MIN_PROGRESS = 0.01


def make_progress(console: Console) -> Progress:
    """A progress display with a label, a bar, the percentage, the elapsed time, the ETA,
    the job's state and its one-line message. The label, percentage, times and state are
    never cut (a batch's step names up to 32 characters); the bar narrows to 10 characters
    and the message takes what is left, cut at its end."""

    def kept(min_width: int | None = None, max_width: int | None = None) -> Column:
        return Column(no_wrap=True, overflow="ignore", min_width=min_width, max_width=max_width)

    return Progress(
        TextColumn("[bold]{task.description}", table_column=kept(max_width=32)),
        BarColumn(bar_width=None, table_column=Column(min_width=10, max_width=30, ratio=1)),
        TaskProgressColumn(table_column=kept(min_width=4)),
        TimeElapsedColumn(table_column=kept(min_width=7)),
        TextColumn("[cyan]{task.fields[eta]}", table_column=kept()),
        TextColumn("{task.fields[state]}", table_column=kept(min_width=9)),
        TextColumn(
            "[dim]{task.fields[message]}",
            table_column=Column(ratio=2, no_wrap=True, overflow="ellipsis"),
        ),
        console=console,
        transient=False,
        expand=True,
    )


def add_job_task(progress: Progress, label: str, *, start: bool = True) -> TaskID:
    """A bar for one job (fields ``state``, ``message`` and ``eta`` empty)."""
    return progress.add_task(label, total=1.0, state="", message="", eta="", start=start)


def _short(text: Any, width: int = 60) -> str:
    s = " ".join(str(text or "").split())
    return s if len(s) <= width else s[: width - 1] + "…"


def format_eta(seconds: float) -> str:
    """``"ETA 0:03:12"``."""
    s = int(round(max(0.0, seconds)))
    return f"ETA {s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}"


def eta_of(doc: dict[str, Any]) -> str:
    """The ETA of a running job from its progress and run time so far, or ``""``."""
    fraction = float(doc.get("progress") or 0.0)
    run_s = (doc.get("timings") or {}).get("run_seconds")
    if doc.get("state") != "running" or not isinstance(run_s, int | float) or run_s < 1:
        return ""
    if not ETA_MIN_PROGRESS <= fraction < 1.0:
        return ""
    return format_eta(run_s * (1.0 - fraction) / fraction)


def show(progress: Progress, task: TaskID, doc: dict[str, Any]) -> None:
    """Put a job document on its bar; a finished job's full message goes on its own line."""
    state = str(doc.get("state", "?"))
    message = doc.get("error") if state == "failed" else doc.get("message")
    fraction = 1.0 if state == "succeeded" else float(doc.get("progress") or 0.0)
    short = _short(message)
    progress.update(task, completed=fraction, state=state, message=short, eta=eta_of(doc))
    full = " ".join(str(message or "").split())
    if state in FINAL_STATES and full and full != short:
        label = next((t.description for t in progress.tasks if t.id == task), "")
        line = Text(f"{label}: " if label else "", style="bold")
        line.append(full)
        progress.console.print(line, overflow="fold", soft_wrap=False)


@dataclass
class Poller:
    """Reads job documents, waiting out a server that answered once and then stopped
    answering for less than ``patience_seconds`` (a restart): :meth:`poll` returns
    ``None`` meanwhile. Past that, or when it never answered, :class:`ServerUnreachable`
    is raised; refused credentials are raised at once."""

    client: Client
    patience_seconds: float = 15.0
    _unreachable_since: float | None = None
    _contacted: bool = False

    def poll(self, job_id: str) -> dict[str, Any] | None:
        try:
            doc = self.client.get(job_id)
        except ServerUnreachable as exc:
            now = time.monotonic()
            self._unreachable_since = self._unreachable_since or now
            if (
                not self._contacted
                or now - self._unreachable_since > self.patience_seconds
                or isinstance(exc, ServerRefused)
            ):
                raise
            log.debug("server unreachable while following %s: %s", job_id, exc)
            return None
        self._unreachable_since, self._contacted = None, True
        return doc


def follow(
    client: Client,
    job_id: str,
    progress: Progress,
    task: TaskID,
    *,
    poll_seconds: float = 0.5,
    patience_seconds: float = 15.0,
) -> dict[str, Any]:
    """Poll a job until it is finished, updating ``task``; returns the final document
    (see :class:`Poller` for a server that stops answering)."""
    poller = Poller(client, patience_seconds)
    while True:
        doc = poller.poll(job_id)
        if doc is not None:
            show(progress, task, doc)
            if doc.get("state") in FINAL_STATES:
                return doc
        time.sleep(poll_seconds)


def wait_with_bar(
    client: Client,
    job_id: str,
    console: Console,
    label: str | None = None,
    poll_seconds: float = 0.5,
) -> dict[str, Any]:
    """Follow one job with its own progress bar on ``console``; returns the final document."""
    with make_progress(console) as progress:
        task = add_job_task(progress, label or job_id[:12])
        return follow(client, job_id, progress, task, poll_seconds=poll_seconds)
