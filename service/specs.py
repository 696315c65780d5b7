"""Job specs: validation, canonical form and identity hash.

A spec is ``{"kind": ..., "name": ..., "seed": ..., "params": {...}, "force": false,
"timeout_seconds": ...}``. Validation is strict and happens before anything is queued: an
unknown kind, an unknown field, a wrong type or an out-of-range value raises
:class:`SpecError` naming the field.

Identity: the canonical JSON of ``{"kind", "seed", "params"}`` with every default filled in,
keys sorted and no whitespace. ``name`` is a label, ``force`` an instruction and
``timeout_seconds`` a limit on how long a run may take, none of which changes the output
bytes, so none is part of the identity: a spec that succeeded is reused whatever its time
limit was. ``timeout_seconds`` is kept in the stored spec (the worker reads it there).

The Mitsuba variant (``MATFORGE_VARIANT``) joins the identity only where it changes the
bytes: for a kind whose :attr:`~jobapi.kinds.Kind.variant_bytes` says its artifacts are
computed by Dr.Jit kernels (renders, Mitsuba tabulation, fused inference), a spec run under
any variant but :data:`REFERENCE_VARIANT` hashes ``{"kind", "seed", "params", "variant"}``.
Under ``llvm_ad_rgb``, and for every kind whose bytes do not depend on it (numpy, torch,
file import), the hash is the one above, as it always was; the stored spec never carries
the variant (the manifest records it).
"""

from __future__ import annotations

import difflib
import hashlib
import json
import re
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from jobapi.errors import SpecError
from jobapi.kinds import Kind
from service import kinds
from service.spec_text import parse_spec_text

__all__ = ["STEP_REF", "JobSpec", "ValidSpec", "load_spec_file", "parse_spec_text", "validate_spec"]

#: ``step:<step>/<artifact>``, or ``step:<step>`` for the whole job (e.g. a dataset).
STEP_REF = re.compile(r"^step:(?P<step>[A-Za-z0-9_.-]+)(?:/(?P<name>[A-Za-z0-9._/-]+))?\Z")
#: ``job:<short id>/<name>`` or ``job:<short id>``: a job ref whose id is a prefix (1 to 31
#: hex digits). The server writes it out in full before validating
#: (:func:`service.submission.expand_short_refs`).
SHORT_JOB_REF = re.compile(r"^job:(?P<job>[0-9a-f]{1,31})(?P<rest>/.*)?\Z")
MAX_SEED = 2**63 - 1
#: The variant whose specs hash without it (every spec's identity before the setting).
REFERENCE_VARIANT = "llvm_ad_rgb"
#: The longest time limit a spec may ask for (30 days).
MAX_TIMEOUT_SECONDS = 30 * 24 * 3600.0


class JobSpec(BaseModel):
    """The envelope of a job spec (``params`` is validated against the kind's model)."""

    model_config = ConfigDict(extra="forbid")

    kind: str = Field(min_length=1, max_length=64)
    name: str | None = Field(default=None, max_length=200)
    seed: int = Field(default=0, ge=0, le=MAX_SEED, strict=True)
    params: dict[str, Any] = Field(default_factory=dict)
    force: bool = Field(default=False, strict=True)
    batch: str | None = Field(
        default=None,
        max_length=200,
        description="a label grouping jobs submitted together (`matforge batch` sets it); "
        "like `name`, not part of the spec's identity",
    )
    timeout_seconds: float | None = Field(
        default=None,
        gt=0,
        le=MAX_TIMEOUT_SECONDS,
        allow_inf_nan=False,
        strict=True,
        description="the most seconds a run of the job may take before it is failed "
        "(default: its kind's, `Kind.timeout_seconds`); a limit, not an input: not part "
        "of the spec's identity",
    )


class ValidSpec(BaseModel):
    """A validated spec: the envelope, the typed params, and the identity hash."""

    model_config = ConfigDict(arbitrary_types_allowed=True, frozen=True)

    kind: str
    name: str | None
    seed: int
    force: bool
    params: BaseModel
    batch: str | None = None
    timeout_seconds: float | None = None
    canonical: str
    spec_hash: str

    def document(self) -> dict[str, Any]:
        """The spec as stored and shown: defaults filled in, ``force`` dropped."""
        doc = json.loads(self.canonical)
        if self.name is not None:
            doc["name"] = self.name
        if self.batch is not None:
            doc["batch"] = self.batch
        if self.timeout_seconds is not None:
            doc["timeout_seconds"] = self.timeout_seconds
        return doc


def _loc(parts: tuple[Any, ...]) -> str:
    return ".".join(str(p) for p in parts)


#: The loc parts pydantic gives a union's members: ``function-after[_check_ref(), str]``,
#: ``list[float]``, ``literal['a']``, plain type names, and model class names.
_MEMBER_TAG = re.compile(r"[a-z][a-z-]*\[.*\]|str|int|float|bool|none|bytes", re.DOTALL)


def _model_names() -> set[str]:
    names, todo = set(), [BaseModel]
    while todo:
        cls = todo.pop()
        for sub in cls.__subclasses__():
            if sub.__name__ not in names:
                names.add(sub.__name__)
                todo.append(sub)
    return names


#: Error types that say a union member does not have the input's shape at all (a key it
#: does not take, a key it needs, or another type), as opposed to a wrong value in a member
#: whose shape fits.
_SHAPE_ERRORS = frozenset({"extra_forbidden", "missing"})
_QUOTED = re.compile(r"'((?:[^'\\]|\\.)*)'")


def _did_you_mean(err: Any) -> str:
    """``"; did you mean 'x'?"`` for a string that misses an enum or ``Literal`` value by a
    typo (pydantic lists the allowed values, quoted, in ``ctx["expected"]``)."""
    value, expected = err.get("input"), (err.get("ctx") or {}).get("expected")
    if err.get("type") not in ("literal_error", "enum") or not isinstance(value, str):
        return ""
    allowed = _QUOTED.findall(str(expected or ""))
    by_case = {a.lower(): a for a in allowed}
    guess = by_case.get(value.lower())
    if guess is None:
        starts = [a for a in allowed if a.startswith(value) or value.startswith(a)]
        close = starts[:1] or difflib.get_close_matches(value, allowed, n=1, cutoff=0.6)
        guess = close[0] if close else None
    return f"; did you mean {guess!r}?" if guess is not None and guess != value else ""


_WORD = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def _field_names(schema: dict[str, Any], loc: tuple[Any, ...]) -> list[str]:
    """The field names of the object at ``loc`` (an error's path, pydantic's union member
    tags included) in a JSON schema: every alternative's, for a union."""
    defs: dict[str, Any] = schema.get("$defs", {})

    def alternatives(node: Any) -> list[dict[str, Any]]:
        seen = 0
        while isinstance(node, dict) and "$ref" in node and seen < 64:
            node, seen = defs.get(str(node["$ref"]).rsplit("/", 1)[-1], {}), seen + 1
        if not isinstance(node, dict):
            return []
        out = [node]
        for key in ("anyOf", "oneOf", "allOf"):
            for alt in node.get(key, ()):
                out.extend(alternatives(alt))
        return out

    nodes = [schema]
    for part in loc:
        here = [alt for node in nodes for alt in alternatives(node)]
        found: list[Any] = []
        for node in here:
            if isinstance(part, int):
                prefix = node.get("prefixItems") or []
                found.extend([prefix[part]] if part < len(prefix) else [])
                if isinstance(node.get("items"), dict):
                    found.append(node["items"])
            elif part in node.get("properties", {}):
                found.append(node["properties"][part])
            elif isinstance(node.get("additionalProperties"), dict):
                found.append(node["additionalProperties"])
        if not found and isinstance(part, str):
            # a union member's tag (``ProceduralExample``, ``function-after[..., Model]``)
            found = [defs[w] for w in _WORD.findall(part) if w in defs][-1:]
        nodes = found or nodes  # a tag of a plain type: the same object
    names: list[str] = []
    for node in nodes:
        for alt in alternatives(node):
            names.extend(n for n in alt.get("properties", {}) if n not in names)
    return names


def _unknown_field_hint(err: Any, schema: dict[str, Any] | None) -> str:
    """``"; did you mean 'spp'?"`` for an unknown field that misses one the object takes
    by a typo."""
    loc = tuple(err.get("loc", ()))
    if err.get("type") != "extra_forbidden" or schema is None or not loc:
        return ""
    if not isinstance(loc[-1], str):
        return ""
    names = _field_names(schema, loc[:-1])
    by_case = {n.lower(): n for n in names}
    close = [by_case[loc[-1].lower()]] if loc[-1].lower() in by_case else []
    close = close or difflib.get_close_matches(loc[-1], names, n=1, cutoff=0.6)
    return f"; did you mean {close[0]!r}?" if close else ""


def _misfit(err_type: str, inner: tuple[Any, ...]) -> bool:
    """Whether an error of a union member says the member does not fit the input's shape."""
    if err_type in _SHAPE_ERRORS:
        return len(inner) <= 1
    return not inner and err_type.endswith(("_type", "_parsing"))


def _pydantic_errors(
    exc: ValidationError, prefix: str = "", schema: dict[str, Any] | None = None
) -> list[tuple[str, str]]:
    """One ``(field path, message)`` per field. A union's members each fail with their own
    error, under a loc part naming the member (pydantic internals, e.g.
    ``function-after[_check_ref(), str]``). When exactly one member fits the input's shape
    (``{"procedural": "scratch"}`` is a procedural example with a wrong value, not a normal
    map without its ``normal_map``), that member's errors are given at their own fields;
    otherwise they are merged into one message at the union's field, each member's reason
    after the other. A string that misses an enum or ``Literal`` value, at any depth, gets
    "did you mean", and so does an unknown field that misses one of ``schema`` (the
    model's JSON schema) by a typo."""
    models = _model_names()

    def is_member(part: Any) -> bool:
        return isinstance(part, str) and (part in models or bool(_MEMBER_TAG.fullmatch(part)))

    def join(*parts: str) -> str:
        return ".".join(p for p in parts if p)

    # field -> member (None: not in a union) -> [(inner path, message, misfit)]
    fields: dict[str, dict[str | None, list[tuple[str, str, bool]]]] = {}
    for err in exc.errors():
        loc = tuple(err.get("loc", ()))
        hint = _unknown_field_hint(err, schema)
        msg = str(err["msg"]).removeprefix("Value error, ") + _did_you_mean(err) + hint
        cut = next((i for i, part in enumerate(loc) if is_member(part)), None)
        member: str | None = None
        inner: tuple[Any, ...] = ()
        if cut is not None:
            member = str(loc[cut])
            inner = tuple(part for part in loc[cut + 1 :] if not is_member(part))
            loc = loc[:cut]
        path = _loc(loc)
        key = f"{prefix}{path}" if path else prefix.rstrip(".")
        # a field that misses one of the member's by a typo: the member still fits
        entry = (_loc(inner), msg, _misfit(str(err.get("type", "")), inner) and not hint)
        fields.setdefault(key, {}).setdefault(member, []).append(entry)
    out: list[tuple[str, str]] = []
    for key, members in fields.items():
        fitting = [m for m, errs in members.items() if not any(e[2] for e in errs)]
        if len(members) > 1 and len(fitting) == 1 and fitting[0] is not None:
            for inner_path, msg, _ in members[fitting[0]]:
                if (join(key, inner_path), msg) not in out:
                    out.append((join(key, inner_path), msg))
            continue
        msgs: list[str] = []
        for errs in members.values():
            for inner_path, msg, _ in errs:
                text = f"{inner_path}: {msg}" if inner_path else msg
                if text not in msgs:
                    msgs.append(text)
        out.append(
            (
                key,
                msgs[0]
                if len(msgs) == 1
                else "none of its accepted forms fits: " + "; or ".join(msgs),
            )
        )
    return out


def canonical_json(obj: Any) -> str:
    """Canonical JSON: sorted keys, no whitespace, UTF-8, finite floats only."""
    return json.dumps(
        obj, sort_keys=True, separators=(",", ":"), ensure_ascii=False, allow_nan=False
    )


#: The envelope's JSON schema, for the field names of "did you mean" (made once: making it
#: builds pydantic validators, which a request must not do).
_ENVELOPE_SCHEMA = JobSpec.model_json_schema()


def _params_schema(kind: Kind) -> dict[str, Any] | None:
    from service.kind_docs import params_schema

    try:
        return params_schema(kind)
    except Exception:  # a plugin's params without a schema: no hint, the error stays
        return None


def _unknown_kind(name: str) -> str:
    """The message for a kind no one registered: the closest registered kind first."""
    known = sorted(kinds.all_kinds())
    by_case = {k.lower(): k for k in known}
    close = [by_case[name.lower()]] if name.lower() in by_case else []
    close = close or difflib.get_close_matches(name, known, n=1, cutoff=0.6)
    hint = f"; did you mean {close[0]!r}?" if close else ""
    return f"unknown job kind {name!r}{hint} (known kinds: {', '.join(known)})"


def validate_spec(raw: Any, *, variant: str | None = None) -> ValidSpec:
    """Validate a spec document (a dict, as parsed from JSON or YAML). ``variant``: the
    Mitsuba variant the job will run under (``None``: identity without it, as under
    :data:`REFERENCE_VARIANT`); see the module docstring for when it joins the hash."""
    if not isinstance(raw, dict):
        raise SpecError([("", f"a job spec must be an object, got {type(raw).__name__}")])
    # Every error at once: the envelope's, the kind's and the params' (the params of a
    # known kind are checked even when the envelope has errors of its own).
    errors: list[tuple[str, str]] = []
    env: JobSpec | None = None
    try:
        env = JobSpec.model_validate(raw)
    except ValidationError as exc:
        errors.extend(_pydantic_errors(exc, schema=_ENVELOPE_SCHEMA))
    name = env.kind if env is not None else raw.get("kind")
    given = env.params if env is not None else raw.get("params", {})
    kind = None
    if isinstance(name, str) and name:
        try:
            kind = kinds.get_kind(name)
        except KeyError:
            errors.append(("kind", _unknown_kind(name)))
    params: BaseModel | None = None
    if kind is not None and isinstance(given, dict):
        try:
            # JSON mode: strict about types, but arrays may fill tuple fields, as in any
            # spec that arrives as JSON or YAML.
            params = kind.params.model_validate_json(canonical_json(given))
        except ValidationError as exc:
            errors.extend(_pydantic_errors(exc, "params.", _params_schema(kind)))
        except ValueError as exc:  # NaN or infinity in params
            errors.append(("params", f"not valid JSON: {exc}"))
    if errors:
        raise SpecError(errors)
    assert env is not None and kind is not None and params is not None
    body = {"kind": env.kind, "seed": env.seed, "params": params.model_dump(mode="json")}
    canonical = canonical_json(body)
    identity = canonical
    if variant not in (None, REFERENCE_VARIANT) and kind.bytes_depend_on_variant(params):
        identity = canonical_json({**body, "variant": variant})
    digest = hashlib.sha256(identity.encode()).hexdigest()
    return ValidSpec(
        kind=env.kind,
        name=env.name,
        seed=env.seed,
        force=env.force,
        batch=env.batch,
        timeout_seconds=env.timeout_seconds,
        params=params,
        canonical=canonical,
        spec_hash=digest,
    )


def load_spec_file(path: str | Path) -> Any:
    """Parse a JSON or YAML spec file; ``SpecError`` names the file on a parse error."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise SpecError([("", f"{p}: no such file")]) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise SpecError([("", f"{p}: cannot read: {exc}")]) from None
    return parse_spec_text(text, str(p))
