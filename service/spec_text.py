"""Parsing spec text (JSON or YAML) without letting hostile input past the edges.

Specs arrive from users: as a REST body or as files given to the CLI. What parses must also
be a plain JSON document of bounded size, and every refusal is a :class:`SpecError` naming the
field (REST 422, CLI exit 2), never an internal error:

- an integer of more than :data:`MAX_INT_DIGITS` digits (Python refuses to convert it);
- nesting deeper than :data:`MAX_DEPTH` levels (the parsers and encoders recurse);
- YAML values JSON has no type for: dates and timestamps, ``!!binary``, ``!!set``;
- a document of more than :data:`MAX_NODES` values or :data:`MAX_TEXT_CHARS` characters of
  strings once YAML aliases are expanded, and, where ``aliases=False`` (the REST API), any
  alias at all: a few hundred bytes of aliases can expand into megabytes.

What can be checked before the document is built is checked first (issue 21, item 5: a 6 KB
YAML spec nested 3,000 deep took PyYAML's pure-Python scanner about a second, quadratic in
the depth, and a 1 MB flat YAML list tens of seconds):

- YAML goes through libyaml's C parser when PyYAML has it: one pass over its events refuses
  nesting deeper than :data:`MAX_DEPTH`, aliases (where refused) and more than
  ``max_values`` values before any Python object is built;
- JSON is parsed by the C decoder; the value-by-value walk then runs only for documents that
  may need it (a huge integer, a non-finite number, more opening brackets than
  :data:`MAX_DEPTH`, or very large text).

The web app runs these functions in a thread (:mod:`service.routes.jobs`), never on its event
loop.
"""

from __future__ import annotations

import json
import math
from typing import Any

import yaml
from yaml import events

from jobapi.errors import SpecError

#: Python's own limit on converting decimal strings to int (``sys.int_info``).
MAX_INT_DIGITS = 4300
#: Far deeper than any spec, far shallower than the recursion limit.
MAX_DEPTH = 100
MAX_NODES = 1_000_000
MAX_TEXT_CHARS = 16 * 1024 * 1024
_SCALARS = (str, int, float, bool, type(None))


class _HugeInt:
    """Stands in for an integer literal too long to convert; reported with its path."""

    def __init__(self, digits: int) -> None:
        self.digits = digits


def _parse_int(text: str) -> int | _HugeInt:
    digits = len(text.lstrip("+-"))
    return _HugeInt(digits) if digits > MAX_INT_DIGITS else int(text)


class _SpecLoader(yaml.SafeLoader):
    """PyYAML's safe loader with integers guarded like JSON's, and aliases optionally refused."""

    allow_aliases = True

    def compose_node(self, parent: Any, index: Any) -> Any:
        if not self.allow_aliases and self.check_event(yaml.AliasEvent):
            event = self.peek_event()
            raise SpecError(
                [
                    (
                        "",
                        f"line {event.start_mark.line + 1}: YAML aliases (*{event.anchor}) "
                        "are not accepted here; write the value out",
                    )
                ]
            )
        return super().compose_node(parent, index)


def _construct_int(loader: Any, node: Any) -> Any:
    """YAML integers, with those too long to convert kept as :class:`_HugeInt`."""
    value = str(loader.construct_scalar(node)).replace("_", "")
    digits = len(value.lstrip("+-"))
    if digits > MAX_INT_DIGITS:
        return _HugeInt(digits)
    return yaml.constructor.SafeConstructor.construct_yaml_int(loader, node)


_SpecLoader.add_constructor("tag:yaml.org,2002:int", _construct_int)


class _NoAliasLoader(_SpecLoader):
    allow_aliases = False


#: libyaml's parser (C) when PyYAML was built with it; ``None`` falls back to pure Python.
_CLoader: Any = getattr(yaml, "CSafeLoader", None) if yaml.__with_libyaml__ else None
if _CLoader is not None:

    class _CSpecLoader(_CLoader):
        """libyaml's safe loader with integers guarded like JSON's."""

    _CSpecLoader.add_constructor("tag:yaml.org,2002:int", _construct_int)


def _not_json(value: Any) -> str:
    """Why ``value`` (a YAML-only type) is refused, and what to write instead."""
    import datetime

    if isinstance(value, datetime.datetime | datetime.date):
        return f"a YAML date ({value.isoformat()}) is not accepted; quote it to pass a string"
    if isinstance(value, bytes):
        return "YAML binary data (!!binary) is not accepted; pass a string or an upload's ref"
    if isinstance(value, set | frozenset):
        return "a YAML set (!!set) is not accepted; use a list"
    return f"a value of type {type(value).__name__} is not accepted (not JSON)"


def check_document(doc: Any) -> None:
    """Raise :class:`SpecError` naming the field if ``doc`` is not a plain, bounded JSON
    document (see the module docstring). Iterative, so depth cannot exhaust the stack."""
    errors: list[tuple[str, str]] = []
    nodes, chars = 0, 0
    stack: list[tuple[Any, str, int]] = [(doc, "", 0)]
    while stack and len(errors) < 10:
        value, path, depth = stack.pop()
        nodes += 1
        if nodes > MAX_NODES or chars > MAX_TEXT_CHARS:
            raise SpecError(
                [(path, f"the document is too large (over {MAX_NODES} values or "
                        f"{MAX_TEXT_CHARS // 2**20} MiB of text, aliases expanded)")]
            )  # fmt: skip
        if depth > MAX_DEPTH:
            raise SpecError([(path, f"nested deeper than {MAX_DEPTH} levels")])
        if isinstance(value, _HugeInt):
            errors.append((path, f"an integer of {value.digits} digits is too large"))
        elif isinstance(value, float) and not math.isfinite(value):
            errors.append((path, f"{value} is not a finite number"))
        elif isinstance(value, str):
            chars += len(value)
        elif isinstance(value, dict):
            for key, item in value.items():
                if not isinstance(key, _SCALARS):
                    errors.append((path, f"bad key: {_not_json(key)}"))
                    continue
                chars += len(str(key))
                stack.append((item, f"{path}.{key}" if path else str(key), depth + 1))
        elif isinstance(value, list | tuple):
            for i, item in enumerate(value):
                stack.append((item, f"{path}.{i}" if path else str(i), depth + 1))
        elif not isinstance(value, _SCALARS):
            errors.append((path, _not_json(value)))
    if errors:
        raise SpecError(errors)


def _too_deep(loc: str) -> SpecError:
    return SpecError([(loc, f"nested deeper than {MAX_DEPTH} levels")])


_OPENING = (events.SequenceStartEvent, events.MappingStartEvent)
_CLOSING = (events.SequenceEndEvent, events.MappingEndEvent)
_NODE = (events.ScalarEvent, events.AliasEvent, *_OPENING)


def _line(event: events.Event) -> str:
    """``"line N: "`` of where an event starts (empty if the parser did not say)."""
    mark = event.start_mark
    return f"line {mark.line + 1}: " if mark is not None else ""


def _scan_yaml(text: str, source: str, *, aliases: bool, max_values: int | None) -> None:
    """Check YAML text's events before any object is built: nesting depth, aliases (when
    refused) and the number of values; raises :class:`SpecError` at the first excess.
    Malformed text passes: the load that follows reports it."""
    depth = values = 0
    try:
        for event in yaml.parse(text, Loader=_CLoader or yaml.SafeLoader):
            if isinstance(event, _NODE):
                values += 1
                if max_values is not None and values > max_values:
                    raise SpecError(
                        [("", f"{source}: more than {max_values} values; a spec this large "
                              "must be sent as JSON")]
                    )  # fmt: skip
            if isinstance(event, _OPENING):
                depth += 1
                if depth > MAX_DEPTH:
                    raise SpecError([("", f"{source}: {_line(event)}nested deeper than "
                                          f"{MAX_DEPTH} levels")])  # fmt: skip
            elif isinstance(event, _CLOSING):
                depth -= 1
            elif not aliases and isinstance(event, events.AliasEvent):
                raise SpecError(
                    [("", f"{_line(event)}YAML aliases (*{event.anchor}) "
                          "are not accepted here; write the value out")]
                )  # fmt: skip
    except yaml.YAMLError as exc:
        if "nesting depth" in str(getattr(exc, "problem", "")):  # libyaml's own cap (1,000)
            raise SpecError([("", f"{source}: nested deeper than {MAX_DEPTH} levels")]) from None
        return  # malformed: the load that follows reports it


def _load_json_fast(text: str) -> tuple[Any, bool]:
    """``(document, checked)``: the C decoder's document, and whether it is known to pass
    :func:`check_document` without walking it: no huge integer or non-finite number, fewer
    opening brackets than :data:`MAX_DEPTH` (so no deeper nesting), and too short to hold
    more than :data:`MAX_NODES` values or :data:`MAX_TEXT_CHARS` of text. Raises
    ``json.JSONDecodeError`` and ``RecursionError`` as :func:`json.loads` does."""
    special: list[str] = []

    def constant(name: str) -> float:
        special.append(name)
        return float(name.replace("Infinity", "inf"))

    try:
        doc = json.loads(text, parse_constant=constant)
    except ValueError as exc:
        if isinstance(exc, json.JSONDecodeError):
            raise
        # an integer too long to convert: parse again to find and name it
        return json.loads(text, parse_int=_parse_int), False
    small = len(text) <= min(2 * MAX_NODES, MAX_TEXT_CHARS)
    # str.count runs in C at memory speed; a regex pass to find the real depth held the GIL
    # (and so the event loop) for 100 ms on 1 MB, longer than the walk it would save
    shallow = text.count("[") + text.count("{") <= MAX_DEPTH
    return doc, not special and small and shallow


def parse_json_text(text: str, loc: str = "body") -> Any:
    """Parse JSON text into a checked document (see :func:`check_document`); errors about
    the text as a whole are reported at ``loc``."""
    try:
        doc, checked = _load_json_fast(text)
    except json.JSONDecodeError as exc:
        raise SpecError(
            [(loc, f"not valid JSON: {exc.msg} at line {exc.lineno} column {exc.colno}")]
        ) from None
    except RecursionError:
        raise _too_deep(loc) from None
    if not checked:
        check_document(doc)
    return doc


def parse_spec_text(
    text: str, source: str = "<spec>", *, aliases: bool = True, max_values: int | None = None
) -> Any:
    """Parse JSON (or YAML, a superset) text into a checked document; ``aliases=False``
    refuses YAML aliases (for text from the network), ``max_values`` caps the values of a
    YAML document before it is built. Errors name ``source``."""
    checked = False
    try:
        try:
            doc, checked = _load_json_fast(text)
        except json.JSONDecodeError:
            _scan_yaml(text, source, aliases=aliases, max_values=max_values)
            if _CLoader is not None:  # aliases, if refused, were refused by the scan
                doc = yaml.load(text, Loader=_CSpecLoader)  # noqa: S506
            else:
                doc = yaml.load(text, Loader=_SpecLoader if aliases else _NoAliasLoader)  # noqa: S506
    except yaml.YAMLError as exc:
        first = str(exc).splitlines()[0] if str(exc) else "invalid YAML"
        raise SpecError([("", f"{source}: not valid JSON or YAML: {first}")]) from None
    except RecursionError:
        raise SpecError([("", f"{source}: nested deeper than {MAX_DEPTH} levels")]) from None
    if not checked:
        check_document(doc)
    return doc
