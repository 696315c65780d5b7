"""Following a job on the server with a Rich progress bar (``wait``, ``submit --wait``,
``batch``). Bars and messages go to stderr; stdout stays for results."""

from __future__ import annotations

import logging
import time
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

from service.cli.client import Client, ServerRefused, ServerUnreachable

log = logging.getLogger("matforge.cli")

FINAL_STATES = frozenset({"succeeded", "failed", "cancelled"})


def make_progress(console: Console) -> Progress:
    """A progress display with a label, a bar, the percentage, the elapsed time, the job's
    state and its one-line message."""
    return Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        TaskProgressColumn(),
        TimeElapsedColumn(),
        TextColumn("{task.fields[state]}"),
        TextColumn("[dim]{task.fields[message]}"),
        console=console,
        transient=False,
    )


def _short(text: Any, width: int = 60) -> str:
    s = " ".join(str(text or "").split())
    return s if len(s) <= width else s[: width - 1] + "…"


def follow(
    client: Client,
    job_id: str,
    progress: Progress,
    task: TaskID,
    *,
    poll_seconds: float = 0.5,
    patience_seconds: float = 15.0,
) -> dict[str, Any]:
    """Poll a job until it is finished, updating ``task``; returns the final document.

    A server that answered once and then stops answering for less than
    ``patience_seconds`` (a restart) is waited out; past that, or when it never answered,
    :class:`ServerUnreachable` is raised.
    """
    unreachable_since: float | None = None
    contacted = False
    while True:
        try:
            doc = client.get(job_id)
            unreachable_since, contacted = None, True
        except ServerUnreachable as exc:
            now = time.monotonic()
            unreachable_since = unreachable_since or now
            if (
                not contacted
                or now - unreachable_since > patience_seconds
                or isinstance(exc, ServerRefused)
            ):
                raise
            log.debug("server unreachable while following %s: %s", job_id, exc)
            time.sleep(poll_seconds)
            continue
        state = str(doc.get("state", "?"))
        message = doc.get("error") if state == "failed" else doc.get("message")
        fraction = float(doc.get("progress") or 0.0)
        if state == "succeeded":
            fraction = 1.0
        progress.update(task, completed=fraction, state=state, message=_short(message))
        if state in FINAL_STATES:
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
        task = progress.add_task(label or job_id[:12], total=1.0, state="", message="")
        return follow(client, job_id, progress, task, poll_seconds=poll_seconds)
