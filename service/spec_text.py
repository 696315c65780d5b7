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
"""

from __future__ import annotations

import json
import math
from typing import Any

import yaml

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

    def construct_yaml_int(self, node: Any) -> Any:
        value = str(self.construct_scalar(node)).replace("_", "")
        digits = len(value.lstrip("+-"))
        if digits > MAX_INT_DIGITS:
            return _HugeInt(digits)
        return super().construct_yaml_int(node)


_SpecLoader.add_constructor("tag:yaml.org,2002:int", _SpecLoader.construct_yaml_int)


class _NoAliasLoader(_SpecLoader):
    allow_aliases = False


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


def parse_json_text(text: str, loc: str = "body") -> Any:
    """Parse JSON text into a checked document (see :func:`check_document`); errors about
    the text as a whole are reported at ``loc``."""
    try:
        doc = json.loads(text, parse_int=_parse_int)
    except json.JSONDecodeError as exc:
        raise SpecError(
            [(loc, f"not valid JSON: {exc.msg} at line {exc.lineno} column {exc.colno}")]
        ) from None
    except RecursionError:
        raise _too_deep(loc) from None
    check_document(doc)
    return doc


def parse_spec_text(text: str, source: str = "<spec>", *, aliases: bool = True) -> Any:
    """Parse JSON (or YAML, a superset) text into a checked document; ``aliases=False``
    refuses YAML aliases (for text from the network). Errors name ``source``."""
    try:
        try:
            doc = json.loads(text, parse_int=_parse_int)
        except json.JSONDecodeError:
            doc = yaml.load(text, Loader=_SpecLoader if aliases else _NoAliasLoader)  # noqa: S506
    except yaml.YAMLError as exc:
        first = str(exc).splitlines()[0] if str(exc) else "invalid YAML"
        raise SpecError([("", f"{source}: not valid JSON or YAML: {first}")]) from None
    except RecursionError:
        raise SpecError([("", f"{source}: nested deeper than {MAX_DEPTH} levels")]) from None
    check_document(doc)
    return doc
