"""Batch files: named steps run in order on a server, later steps using earlier artifacts.

A batch file is JSON or YAML::

    steps:
      - name: gold
        spec: {kind: render, seed: 1, params: {...}}
      - name: score
        spec: {kind: score, params: {reference: "step:gold/image.exr",
                                     candidates: {a: "step:alu/image.exr"}}}
    defaults: {seed: 3}      # optional: top-level fields a step's spec lacks
                             # (seed, force, timeout_seconds)

Variables: a top-level ``vars: {name: default}`` (string, integer or ``null`` defaults)
declares parameters of the recipe; anywhere in a spec the whole string ``var:<name>``
becomes its value, given on the command line (``matforge batch FILE --var model=sha256:...``)
or the default. A variable with an integer default is an integer: its ``--var`` value must
be one (``--var resolution=16``). A variable without a value, an unknown ``var:`` name, an
undeclared ``--var`` or a non-integer value of an integer variable is an error naming it.
(The recipes ``scripts/external_brdf.yaml`` and ``scripts/external_btf.yaml`` take the
user's model this way, and ``external_btf.yaml`` its sizes.)

A top-level list of steps is accepted as well. ``spec`` is a spec mapping, or the path of a
spec file relative to the batch file. Anywhere in a spec, the string
``step:<step-name>/<artifact-name>`` names an artifact of an EARLIER step; it becomes
``job:<job-id>/<artifact-name>`` once that step has finished.

The whole file is validated before anything is submitted (:func:`parse_batch`): step names
are unique and match ``[A-Za-z0-9_.-]+``, every ``step:`` ref names an earlier step, and every
spec passes :func:`service.specs.validate_spec` with its step refs replaced by placeholder
``job:`` refs. Errors name the file, the step and the field.

Steps are run by :mod:`service.cli.batch_run` (in order, or N independent steps at a
time). The results (one flat row per step, metrics flattened to ``<label>.<metric>``
columns) are built, written and shown by :mod:`service.cli.results`.
"""

from __future__ import annotations

import logging
import re
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from jobapi.errors import SpecError
from jobapi.results import ResultTable
from service.specs import (
    SHORT_JOB_REF,
    STEP_REF,
    load_spec_file,
    parse_spec_text,
    validate_spec,
)

log = logging.getLogger("matforge.batch")

STEP_NAME = re.compile(r"^[A-Za-z0-9_.-]+\Z")
PLACEHOLDER_JOB = "0" * 32
DEFAULT_KEYS = frozenset({"seed", "force", "timeout_seconds"})


class BatchError(ValueError):
    """A batch file is invalid; ``problems`` lists one line per problem, each naming the
    file, and the step and field where there is one."""

    def __init__(self, problems: list[str]) -> None:
        self.problems = problems
        super().__init__("\n".join(problems))


@dataclass(frozen=True)
class StepRef:
    """A ``step:<step>/<artifact>`` reference found at ``loc`` (a dotted field path)."""

    loc: str
    step: str
    artifact: str

    @property
    def text(self) -> str:
        return f"step:{self.step}/{self.artifact}"


@dataclass(frozen=True)
class Step:
    """One validated step: its name, its spec (with ``step:`` refs still in it), its kind."""

    name: str
    spec: dict[str, Any]
    kind: str
    refs: tuple[StepRef, ...] = ()


@dataclass(frozen=True)
class Batch:
    """A validated batch file: its source (for messages) and its steps, in order."""

    source: str
    steps: tuple[Step, ...]


@dataclass
class StepResult:
    """What happened to one step. ``state`` is the job's final state, or ``skipped`` (a
    previous step failed), or ``error`` (not submitted: a ref did not resolve, the server
    rejected the spec, or the server could not be reached)."""

    step: str
    kind: str
    job_id: str | None = None
    state: str = "skipped"
    seconds: float | None = None
    error: str | None = None
    metrics: dict[str, float] = field(default_factory=dict)
    table: ResultTable | None = None
    artifacts: list[dict[str, Any]] = field(default_factory=list)


@dataclass
class BatchOutcome:
    """All step results and the exit code: 0, 1 (a job failed or was cancelled), 2 (bad
    input found while running) or 3 (server unreachable or refused)."""

    results: list[StepResult]
    exit_code: int = 0


# -- parsing and validation ----------------------------------------------------------------
def _strings(obj: Any, loc: str) -> Iterator[tuple[str, str]]:
    if isinstance(obj, str):
        yield loc, obj
    elif isinstance(obj, dict):
        for k, v in obj.items():
            yield from _strings(v, f"{loc}.{k}" if loc else str(k))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from _strings(v, f"{loc}.{i}" if loc else str(i))


def substitute_refs(obj: Any, resolve: Callable[[str], str]) -> Any:
    """A copy of ``obj`` with every string that is a ``step:`` ref replaced by
    ``resolve(ref)``; ``obj`` itself is not modified."""
    if isinstance(obj, str):
        return resolve(obj) if STEP_REF.match(obj) else obj
    if isinstance(obj, dict):
        return {k: substitute_refs(v, resolve) for k, v in obj.items()}
    if isinstance(obj, list):
        return [substitute_refs(v, resolve) for v in obj]
    return obj


def pad_short_job_refs(obj: Any) -> Any:
    """A copy of ``obj`` with each ``job:<short id>/<name>`` padded to a full-length id, for
    validating a spec here; the server resolves the prefix when the step is submitted."""
    if isinstance(obj, str):
        m = SHORT_JOB_REF.match(obj)
        return f"job:{m['job'].ljust(32, '0')}{m['rest'] or ''}" if m else obj
    if isinstance(obj, dict):
        return {k: pad_short_job_refs(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [pad_short_job_refs(v) for v in obj]
    return obj


def _placeholder(ref: str) -> str:
    m = STEP_REF.match(ref)
    assert m is not None
    if m["name"] is None:
        return f"job:{PLACEHOLDER_JOB}"
    return f"job:{PLACEHOLDER_JOB}/{m['name']}"


def _step_spec(
    entry: dict[str, Any], where: str, base_dir: Path | None, problems: list[str]
) -> dict[str, Any] | None:
    spec = entry.get("spec")
    if isinstance(spec, str):
        path = Path(spec)
        if base_dir is not None and not path.is_absolute():
            path = base_dir / path
        try:
            spec = load_spec_file(path)
        except SpecError as exc:
            problems.append(f"{where}: spec: {exc}")
            return None
    if not isinstance(spec, dict):
        problems.append(
            f"{where}: spec: must be a job spec mapping (or a spec file path), "
            f"got {type(spec).__name__}"
        )
        return None
    return spec


VAR_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]{0,63}\Z")


def _variables(doc: Any, given: dict[str, str], source: str) -> dict[str, str | int]:
    """The values of the batch's ``vars`` (see the module docstring)."""
    declared = doc.get("vars") if isinstance(doc, dict) else None
    declared = {} if declared is None else declared
    if not isinstance(declared, dict) or not all(
        isinstance(k, str)
        and VAR_NAME.match(k)
        and (v is None or isinstance(v, str) or (isinstance(v, int) and not isinstance(v, bool)))
        for k, v in declared.items()
    ):
        raise BatchError(
            [f"{source}: vars: must map names to string or integer defaults (or null)"]
        )
    unknown = sorted(set(given) - set(declared))
    if unknown:
        known = ", ".join(sorted(declared)) or "none"
        raise BatchError([f"{source}: --var {unknown[0]}: not a variable of this batch "
                          f"(its vars: {known})"])  # fmt: skip
    values = {k: given.get(k, v) for k, v in declared.items()}
    missing = sorted(k for k, v in values.items() if v is None)
    if missing:
        raise BatchError([f"{source}: vars.{missing[0]}: no value; give --var {missing[0]}=VALUE"])
    out: dict[str, str | int] = {}
    for k, v in values.items():
        if isinstance(declared[k], int) and not isinstance(v, int):
            try:
                v = int(str(v), 10)
            except ValueError:
                raise BatchError(
                    [f"{source}: --var {k}={v}: {k} is an integer variable (its default is "
                     f"{declared[k]})"]
                ) from None  # fmt: skip
        out[k] = v if isinstance(v, int) else str(v)
    return out


def substitute_vars(
    obj: Any, values: Mapping[str, str | int], where: str, problems: list[str]
) -> Any:
    """A copy of ``obj`` with every string ``var:<name>`` replaced by its value (an unknown
    name is a problem, named with ``where``)."""
    if isinstance(obj, str):
        if not obj.startswith("var:"):
            return obj
        name = obj.removeprefix("var:")
        if name not in values:
            problems.append(f"{where}: {obj}: no variable {name!r} in the batch's vars")
            return obj
        return values[name]
    if isinstance(obj, dict):
        return {k: substitute_vars(v, values, where, problems) for k, v in obj.items()}
    if isinstance(obj, list):
        return [substitute_vars(v, values, where, problems) for v in obj]
    return obj


def parse_batch(
    doc: Any,
    source: str = "<batch>",
    *,
    base_dir: Path | None = None,
    validate: Callable[[Any], Any] = validate_spec,
    variables: dict[str, str] | None = None,
) -> Batch:
    """Validate a parsed batch document; raises :class:`BatchError` listing every problem.

    ``validate`` checks one spec (default :func:`validate_spec`; tests may pass their own);
    ``variables`` are the values of the batch's ``vars`` (``--var name=value``).
    """
    defaults: dict[str, Any] = {}
    values = _variables(doc, dict(variables or {}), source)
    if isinstance(doc, dict):
        unknown = sorted(set(doc) - {"steps", "defaults", "vars"})
        if unknown:
            raise BatchError(
                [
                    f"{source}: unknown top-level field(s) {', '.join(unknown)}; "
                    "a batch file has 'steps' and optional 'defaults' and 'vars'"
                ]
            )
        raw_defaults = doc.get("defaults") or {}
        if not isinstance(raw_defaults, dict) or set(raw_defaults) - DEFAULT_KEYS:
            raise BatchError(
                [
                    f"{source}: defaults: must be a mapping with only "
                    f"{', '.join(sorted(DEFAULT_KEYS))}"
                ]
            )
        defaults = raw_defaults
        entries = doc.get("steps")
    else:
        entries = doc
    if not isinstance(entries, list) or not entries:
        raise BatchError([f"{source}: expected a non-empty list of steps ('steps: [...]')"])

    problems: list[str] = []
    steps: list[Step] = []
    seen: dict[str, int] = {}
    all_names = {e.get("name") for e in entries if isinstance(e, dict)}
    for i, entry in enumerate(entries, start=1):
        if not isinstance(entry, dict):
            problems.append(f"{source}: step #{i}: must be a mapping with 'name' and 'spec'")
            continue
        name = entry.get("name")
        where = f"{source}: step #{i}" + (f" {name!r}" if isinstance(name, str) else "")
        unknown = sorted(set(entry) - {"name", "spec"})
        if unknown:
            problems.append(
                f"{where}: unknown field(s) {', '.join(unknown)}; a step has 'name' and 'spec'"
            )
        if not isinstance(name, str) or not STEP_NAME.match(name):
            problems.append(f"{where}: name: must be a string of letters, digits, '_', '.' or '-'")
            continue
        if name in seen:
            problems.append(
                f"{where}: name: duplicate step name {name!r} (first used by step #{seen[name]})"
            )
            continue
        seen[name] = i
        spec = _step_spec(entry, where, base_dir, problems)
        if spec is None:
            continue
        spec = substitute_vars(spec, values, where, problems)
        spec = {**{k: v for k, v in defaults.items() if k not in spec}, **spec}
        refs, ok = [], True
        for loc, value in _strings(spec, ""):
            if not value.startswith("step:"):
                continue
            m = STEP_REF.match(value)
            if m is None:
                problems.append(
                    f"{where}: {loc}: bad step reference {value!r}; expected "
                    "'step:<step-name>/<artifact-name>' (or 'step:<step-name>' for the whole job)"
                )
                ok = False
            elif m["step"] == name:
                problems.append(f"{where}: {loc}: {value} refers to the step itself")
                ok = False
            elif m["step"] not in seen:
                why = (
                    "a later step; a step may only use artifacts of earlier steps"
                    if m["step"] in all_names
                    else "no step of that name in the batch"
                )
                problems.append(f"{where}: {loc}: {value} refers to {m['step']!r}: {why}")
                ok = False
            else:
                refs.append(StepRef(loc, m["step"], m["name"]))
        if not ok:
            continue
        try:
            valid = validate(pad_short_job_refs(substitute_refs(spec, _placeholder)))
        except SpecError as exc:
            problems.extend(
                f"{where}: {loc}: {msg}" if loc else f"{where}: {msg}" for loc, msg in exc.errors
            )
            continue
        kind = getattr(valid, "kind", None) or str(spec.get("kind"))
        steps.append(Step(name=name, spec=spec, kind=kind, refs=tuple(refs)))
    if problems:
        raise BatchError(problems)
    return Batch(source=source, steps=tuple(steps))


def parse_vars(items: list[str]) -> dict[str, str]:
    """``--var NAME=VALUE`` options as ``{name: value}``; :class:`BatchError` for an item
    without ``=`` or a name."""
    out: dict[str, str] = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or not name:
            raise BatchError([f"--var {item}: expected NAME=VALUE"])
        out[name] = value
    return out


def load_batch(
    path: str | Path,
    *,
    validate: Callable[[Any], Any] = validate_spec,
    variables: dict[str, str] | None = None,
) -> Batch:
    """Read and validate a batch file (``variables``: its ``vars``' values); raises
    :class:`BatchError` naming the file."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise BatchError([f"{p}: no such file"]) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise BatchError([f"{p}: cannot read: {exc}"]) from None
    try:
        doc = parse_spec_text(text, str(p))
    except SpecError as exc:
        raise BatchError([str(exc)]) from None
    return parse_batch(doc, str(p), base_dir=p.parent, validate=validate, variables=variables)
