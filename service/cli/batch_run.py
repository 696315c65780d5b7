"""Running a validated batch on a server: each step's ``step:`` refs resolved once the
steps they name have finished, a progress bar per step, and the result tables read back.

Steps run in file order. With ``parallel`` N > 1, up to N steps whose refs are satisfied
run at once (a step waits for every step it refers to). After a step fails, no new step
starts, unless ``continue_on_error``: then only the steps that depend on it, directly or
through others, are skipped, and the rest of the batch runs.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.progress import Progress, TaskID

from jobapi.results import ResultTable
from service.cli.batch import Batch, BatchOutcome, Step, StepResult, substitute_refs
from service.cli.client import BadInput, Client, ClientError, ServerUnreachable
from service.cli.follow import FINAL_STATES, Poller, add_job_task, make_progress, show
from service.cli.resubmit import reuse_notices
from service.specs import STEP_REF

log = logging.getLogger("matforge.batch")


def _resolve(step: Step, results: dict[str, StepResult]) -> dict[str, Any]:
    def resolve(ref: str) -> str:
        m = STEP_REF.match(ref)
        assert m is not None
        prior = results[m["step"]]
        if m["name"] is None:
            return f"job:{prior.job_id}"
        names = [a.get("name") for a in prior.artifacts]
        if m["name"] not in names:
            have = ", ".join(str(n) for n in names) or "none"
            raise BadInput(
                f"step {step.name!r}: {ref}: step {m['step']!r} (job "
                f"{prior.job_id}) has no artifact {m['name']!r}; it has: {have}"
            )
        return f"job:{prior.job_id}/{m['name']}"

    resolved: dict[str, Any] = substitute_refs(step.spec, resolve)
    return resolved


def _summary(client: Client, result: StepResult) -> None:
    """The step's result table (its kind's summary hook, through the REST API) and its
    numeric cells as ``<label>.<column>`` metrics."""
    assert result.job_id is not None
    try:
        doc = client.summary(result.job_id)
        if doc is not None:
            result.table = ResultTable.from_document(doc)
            result.metrics = result.table.flat()
    except (ClientError, ValueError) as exc:
        log.warning("step %s: cannot read its result table: %s", result.step, exc)


@dataclass
class _Run:
    """The scheduler's state for one batch."""

    batch: Batch
    client: Client
    progress: Progress
    tasks: list[TaskID]
    outcome: BatchOutcome
    parallel: int
    continue_on_error: bool
    label: str
    stopped: bool = False

    def result(self, i: int) -> StepResult:
        return self.outcome.results[i]

    def by_name(self) -> dict[str, StepResult]:
        return {r.step: r for r in self.outcome.results}

    def fail(self, i: int, state: str, error: str | None, code: int) -> None:
        r = self.result(i)
        r.state, r.error = state, error
        if self.outcome.exit_code == 0:
            self.outcome.exit_code = code
        if not self.continue_on_error or code == ServerUnreachable.exit_code:
            self.stopped = True

    def blocked_by(self, step: Step) -> tuple[str | None, bool]:
        """``(a failed step it needs, whether all it needs succeeded)``."""
        results = self.by_name()
        for ref in step.refs:
            dep = results[ref.step]
            if dep.state in ("failed", "cancelled", "error") or dep.error is not None:
                return ref.step, False
        return None, all(results[ref.step].state == "succeeded" for ref in step.refs)

    def start(self, i: int) -> str | None:
        """Submit step ``i``; returns its job id, or ``None`` when it did not start."""
        step, task = self.batch.steps[i], self.tasks[i]
        self.progress.start_task(task)  # the elapsed time counts from here
        try:
            spec = _resolve(step, self.by_name())
            spec.setdefault("batch", self.label)
            spec.setdefault("name", step.name)  # two renders of a batch: not both "render"
            doc, created = self.client.submit_created(spec)
        except ClientError as exc:
            self.fail(i, "error", str(exc), exc.exit_code)
            self.progress.update(task, state="error", message=str(exc)[:60])
            return None
        job_id = str(doc["id"])
        self.result(i).job_id = job_id
        for line in reuse_notices(spec, doc, created):
            self.progress.console.print(f"{step.name}: {line}", markup=False, highlight=False)
        self.progress.update(task, state=str(doc.get("state", "queued")), message=job_id[:12])
        return job_id

    def finish(self, i: int, doc: dict[str, Any]) -> None:
        r = self.result(i)
        r.state = str(doc.get("state"))
        r.error = doc.get("error")
        r.seconds = (doc.get("timings") or {}).get("run_seconds")
        r.artifacts = list(doc.get("artifacts") or [])
        if r.state == "succeeded":
            _summary(self.client, r)
        else:
            self.fail(i, r.state, r.error, 1)

    def ready(self, pending: list[int]) -> list[int]:
        """Steps of ``pending`` that can start now, in order; marks as skipped (and drops
        from ``pending``) those that need a failed step."""
        out = []
        for i in list(pending):
            failed, ok = self.blocked_by(self.batch.steps[i])
            if failed is not None:
                pending.remove(i)
                self.result(i).error = f"skipped: it needs step {failed!r}, which did not succeed"
                self.progress.update(self.tasks[i], state="skipped", message=f"needs {failed}")
            elif ok:
                out.append(i)
        return out


def run_batch(
    batch: Batch,
    client: Client,
    console: Console,
    *,
    poll_seconds: float = 0.5,
    parallel: int = 1,
    continue_on_error: bool = False,
    label: str | None = None,
) -> BatchOutcome:
    """Run the steps with a progress bar each (see the module docstring for ``parallel``
    and ``continue_on_error``); steps that never started stay ``skipped``.

    Each new job gets the batch run's ``label`` (default: the file's name and the UTC
    time) as its spec's ``batch``, unless its spec sets one: the dashboard groups by it.
    """
    if label is None:
        label = f"{Path(batch.source).name} {time.strftime('%Y-%m-%d %H:%M:%S', time.gmtime())}"
    outcome = BatchOutcome([StepResult(step=s.name, kind=s.kind) for s in batch.steps])
    with make_progress(console) as progress:
        tasks = [add_job_task(progress, f"{s.name} ({s.kind})", start=False) for s in batch.steps]
        for task in tasks:
            progress.update(task, state="pending")
        run = _Run(
            batch, client, progress, tasks, outcome, max(1, parallel), continue_on_error, label
        )
        poller = Poller(client)
        pending = list(range(len(batch.steps)))
        running: dict[int, str] = {}
        while True:
            if not run.stopped:
                for i in run.ready(pending):
                    if len(running) >= run.parallel or run.stopped:
                        break
                    pending.remove(i)
                    job_id = run.start(i)
                    if job_id is not None:
                        running[i] = job_id
            if not running:
                if run.stopped or not pending or not run.ready(pending):
                    break
                continue
            time.sleep(poll_seconds)
            for i, job_id in list(running.items()):
                try:
                    doc = poller.poll(job_id)
                except ClientError as exc:
                    run.fail(i, "error", str(exc), exc.exit_code)
                    progress.update(tasks[i], state="error", message=str(exc)[:60])
                    del running[i]
                    continue
                if doc is None:
                    continue
                show(progress, tasks[i], doc)
                if doc.get("state") in FINAL_STATES:
                    del running[i]
                    run.finish(i, doc)
        for result, task in zip(outcome.results, tasks, strict=True):
            if result.state == "skipped" and result.error is None:
                progress.update(task, state="skipped", message="")
    return outcome
