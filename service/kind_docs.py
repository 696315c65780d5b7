"""Kinds described for people, from the registry: the README's table of kinds
(``scripts/kinds_table.py``) and ``matforge kinds`` share these."""

from __future__ import annotations

from typing import Any

from jobapi.kinds import Kind
from service.kinds import plugin_of


def type_text(prop: dict[str, Any], *, markdown: bool = False) -> str:
    """A JSON-schema property's type in words: ``integer``, ``array``, an enum's values
    (quoted in backticks for markdown), ``A or B`` for a union, a model's name for a ref."""
    quote = (lambda v: f"`{v}`") if markdown else str
    if "enum" in prop:
        return (" \\| " if markdown else " | ").join(quote(v) for v in prop["enum"])
    if "const" in prop:
        return quote(prop["const"])
    if "anyOf" in prop:
        return " or ".join(type_text(p, markdown=markdown) for p in prop["anyOf"])
    if "$ref" in prop:
        return str(prop["$ref"]).rsplit("/", 1)[-1]
    t = prop.get("type", "object")
    return "array" if t == "array" else str(t)


def param_rows(kind: Kind, *, markdown: bool = False) -> list[tuple[str, str, str, str]]:
    """``(name, type, default, description)`` of each of a kind's params, in schema order;
    the default is ``required`` for a required param."""
    schema = kind.params.model_json_schema()
    required = set(schema.get("required", []))
    rows = []
    for name, prop in schema.get("properties", {}).items():
        if name in required:
            default = "required"
        else:
            default = f"`{prop.get('default')!r}`" if markdown else repr(prop.get("default"))
        desc = " ".join(str(prop.get("description", "")).split())
        rows.append((name, type_text(prop, markdown=markdown), default, desc))
    return rows


def kind_document(kind: Kind) -> dict[str, Any]:
    """A kind as ``GET /api/kinds`` lists it: name, summary, artifacts, params schema, and
    ``plugin``: the package that added it (``None`` for a built-in kind)."""
    return {
        "name": kind.name,
        "summary": kind.description,
        "artifacts": list(kind.artifacts),
        "params_schema": kind.params.model_json_schema(),
        "plugin": plugin_of(kind.name),
    }
