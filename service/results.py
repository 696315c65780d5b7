"""The results table: every finished job's measured values as long-format rows.

``GET /api/results``, ``POST /api/results/batch`` and ``matforge results`` come through
here. Each job's rows come from its kind's rows hook (:attr:`jobapi.kinds.Kind.rows`); this
module knows no kind's fields. It reads the jobs from the queue and their JSON artifacts
from the store, filters the rows, and resolves a batch file's steps to the jobs that ran
them (the same canonical spec hash that resubmitting the step would find).
"""

from __future__ import annotations

import csv
import difflib
import io
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from jobapi import row_sources
from jobapi.errors import SpecError
from jobapi.kinds import declared_metrics
from jobapi.metric_names import matches, unknown_metric
from jobapi.row_sources import job_id_of_ref
from jobapi.rows import COLUMNS, ResultRow
from service import kinds
from service.specs import STEP_REF, validate_spec
from storage.artifacts import ArtifactStore
from storage.jobs import Job, JobStore

#: Jobs read at most when no job is named (the newest succeeded ones).
MAX_JOBS = 1000


def job_rows(job: Job, jobs: JobStore, store: ArtifactStore) -> list[ResultRow]:
    """Every value ``job`` measured (:func:`jobapi.row_sources.job_rows`), once the
    built-in kinds are registered."""
    kinds.load()
    return row_sources.job_rows(job, jobs, store)


@dataclass(frozen=True)
class RowFilter:
    """Which rows to keep; ``None`` (or empty) keeps all. ``dataset`` matches the row's
    dataset ref or the job id inside it; ``metric`` names row metrics or old names that
    stand for them (``smape``: ``brdf.smape``; ``mae``: ``brdf.mae`` and ``image.mae``,
    :mod:`jobapi.metric_names`)."""

    kind: str | None = None
    dataset: str | None = None
    metric: Sequence[str] = ()
    candidate: str | None = None
    scene: str | None = None

    def keep(self, row: ResultRow) -> bool:
        if self.kind and row.kind != self.kind:
            return False
        if self.metric and not matches(row.metric, self.metric):
            return False
        if self.candidate and row.candidate != self.candidate:
            return False
        if self.scene and row.scene != self.scene:
            return False
        if self.dataset:
            ds = row.dataset or ""
            if self.dataset not in (ds, job_id_of_ref(ds)):
                return False
        return True


def check_row_filter(where: RowFilter, names: Mapping[str, str] | None = None) -> RowFilter:
    """``where`` if its ``kind`` is a registered kind and each ``metric`` a metric some kind
    declares (or an old name of one); else :class:`SpecError` naming the option (``names``:
    ``{"kind": "--kind", "metric": "--metric"}``; default ``query.kind``, ``query.metric``)
    and the closest known values, so that a misspelt filter is never an empty answer."""
    at = {"kind": "query.kind", "metric": "query.metric", **(names or {})}
    errors: list[tuple[str, str]] = []
    if where.kind:
        known = sorted(kinds.all_kinds())
        if where.kind not in known:
            close = difflib.get_close_matches(where.kind, known, n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            errors.append((at["kind"], f"unknown kind {where.kind!r}{hint}"))
    else:
        kinds.load()
    for metric in where.metric:
        why = unknown_metric(metric, declared_metrics())
        if why is not None:
            errors.append((at["metric"], why))
    if errors:
        raise SpecError(errors)
    return where


def select_rows(
    jobs: JobStore,
    store: ArtifactStore,
    *,
    job_ids: Sequence[str] = (),
    where: RowFilter | None = None,
    max_jobs: int = MAX_JOBS,
) -> list[ResultRow]:
    """The rows of the named jobs (in the order given; ``NotFoundError`` for an unknown
    id), or of the newest ``max_jobs`` succeeded jobs (oldest first), filtered."""
    where = where or RowFilter()
    if job_ids:
        picked = [jobs.get(j) for j in job_ids]
    else:
        picked = jobs.list_jobs(state="succeeded", kind=where.kind, limit=max_jobs)[::-1]
        picked = [jobs.get(j.id) for j in picked]  # with artifacts
    return [r for job in picked for r in job_rows(job, jobs, store) if where.keep(r)]


# -- batches -----------------------------------------------------------------------------------
@dataclass
class BatchResults:
    """A batch's rows in step order (each row's ``step`` set) and what each step found:
    ``{"step", "kind", "job", "state"}`` with state ``succeeded`` or ``missing`` (no
    succeeded job of that spec: not run yet, failed, or a step it depends on is missing)."""

    rows: list[ResultRow] = field(default_factory=list)
    steps: list[dict[str, Any]] = field(default_factory=list)

    def document(self) -> dict[str, Any]:
        return {"steps": self.steps, "rows": [r.document() for r in self.rows]}


def _substitute(obj: Any, resolve: Callable[[str], str]) -> Any:
    if isinstance(obj, str):
        return resolve(obj) if STEP_REF.match(obj) else obj
    if isinstance(obj, dict):
        return {k: _substitute(v, resolve) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_substitute(v, resolve) for v in obj]
    return obj


class _Missing(Exception):
    """A step ref names a step without a job."""


def batch_rows(
    steps: Iterable[Mapping[str, Any]],
    jobs: JobStore,
    store: ArtifactStore,
    where: RowFilter | None = None,
    variant: str | None = None,
) -> BatchResults:
    """The results of a batch's steps (``[{"name", "spec"}]``, specs with ``step:`` refs,
    as :func:`service.cli.batch.load_batch` reads them), in step order, a step's candidates
    in the order its spec gives them (``variant``: the workers' Mitsuba variant, part of
    some specs' identity: :func:`service.specs.validate_spec`). A step's job is the
    succeeded job of its spec once its refs name the earlier steps' jobs. Raises
    ``SpecError`` for a spec that does not validate."""
    where = where or RowFilter()
    out = BatchResults()
    found: dict[str, str] = {}

    def resolve(ref: str) -> str:
        m = STEP_REF.match(ref)
        assert m is not None
        if m["step"] not in found:
            raise _Missing(m["step"])
        return f"job:{found[m['step']]}" + (f"/{m['name']}" if m["name"] else "")

    for i, step in enumerate(steps):
        name = str(step.get("name"))
        try:
            spec = validate_spec(_substitute(step.get("spec"), resolve), variant=variant)
        except _Missing:
            out.steps.append({"step": name, "kind": None, "job": None, "state": "missing"})
            continue
        except SpecError as exc:  # name the step: "steps.2.spec.params.spp: ..."
            at = f"steps.{i}.spec"
            raise SpecError(
                [(f"{at}.{loc}" if loc else at, msg) for loc, msg in exc.errors]
            ) from None
        job = jobs.succeeded_with_hash(spec.spec_hash)
        out.steps.append({"step": name, "kind": spec.kind, "job": job.id if job else None,
                          "state": "succeeded" if job else "missing"})  # fmt: skip
        if job is None:
            continue
        found[name] = job.id
        rows = [r.with_(step=name) for r in job_rows(job, jobs, store) if where.keep(r)]
        out.rows += in_given_order(rows, step.get("spec"))
    return out


def in_given_order(rows: list[ResultRow], spec: Any) -> list[ResultRow]:
    """``rows`` with the candidates in the order the step's spec lists them (its params'
    ``candidates`` mapping), not the stored, canonical (sorted) one; stable otherwise."""
    params = spec.get("params") if isinstance(spec, Mapping) else None
    cands = params.get("candidates") if isinstance(params, Mapping) else None
    if not isinstance(cands, Mapping):
        return rows
    rank = {str(c): i for i, c in enumerate(cands)}
    return sorted(rows, key=lambda r: rank.get(r.candidate or "", len(rank)))


# -- formats -----------------------------------------------------------------------------------
def rows_csv(rows: Iterable[ResultRow]) -> str:
    """The rows as CSV text, a header of :data:`jobapi.rows.COLUMNS` first."""
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(COLUMNS), lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow(row.csv_cells())
    return buf.getvalue()
