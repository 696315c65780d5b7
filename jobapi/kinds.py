"""What a job kind is, and the registry that kinds add themselves to.

A job kind is exactly four things: a params model, a runner, a summary hook that turns its
results into a table, and its tests with tiny smoke params. A kind module ends with one
registration line::

    register(Kind(name="render", params=RenderParams, runner=run_render, ...))

This module only holds what was registered. Which modules register the built-in kinds is
decided at the edge, by the explicit list in :mod:`service.kinds`; nothing here imports a
kind or scans directories.
"""

from __future__ import annotations

import fnmatch
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from pydantic import BaseModel

from jobapi.documents import prepare
from jobapi.reports import ReportFacts
from jobapi.results import ArtifactReader, ResultTable
from jobapi.rows import RowsHook

if TYPE_CHECKING:
    from jobapi.context import JobContext

Runner = Callable[[Any, "JobContext"], None]
#: A run's time limit unless its kind or its spec says otherwise (24 h).
DEFAULT_TIMEOUT_SECONDS = 24 * 3600.0
#: How long a run may go without progress unless its kind says otherwise (30 min).
DEFAULT_STALL_SECONDS = 30 * 60.0
#: ``summary(read)``: the kind's result table from its JSON artifacts (``read(name)`` is
#: the parsed artifact called ``name``, or ``None``), or ``None`` when it has none.
SummaryHook = Callable[[ArtifactReader], ResultTable | None]


@dataclass(frozen=True)
class Axis:
    """An axis of a picture: what runs along it and its values at the two ends (left to
    right, or top to bottom)."""

    label: str
    start: str = ""
    end: str = ""


@dataclass(frozen=True)
class Figure:
    """How the dashboard shows a kind's image artifacts whose name matches ``pattern``
    (``fnmatch``, e.g. ``"*.png"``).

    Attributes:
        pattern: artifact names this applies to.
        caption: a sentence shown under the picture.
        x: the horizontal axis, when the picture is a plot of two coordinates.
        y: the vertical axis (top to bottom).
        lead: the kind's most telling picture: shown first, at its full size.
    """

    pattern: str
    caption: str = ""
    x: Axis | None = None
    y: Axis | None = None
    lead: bool = False


@dataclass(frozen=True)
class Kind:
    """One job kind.

    Attributes:
        name: the ``kind`` of a spec, e.g. ``"render"``.
        params: strict pydantic model of ``params`` (``extra="forbid"``).
        runner: ``runner(params, ctx)``; writes artifacts through ``ctx``.
        description: one line for the README table and the OpenAPI description.
        artifacts: the fixed artifact names (``"<name>.binary"`` style patterns allowed).
        smoke: tiny params that run in seconds; the parametrised registry test runs them.
        summary: the result-table hook (:data:`SummaryHook`); the dashboard, the CLI and
            ``GET /api/jobs/{id}/summary`` show what it returns and know no kind's fields.
        layout: markdown describing the artifacts' layouts (arrays, shapes, indexing), for
            the README's table of kinds.
        rows: the result-rows hook (:data:`jobapi.rows.RowsHook`): every value the job
            measured, one row each, for ``GET /api/results`` and ``matforge results``.
        figures: how the dashboard shows its pictures (:class:`Figure`): which comes first,
            and the axes of those that are plots.
        timeout_seconds: the default time limit of one run (a spec's ``timeout_seconds``
            replaces it): a run still going after it is failed, "timed out".
        stall_seconds: the longest a run may go without progress (a new progress value
            or message; every finished shard reports one) before it is failed as stuck,
            its shard processes killed and its worker freed. Set it above the kind's
            longest silent step.
        report: what the report kinds read of its jobs
            (:class:`jobapi.reports.ReportFacts`: headline metric, loss key, failure-case
            metric, model checks, claims); ``None`` for a kind that trains nothing.
        variant_bytes: whether the artifacts' bytes depend on the Mitsuba variant
            (``MATFORGE_VARIANT``): ``True`` for a kind whose outputs come from Dr.Jit
            kernels (a render, a Mitsuba tabulation), ``False`` for numpy, torch and file
            work, or ``params -> bool`` when it depends on the spec (a MERL table of an
            analytic source is numpy, of a Mitsuba BSDF is a kernel). Where true, a spec's
            identity includes the variant (:mod:`service.specs`).
        documents: the JSON documents it writes, ``{artifact name: TypedDict}``
            (:mod:`jobapi.documents`): ``put_json`` validates each against its type, readers
            parse it with :func:`jobapi.documents.read_typed`, the kinds reference lists
            its fields.
        timing_artifacts: the artifacts whose product is a timing (``fnmatch`` patterns), or
            ``params -> patterns`` when it depends on the spec: the one exception to "same
            spec, same bytes" (a kind whose figure plots what it timed, e.g. an error
            against the measured frame cost). Every other timing goes to the manifest
            (:meth:`jobapi.context.JobContext.measure`); the registry's determinism test
            compares every artifact of two runs of a spec but these.
        metrics: the metric names of its result rows (names or ``fnmatch`` patterns, e.g.
            ``"brdf.smape"``, ``"*.rel"``; :mod:`jobapi.metric_names`): what ``metric.<name>``
            columns and filters and ``--metric`` accept. A name no kind declares is
            refused with the closest known ones.
    """

    name: str
    params: type[BaseModel]
    runner: Runner
    description: str
    artifacts: tuple[str, ...] = ()
    smoke: dict[str, Any] = field(default_factory=dict)
    summary: SummaryHook | None = None
    layout: str = ""
    rows: RowsHook | None = None
    figures: tuple[Figure, ...] = ()
    timeout_seconds: float = DEFAULT_TIMEOUT_SECONDS
    stall_seconds: float = DEFAULT_STALL_SECONDS
    report: ReportFacts | None = None
    variant_bytes: bool | Callable[[Any], bool] = False
    documents: Mapping[str, type] = field(default_factory=dict)
    timing_artifacts: tuple[str, ...] | Callable[[Any], tuple[str, ...]] = ()
    metrics: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        # Its documents' validators are built with the kind (at import), not by the first
        # request that reads one: :func:`jobapi.documents.prepare`.
        prepare(*self.documents.values())

    def bytes_depend_on_variant(self, params: BaseModel) -> bool:
        """:attr:`variant_bytes` for these (validated) params."""
        rule = self.variant_bytes
        return bool(rule(params) if callable(rule) else rule)

    def is_timing_artifact(self, artifact: str, params: BaseModel) -> bool:
        """Whether ``artifact`` is one of :attr:`timing_artifacts` for these (validated)
        params: its bytes vary between runs of the same spec."""
        rule = self.timing_artifacts
        patterns = rule(params) if callable(rule) else rule
        return any(fnmatch.fnmatchcase(artifact, p) for p in patterns)

    def figure(self, artifact: str) -> Figure | None:
        """The first of :attr:`figures` whose pattern matches an artifact name, if any."""
        return next((f for f in self.figures if fnmatch.fnmatchcase(artifact, f.pattern)), None)


_KINDS: dict[str, Kind] = {}


def register(kind: Kind) -> Kind:
    """Add ``kind`` to the registry (re-registering the same name replaces it)."""
    _KINDS[kind.name] = kind
    return kind


def restore(snapshot: Mapping[str, Kind]) -> None:
    """Make the registry ``snapshot`` again (a :func:`registered` copy), in its order: the
    plugin loader undoes what a plugin's import registered or replaced."""
    _KINDS.clear()
    _KINDS.update(snapshot)


def registered() -> dict[str, Kind]:
    """The kinds registered so far, by name (a copy)."""
    return dict(_KINDS)


def declared_metrics() -> list[str]:
    """Every registered kind's :attr:`Kind.metrics` (names and patterns), once each, in
    registry order."""
    return list(dict.fromkeys(m for k in _KINDS.values() for m in k.metrics))


def report_facts(name: str) -> ReportFacts | None:
    """What the report kinds read of kind ``name``'s jobs (``None``: not registered, or it
    declares none)."""
    kind = _KINDS.get(name)
    return kind.report if kind is not None else None
