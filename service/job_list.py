"""The query of ``GET /api/jobs`` (and the dashboard's list): filters, sort and paging.

Unknown filter values are refused with a 422 that names the filter (``?kind=scor`` used to
return an empty list, which reads as "no such jobs" rather than "no such kind").
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass
from typing import Annotated

from fastapi import Depends, Query
from pydantic import WithJsonSchema

from jobapi.errors import SpecError
from service import kinds
from service.job_columns import FILTER_PATTERN, JobFilter, parse_filters, parse_keys
from service.schemas import JobState
from storage.job_queries import JOB_SORTS

#: SQLite's largest integer: a larger offset cannot be bound (it was a 500).
MAX_OFFSET = 2**63 - 1


@dataclass(frozen=True)
class JobListQuery:
    """Validated list options; ``sort`` is a key of :data:`storage.job_queries.JOB_SORTS`."""

    state: str | None = None
    kind: str | None = None
    name: str | None = None
    batch: str | None = None
    sort: str = "-created"
    limit: int = 200
    offset: int = 0
    columns: tuple[str, ...] = ()
    filters: tuple[JobFilter, ...] = ()
    tag: str | None = None


#: One ``filter``: its rule in the OpenAPI document (:data:`FILTER_PATTERN`), checked by
#: :func:`parse_filters`, whose refusal names it (a schema-valid filter is never a 422).
FilterText = Annotated[str, WithJsonSchema({"type": "string", "pattern": FILTER_PATTERN})]


def _unknown(filter_name: str, value: str, known: list[str]) -> SpecError:
    close = difflib.get_close_matches(value, known, n=1)
    hint = f"; did you mean {close[0]!r}?" if close else ""
    return SpecError(
        [
            (
                f"query.{filter_name}",
                f"unknown {filter_name} {value!r}{hint} (one of: {', '.join(known)})",
            )
        ]
    )


def job_list_query(
    state: Annotated[JobState | None, Query(description="only jobs in this state")] = None,
    kind: Annotated[
        str | None,
        Query(min_length=1, max_length=64, description="only this kind (422 if no such kind)"),
    ] = None,
    name: Annotated[
        str | None,
        Query(max_length=200, description="only jobs whose name contains this (any case)"),
    ] = None,
    batch: Annotated[
        str | None,
        Query(max_length=200, description="only jobs of this batch run (its exact label)"),
    ] = None,
    sort: Annotated[
        str,
        Query(
            max_length=16,
            description="order: " + ", ".join(f"`{k}`" for k in JOB_SORTS) + " (`-`: descending)",
            # documented as the closed set it is (issue 21, item 12: schemathesis sent other
            # strings the schema allowed and got the 422)
            json_schema_extra={"enum": list(JOB_SORTS)},
        ),
    ] = "-created",
    limit: Annotated[int, Query(ge=1, le=1000, description="at most this many")] = 200,
    offset: Annotated[int, Query(ge=0, le=MAX_OFFSET, description="skip this many (paging)")] = 0,
    columns: Annotated[
        list[str] | None,
        Query(
            max_length=16,
            description="add these values to each job as `columns` (repeatable or "
            "comma-separated): `params.<path>` (e.g. `params.model`) or `metric.<name>` "
            "(the mean of its result rows, e.g. `metric.brdf.smape`)",
        ),
    ] = None,
    filter: Annotated[
        list[FilterText] | None,
        Query(
            max_length=16,
            description="only jobs whose value passes `<column><op><value>` "
            "(op: = != < <= > >=, an order with a decimal number; spaces around allowed; "
            "repeatable, all must pass), e.g. `params.model=hybrid`, `metric.brdf.smape<0.1`; "
            "a column no kind has (a param, a metric) is refused naming the closest ones",
        ),
    ] = None,
    tag: Annotated[
        str | None, Query(min_length=1, max_length=64, description="only jobs with this tag")
    ] = None,
) -> JobListQuery:
    """The validated options; raises :class:`SpecError` (422) naming an unknown kind or
    sort order."""
    if kind:
        known = sorted(kinds.all_kinds())
        if kind not in known:
            raise _unknown("kind", kind, known)
    if sort not in JOB_SORTS:
        raise _unknown("sort", sort, list(JOB_SORTS))
    return JobListQuery(
        state=state,
        kind=kind or None,
        name=name or None,
        batch=batch or None,
        sort=sort,
        limit=limit,
        offset=offset,
        columns=tuple(parse_keys(columns or [])),
        filters=tuple(parse_filters(filter or [])),
        tag=tag or None,
    )


JobListDep = Annotated[JobListQuery, Depends(job_list_query)]
