"""Run a batch's steps in this process, in order, without a server.

The benchmarks that reproduce a recipe's figures and the integration tests that run a
recipe at tiny sizes both need what ``matforge batch`` does (each step's ``step:`` refs
resolved to the jobs of the steps before it) but in-process, through
:func:`service.submission.run_in_process`, so that a step whose spec already ran in the data
directory is reused and a recipe resumes. Steps run one after another; the first that does
not succeed stops the run with :class:`StepFailed`.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from typing import Any

from service.cli.batch import Step, substitute_refs
from service.settings import Settings
from service.specs import STEP_REF
from service.submission import run_in_process
from storage.jobs import Job

#: ``transform(spec) -> spec``: e.g. shrink a recipe's costly params for a test.
Transform = Callable[[dict[str, Any]], dict[str, Any]]
#: ``on_step(step, job, seconds)``: called after each step that succeeded.
OnStep = Callable[[Step, Job, float], None]


class StepFailed(RuntimeError):
    """A step's job did not succeed; names the step, its state and the job's error."""

    def __init__(self, step: Step, job: Job) -> None:
        super().__init__(f"step {step.name} {job.state}: {job.error}")
        self.step, self.job = step, job


def run_steps_in_process(
    steps: Iterable[Step],
    settings: Settings,
    *,
    transform: Transform | None = None,
    on_step: OnStep | None = None,
) -> dict[str, Job]:
    """Run ``steps`` in order in this process over ``settings.data_dir``; returns each step's
    job by step name. ``step:NAME`` and ``step:NAME/ARTIFACT`` refs become ``job:`` refs of
    the earlier steps' jobs (a ref to a step not run here raises ``KeyError``)."""
    jobs: dict[str, Job] = {}

    def resolve(ref: str) -> str:
        m = STEP_REF.match(ref)
        if m is None or m["step"] not in jobs:
            raise KeyError(f"{ref}: no earlier step of that name ran here")
        job_id = jobs[m["step"]].id
        return f"job:{job_id}" if m["name"] is None else f"job:{job_id}/{m['name']}"

    for step in steps:
        spec: dict[str, Any] = substitute_refs(step.spec, resolve)
        if transform is not None:
            spec = transform(spec)
        started = time.perf_counter()
        job = run_in_process(spec, settings)
        if job.state != "succeeded":
            raise StepFailed(step, job)
        jobs[step.name] = job
        if on_step is not None:
            on_step(step, job, time.perf_counter() - started)
    return jobs
