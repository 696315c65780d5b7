"""The one schema of each JSON artifact that the dashboard draws: ``curves.json``
(:class:`CurvesDocument`) and ``pareto.json`` (:class:`ParetoDocument`), each a type with
the rules a type cannot say (:data:`RULES`: :func:`check_curves`, :func:`check_pareto`)
(``docs/artifacts.md``, "Chart documents", whose field tables are generated from the
types). :class:`~jobapi.context.JobContext` validates them when a kind writes them
(``put_json``, declared in ``Kind.documents`` or not) or publishes them live (``publish``),
so that a kind that writes another shape fails its first test instead of drawing nothing.

``curves.json`` (``train.brdf``, ``train.btf``, ``train.fabric``, any plugin):

- ``step``: list of N >= 1 ints, strictly increasing: the x axis (optimiser steps, counted
  across phases);
- every other key whose value is a list: a *series* of N numbers or ``null`` (a loss or an
  error, lower is better), at least one of them a number;
- every key whose value is an object: a *group* ``{name: series}``, drawn as ``key.name``;
- reserved: ``lr`` (a series, the learning rate, drawn on its own axis), ``epoch`` (N
  numbers, a second coordinate, never drawn as a series), ``phases`` (a list of ``{"name",
  "first_step", "last_step"}``, consecutive, within ``step``);
- any key whose value is a string: a note (e.g. ``loss_definition``).

``pareto.json`` (``report.pareto``, ``report.brdf``):

- ``format``: a string; ``runs``: the ``job:<id>`` refs reported on;
- ``panels``: a non-empty list; each panel has ``metric`` and ``cost`` (strings; ``dataset``,
  ``scene`` and ``cost_label`` strings or ``null``), ``points`` (a non-empty list of
  ``{"candidate": str, "mean": number, "cost": number, "front": bool}``, optionally ``std``,
  ``min``, ``max`` numbers, ``n``, ``jobs`` a list of ``job:<id>``) and ``front`` (the
  candidates on the front, each one of the points');
- ``claims`` (optional): a list of ``{"claim": str, "holds": bool or null}`` objects;
- other keys are a kind's own (``report.brdf``'s ``points`` per configuration).

Typed documents: a kind declares the JSON documents it writes as ``TypedDict`` types
(``Kind.documents``: ``{artifact name: type}``, decorated with :data:`document` so that a
key the type does not name is refused). The type is the one definition of the document:
the writer builds it (mypy checks its keys and values), ``put_json`` validates it
(:func:`check_typed`: missing, unknown or mistyped keys fail the job, naming the field),
readers parse it with :func:`read_typed` (typed access instead of ``.get() or {}``
chains), and ``docs/reference/kinds.md`` lists its fields from the type
(``scripts/kinds_table.py``). Validation never changes the document: the bytes written are
the writer's, as before.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from typing import Any, NotRequired, TypeVar

from pydantic import ConfigDict, TypeAdapter, ValidationError, with_config
from typing_extensions import TypedDict

__all__ = [
    "ManifestArtifact",
    "ManifestDocument",
    "ManifestTimings",
    "CurvesDocument",
    "CurvesPhase",
    "DocumentError",
    "CostDistribution",
    "ParetoClaim",
    "ParetoDocument",
    "ParetoPanel",
    "ParetoPoint",
    "TimingCost",
    "TimingDocument",
    "TimingMachine",
    "check_document",
    "check_curves",
    "check_pareto",
    "check_typed",
    "document",
    "prepare",
    "read_typed",
]

T = TypeVar("T")

#: The decorator of a typed document (a ``TypedDict``): unknown keys are refused, and each
#: field's docstring (a string literal under it) is its description in the docs.
document = with_config(ConfigDict(extra="forbid", use_attribute_docstrings=True))

#: Where the schemas are written down (named in every error).
SCHEMA_DOC = "docs/artifacts.md (Chart documents)"
#: Keys of ``curves.json`` that are not loss series.
CURVE_COORDINATES = ("step", "epoch")


class DocumentError(ValueError):
    """A chart document that does not follow its schema; the message names the document,
    the field and what is wrong."""


def _number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _fail(name: str, field: str, what: str) -> DocumentError:
    return DocumentError(f"{name}: {field}: {what} (schema: {SCHEMA_DOC})")


def check_curves(doc: Any, name: str = "curves.json") -> None:
    """Raise :class:`DocumentError` unless ``doc`` follows the ``curves.json`` schema."""
    if not isinstance(doc, dict):
        raise _fail(name, "(document)", f"an object expected, got {type(doc).__name__}")
    step = doc.get("step")
    if not isinstance(step, list) or not step:
        raise _fail(name, "step", "a non-empty list of step numbers is required at the top level")
    for i, s in enumerate(step):
        if not isinstance(s, int) or isinstance(s, bool) or s < 0:
            raise _fail(name, f"step[{i}]", f"a step number (int >= 0) expected, got {s!r}")
        if i and s <= step[i - 1]:
            raise _fail(name, f"step[{i}]", f"steps must increase, {s} follows {step[i - 1]}")
    n = len(step)

    def series(field: str, values: Any, *, any_number: bool = True) -> None:
        if not isinstance(values, list) or len(values) != n:
            got = f"{len(values)} values" if isinstance(values, list) else type(values).__name__
            raise _fail(name, field, f"a list of {n} values (one per step) expected, got {got}")
        for i, v in enumerate(values):
            if v is not None and not _number(v):
                raise _fail(name, f"{field}[{i}]", f"a finite number or null expected, got {v!r}")
        if any_number and not any(_number(v) for v in values):
            raise _fail(name, field, "every value is null: nothing to draw")

    found = 0
    for key, value in doc.items():
        if key == "step":
            continue
        if key == "epoch":
            series(key, value)
        elif key == "phases":
            _check_phases(name, value, step)
        elif isinstance(value, str):
            continue
        elif isinstance(value, list):
            series(key, value)
            found += key != "lr"
        elif isinstance(value, dict):
            if not value:
                raise _fail(name, key, "an empty group of series")
            for sub, values in value.items():
                series(f"{key}.{sub}", values)
                found += 1
        else:
            raise _fail(
                name, key, "a series (list), a group of series (object) or a note (string) "
                f"expected, got {type(value).__name__}"
            )  # fmt: skip
    if not found:
        raise _fail(name, "(document)", "no series besides step, epoch and lr: nothing to draw")


def _check_phases(name: str, phases: Any, step: list[int]) -> None:
    if not isinstance(phases, list) or not phases:
        raise _fail(name, "phases", "a non-empty list of {name, first_step, last_step} expected")
    previous = None
    if isinstance(phases[0], dict) and isinstance(phases[0].get("first_step"), int):
        if step[0] < phases[0]["first_step"]:
            raise _fail(name, "phases[0]", f"step {step[0]} is before the first phase")
    for i, p in enumerate(phases):
        where = f"phases[{i}]"
        if not isinstance(p, dict) or set(p) != {"name", "first_step", "last_step"}:
            raise _fail(name, where, "an object of exactly name, first_step, last_step expected")
        first, last = p["first_step"], p["last_step"]
        if not isinstance(p["name"], str) or not p["name"]:
            raise _fail(name, f"{where}.name", "a non-empty string expected")
        if not (isinstance(first, int) and isinstance(last, int) and first <= last):
            raise _fail(name, where, f"first_step <= last_step (ints) expected, got {first!r}, "
                                     f"{last!r}")  # fmt: skip
        if previous is not None and first != previous + 1:
            raise _fail(name, where, f"phases are consecutive: first_step {first} should be "
                                     f"{previous + 1}")  # fmt: skip
        if not any(first <= s <= last for s in step):
            raise _fail(name, where, f"no step of the curves in {first}..{last}")
        previous = last
    if step[-1] > previous:  # type: ignore[operator]
        raise _fail(name, "phases", f"step {step[-1]} is after the last phase's last_step")


def check_pareto(doc: Any, name: str = "pareto.json") -> None:
    """Raise :class:`DocumentError` unless ``doc`` follows the ``pareto.json`` schema."""
    if not isinstance(doc, dict):
        raise _fail(name, "(document)", f"an object expected, got {type(doc).__name__}")
    if not isinstance(doc.get("format"), str):
        raise _fail(name, "format", "a string naming the document's format is required")
    runs = doc.get("runs")
    if not isinstance(runs, list) or not all(isinstance(r, str) for r in runs):
        raise _fail(name, "runs", "a list of job:<id> strings is required")
    panels = doc.get("panels")
    if not isinstance(panels, list) or not panels:
        raise _fail(name, "panels", "a non-empty list of panels is required (points alone "
                                    "are not drawn)")  # fmt: skip
    for i, panel in enumerate(panels):
        _check_panel(name, f"panels[{i}]", panel)
    claims = doc.get("claims", [])
    if not isinstance(claims, list):
        raise _fail(name, "claims", "a list expected")
    for i, c in enumerate(claims):
        if not isinstance(c, dict) or not isinstance(c.get("claim"), str):
            raise _fail(name, f"claims[{i}]", "an object with a claim string expected")
        if c.get("holds") not in (True, False, None):
            raise _fail(name, f"claims[{i}].holds", f"true, false or null, got {c['holds']!r}")


def _check_panel(name: str, where: str, panel: Any) -> None:
    if not isinstance(panel, dict):
        raise _fail(name, where, "an object expected")
    for key in ("metric", "cost"):
        if not isinstance(panel.get(key), str) or not panel[key]:
            raise _fail(name, f"{where}.{key}", "a non-empty string is required")
    for key in ("dataset", "scene", "cost_label"):
        if panel.get(key) is not None and not isinstance(panel[key], str):
            raise _fail(name, f"{where}.{key}", f"a string or null expected, got {panel[key]!r}")
    points = panel.get("points")
    if not isinstance(points, list) or not points:
        raise _fail(name, f"{where}.points", "a non-empty list of points is required")
    candidates = []
    for j, p in enumerate(points):
        at = f"{where}.points[{j}]"
        if not isinstance(p, dict) or not isinstance(p.get("candidate"), str):
            raise _fail(name, at, "an object with a candidate string expected")
        for key in ("mean", "cost"):
            if not _number(p.get(key)):
                raise _fail(name, f"{at}.{key}", f"a finite number is required, got "
                                                 f"{p.get(key)!r}")  # fmt: skip
        for key in ("std", "min", "max"):
            if p.get(key) is not None and not _number(p[key]):
                raise _fail(name, f"{at}.{key}", f"a finite number or absent, got {p[key]!r}")
        if not isinstance(p.get("front"), bool):
            raise _fail(name, f"{at}.front", "true or false is required (on the front or not)")
        jobs = p.get("jobs", [])
        if not isinstance(jobs, list) or not all(isinstance(j, str) for j in jobs):
            raise _fail(name, f"{at}.jobs", "a list of job:<id> strings expected")
        candidates.append(p["candidate"])
    front = panel.get("front")
    if not isinstance(front, list) or any(c not in candidates for c in front):
        raise _fail(name, f"{where}.front", "a list of the candidates of its points expected")
    flagged = [p["candidate"] for p in points if p["front"]]
    if sorted(flagged) != sorted(front):
        raise _fail(name, f"{where}.front", f"lists {front} but the points on the front are "
                                            f"{flagged}")  # fmt: skip


# -- the chart documents' types ---------------------------------------------------------------
# The fields every writer and reader shares; the rules a type cannot say (strictly increasing
# steps, one value per step, the front among the points) are the checkers above, attached to
# each type in ``RULES``. Extra keys stay allowed where the schema allows them (a series, a
# group, a note; a kind's own keys), so the types describe the documents as they are.

_OPEN = ConfigDict(extra="allow", use_attribute_docstrings=True)


@document
class ManifestArtifact(TypedDict):
    """One artifact a job wrote, as its manifest lists it."""

    name: str
    """The artifact's name, e.g. ``image.exr``."""
    digest: str
    """sha256 of its bytes, 64 lowercase hex."""
    size: int
    """Its size in bytes."""
    media_type: str
    """Its media type, e.g. ``image/x-exr``."""


@document
class ManifestTimings(TypedDict):
    """When a job's run started and finished (Unix seconds) and what it timed itself."""

    started: float
    finished: float
    run_seconds: float
    measured: dict[str, float]
    """What the kind timed itself (``JobContext.measure``), e.g. ``render_seconds``."""


@document
class ManifestDocument(TypedDict):
    """A succeeded job's provenance, stored beside its artifacts (``GET
    /api/jobs/{id}/manifest``; its ``sha256:`` ref is the job's ``manifest``)."""

    job: str
    """The job id, 32 lowercase hex."""
    kind: str
    name: str | None
    spec: dict[str, Any]
    """The validated spec, defaults filled in."""
    spec_hash: str
    """sha256 of the canonical spec (the job's identity)."""
    seed: int
    artifacts: list[ManifestArtifact]
    """Every artifact the job wrote, by name."""
    matforge_version: str
    code_version: str
    """The git commit of the code (``<sha>``, ``<sha>+dirty`` or ``unknown``)."""
    packages: dict[str, str | None]
    """Installed versions of the packages that decide artifact bytes (``python`` too)."""
    worker: str | None
    """``<host>:<pid>`` of the worker that ran it."""
    executor: str
    """Where the shards ran: ``process`` (the local pool), ``inline`` or ``ray``."""
    executor_nodes: int
    """How many machines (Ray: the live nodes when the job finished)."""
    variant: str | None
    """The Mitsuba variant the job's processes used (``MATFORGE_VARIANT``, resolved)."""
    device: str | None
    """The torch device a training kind ran on (``None`` for the other kinds)."""
    attempt: int
    """Which attempt succeeded (1 unless a worker was lost)."""
    timings: ManifestTimings


@document
class CurvesPhase(TypedDict):
    """One phase of a training run, on the steps of ``curves.json``."""

    name: str
    """The phase (``train``, ``heldout``)."""
    first_step: int
    """Its first step; the first phase's is at or before ``step[0]``."""
    last_step: int
    """Its last step; the next phase begins at ``last_step + 1``."""


@with_config(_OPEN)
class CurvesDocument(TypedDict):
    """``curves.json``: series against step. Every other key is a series (a list of N
    finite numbers or ``null``, at least one a number), a group ``{name: series}`` drawn as
    ``key.name``, or a note (a string, e.g. ``loss_definition``)."""

    step: list[int]
    """N >= 1 ints >= 0, strictly increasing: the x axis (optimiser steps, counted across
    phases)."""
    lr: NotRequired[list[float | None]]
    """The learning rate (N values), drawn on its own log axis."""
    epoch: NotRequired[list[float | None]]
    """A second coordinate (N values: data passes), never drawn as a loss."""
    phases: NotRequired[list[CurvesPhase]]
    """The run's phases, consecutive, covering every step."""


@with_config(_OPEN)
class CostDistribution(TypedDict):
    """A timed cost over its repeats (or a ratio over rounds): ``torch.utils.benchmark``'s
    median and IQR, Google Benchmark's aggregates."""

    median: float
    """The median."""
    min: float
    """The least value."""
    max: float
    """The largest value."""
    iqr: float
    """Interquartile range (``q3 - q1``)."""
    n: int
    """Repeats."""
    q1: NotRequired[float]
    """First quartile."""
    q3: NotRequired[float]
    """Third quartile."""


@with_config(_OPEN)
class TimingMachine(TypedDict):
    """Where a timing pass ran."""

    processor: str
    """The CPU model."""
    cores: int | None
    """Logical CPUs of the machine."""
    threads: int
    """Threads the pass's runtimes used (Dr.Jit and torch)."""
    load_before: list[float]
    """Load average (1, 5, 15 min) before the pass."""
    load_after: list[float]
    """Load average after it."""
    runtimes: dict[str, str]
    """Runtime versions and the Mitsuba variant (``mitsuba_variant``)."""


@with_config(_OPEN)
class TimingCost(TypedDict):
    """One kernel's cost in a timing pass: the cost record every model's cost takes."""

    ns_per_eval: float
    """The median ns per evaluation."""
    distribution: CostDistribution
    """ns per evaluation over the repeats."""
    runtime: str
    """What evaluated it (``drjit-fused``, ``onnxruntime``, ``mitsuba``)."""
    relative: NotRequired[CostDistribution | None]
    """Per round, its ns per evaluation over the reference kernel's."""
    wall: NotRequired[CostDistribution]
    """Its calls' wall time, ns per evaluation (beside a CPU-time ``distribution``)."""
    calls: NotRequired[int]
    """Calls per sample (each synchronised), sized after the warm-up."""
    macs_per_eval: NotRequired[int | float | None]
    """Multiply-adds per evaluation (machine-independent; ``null``: not counted)."""
    bytes_per_eval: NotRequired[int | float | None]
    """Bytes read per evaluation (machine-independent; ``null``: not counted)."""


@with_config(_OPEN)
class TimingDocument(TypedDict):
    """A comparison's timing pass (``matforge.timing/1``): every model and the reference
    kernel timed in one process, interleaved round-robin, on the same batch."""

    format: str
    """``matforge.timing/1``."""
    reference: str | None
    """The reference kernel's name among ``costs``."""
    repeats: int
    """Recorded rounds per kernel (at least 5)."""
    warmup: int
    """Unrecorded rounds before them."""
    clock: NotRequired[str]
    """``cpu`` (process CPU time over the threads / threads) or ``wall``."""
    machine: TimingMachine
    """Where it ran."""
    settings: dict[str, Any]
    """Batch, seed, queries, the reference BSDF."""
    costs: dict[str, TimingCost]
    """Per kernel (candidate or reference), its cost."""
    order: NotRequired[list[list[str]]]
    """The kernels' order in each recorded round."""


@with_config(_OPEN)
class ParetoPoint(TypedDict):
    """One candidate of a panel (a kind may add its own keys, e.g. ``seeds``)."""

    candidate: str
    """The candidate's label."""
    mean: float
    """Its error: the mean over jobs (seeds), finite."""
    cost: float
    """Its cost, finite."""
    front: bool
    """On the panel's front (not beaten on both cost and error)."""
    std: NotRequired[float | None]
    """Sample std over seeds (ddof 1)."""
    min: NotRequired[float | None]
    """Least error over seeds (the error bar's low end)."""
    max: NotRequired[float | None]
    """Largest error over seeds."""
    n: NotRequired[int]
    """Jobs (seeds) averaged."""
    jobs: NotRequired[list[str]]
    """The ``job:<id>`` refs averaged; the first is opened on click."""
    runtime: NotRequired[str | None]
    """What evaluated the candidate (``drjit-fused``, ``onnxruntime``, ``mitsuba``, several
    joined with ``+``)."""
    cost_min: NotRequired[float]
    """Timing pass: the least ns per evaluation over the repeats (the x error bar)."""
    cost_max: NotRequired[float]
    """Timing pass: the largest."""
    cost_iqr: NotRequired[float]
    """Timing pass: the interquartile range."""
    cost_n: NotRequired[int]
    """Timing pass: the repeats."""
    relative: NotRequired[CostDistribution | None]
    """Timing pass: the cost over the reference kernel's, per round."""
    resolved: NotRequired[bool]
    """Whether its place on or off the front holds anywhere inside the spreads."""
    tied_with: NotRequired[list[str]]
    """The candidates that make it undecided (empty: resolved)."""
    split: NotRequired[str | None]
    """Whose error it is: ``test`` (held-out data), ``train`` (the data it was fitted to),
    ``null`` for neither (a score of renders)."""


@with_config(_OPEN)
class ParetoPanel(TypedDict):
    """One chart: one dataset and scene, one error metric against one cost."""

    metric: str
    """The error metric (lower is better), non-empty."""
    cost: str
    """The cost column, non-empty."""
    dataset: NotRequired[str | None]
    """The dataset (``null``: any)."""
    scene: NotRequired[str | None]
    """The scene (``null``: any)."""
    cost_label: NotRequired[str | None]
    """The cost axis' label."""
    runtimes: NotRequired[list[str]]
    """The points' runtimes; with more than one, ``cost_label`` says they differ."""
    points: list[ParetoPoint]
    """One per candidate, non-empty."""
    front: list[str]
    """The candidates of the points with ``front: true``."""
    resolved: NotRequired[bool | None]
    """Whether the front holds inside the spreads (``false``: see ``not_resolved``)."""
    ties: NotRequired[list[list[str]]]
    """Pairs of candidates whose order is inside the spreads."""
    not_resolved: NotRequired[str | None]
    """Why the front is not resolved, in words (``null``: it is)."""
    timing_pass: NotRequired[bool]
    """Whether the costs are this job's own timing pass (``timing`` of the document)."""
    job_timed: NotRequired[bool]
    """Whether the costs are timings each job took itself (separate passes: not ranked)."""


@with_config(_OPEN)
class ParetoClaim(TypedDict):
    """A claim checked (a kind may add ``why`` and its own keys)."""

    claim: str
    """What is claimed."""
    holds: bool | None
    """Whether it holds (``null``: not resolved)."""


@with_config(_OPEN)
class ParetoDocument(TypedDict):
    """``pareto.json``: error against cost, in panels. Other keys are a kind's own
    (``report.brdf``'s per-configuration ``points``; ``report.pareto``'s ``families``)."""

    format: str
    """The writer's format (``matforge.pareto/1``, ``matforge.brdf-report/1``)."""
    runs: list[str]
    """The ``job:<id>`` refs reported on."""
    panels: list[ParetoPanel]
    """One chart each, non-empty."""
    claims: NotRequired[list[ParetoClaim]]
    """The claims checked."""
    timing: NotRequired[TimingDocument]
    """The timing pass that measured the ``ns_per_eval`` panels' costs."""


#: The rules of a typed document that its type cannot say (checked before its type, so
#: that the error is the rule's): ``check(doc, artifact name)``.
RULES: dict[type, Callable[[Any, str], None]] = {
    CurvesDocument: check_curves,
    ParetoDocument: check_pareto,
}
#: The chart documents' types by artifact name (the last path component): checked for
#: every kind, declared or not (a plugin's too).
CHARTS: dict[str, type] = {"curves.json": CurvesDocument, "pareto.json": ParetoDocument}


def check_document(name: str, doc: Any) -> None:
    """Check ``doc`` against the type of the chart document ``name`` if it is one (by its
    file name: ``curves.json``, ``pareto.json``, also under a folder); other names pass."""
    typed = CHARTS.get(name.rsplit("/", 1)[-1])
    if typed is not None:
        check_typed(name, doc, typed)


_ADAPTERS: dict[Any, TypeAdapter[Any]] = {}
_ADAPTERS_LOCK = threading.Lock()


def prepare(*types: Any) -> None:
    """Build the validators of these document types now (once each), not when a document
    is first read. Building one reads the type's source for its field docstrings
    (``inspect`` and ``ast``), which CPython 3.11's ``ast`` cannot do in two threads at
    once (``SystemError: AST constructor recursion depth mismatch``): a request must find
    them built. :class:`jobapi.kinds.Kind` prepares its :attr:`~jobapi.kinds.Kind.documents`
    when it is defined, this module its chart documents."""
    for typed in types:
        _adapter(typed)


def _adapter(typed: Any) -> TypeAdapter[Any]:
    # Built once per type (validating must not rebuild pydantic's schema every time), and
    # under a lock: a type no kind declares is still built by one thread at a time.
    adapter = _ADAPTERS.get(typed)
    if adapter is None:
        with _ADAPTERS_LOCK:
            adapter = _ADAPTERS.get(typed)
            if adapter is None:
                adapter = _ADAPTERS[typed] = TypeAdapter(typed)
    return adapter


def check_typed(name: str, doc: Any, typed: type) -> None:
    """Raise :class:`DocumentError` unless ``doc`` is a ``typed`` document: every key it
    requires, no other, each value of its declared JSON type (strict: no coercion, but an
    int is a number), and its :data:`RULES` if it has any. Names the artifact, the field
    and the type."""
    rule = RULES.get(typed)
    if rule is not None:
        rule(doc, name)
    try:
        _adapter(typed).validate_python(doc, strict=True)
    except ValidationError as exc:
        err = exc.errors()[0]
        field = ".".join(str(p) for p in err["loc"]) or "(document)"
        raise DocumentError(
            f"{name}: {field}: {err['msg']} (schema: {typed.__module__}.{typed.__qualname__})"
        ) from None


def read_typed(doc: Any, typed: type[T]) -> T | None:
    """``doc`` (parsed JSON) as a ``typed`` document, or ``None`` when it is not one (a
    missing artifact, or one of another shape): a reader then shows nothing rather than
    guessing. A type's :data:`RULES` apply as when it is written."""
    try:
        rule = RULES.get(typed)
        if rule is not None:
            rule(doc, "document")
        valid: T = _adapter(typed).validate_python(doc, strict=True)
        return valid
    except (ValidationError, DocumentError):
        return None


def document_fields(typed: type) -> list[tuple[str, str, bool, str]]:
    """``(field, JSON type, required, description)`` of every field of a typed document,
    nested objects' fields as ``outer.inner`` (in a list: ``outer[].inner``), in
    declaration order: the docs' table."""
    schema = _adapter(typed).json_schema()
    defs = schema.get("$defs", {})

    def resolve(s: dict[str, Any]) -> dict[str, Any]:
        while "$ref" in s:
            s = defs[s["$ref"].rsplit("/", 1)[-1]]
        return s

    def type_of(s: dict[str, Any]) -> str:
        s = resolve(s)
        if "anyOf" in s:
            return " or ".join(type_of(x) for x in s["anyOf"])
        if s.get("type") == "array":
            return f"list of {type_of(s.get('items', {}))}"
        extra = s.get("additionalProperties")
        if s.get("type") == "object" and "properties" not in s and isinstance(extra, dict):
            return f"object of {type_of(extra)}"
        return str(s.get("type", "any"))

    out: list[tuple[str, str, bool, str]] = []

    def walk(s: dict[str, Any], prefix: str) -> None:
        s = resolve(s)
        required = set(s.get("required", ()))
        for key, prop in s.get("properties", {}).items():
            # pydantic leaves out a field's description equal to its type's: use the type's
            found = prop.get("description") or resolve(prop).get("description", "")
            desc = " ".join(str(found).split())
            out.append((prefix + key, type_of(prop), key in required, desc))
            if "properties" in resolve(prop):
                walk(prop, f"{prefix}{key}.")
            elif "properties" in resolve(resolve(prop).get("items", {})):
                walk(resolve(prop)["items"], f"{prefix}{key}[].")

    walk(schema, "")
    return out


prepare(*CHARTS.values())
