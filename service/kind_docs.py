"""Kinds described for people, from the registry: the README's table of kinds
(``scripts/kinds_table.py``) and ``matforge kinds`` share these."""

from __future__ import annotations

import copy
import threading
from typing import Any

from pydantic import BaseModel

from jobapi.kinds import Kind
from service.kinds import plugin_of

_SCHEMAS: dict[type[BaseModel], dict[str, Any]] = {}
_SCHEMAS_LOCK = threading.Lock()


def params_schema(kind: Kind) -> dict[str, Any]:
    """The JSON schema of a kind's params (a copy: the caller may change it), made once per
    params model: making one builds a pydantic validator per default value, which a
    request must not do (the server makes them all at start, :func:`prepare`)."""
    schema = _SCHEMAS.get(kind.params)
    if schema is None:
        with _SCHEMAS_LOCK:
            schema = _SCHEMAS.get(kind.params)
            if schema is None:
                schema = _SCHEMAS[kind.params] = kind.params.model_json_schema()
    return copy.deepcopy(schema)


def prepare(kinds: list[Kind]) -> None:
    """Make the params schemas of these kinds now (:func:`params_schema`); a kind whose
    params have none is left to fail where its schema is asked for."""
    for kind in kinds:
        try:
            params_schema(kind)
        except Exception:  # the plugin loader refuses such kinds; a test's may slip in
            continue


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
    return _rows(params_schema(kind), markdown=markdown)


def _refs(node: Any) -> list[str]:
    """The names of the ``$defs`` models that ``node`` refers to, in order of appearance."""
    if isinstance(node, dict):
        own = [str(node["$ref"]).rsplit("/", 1)[-1]] if "$ref" in node else []
        return own + [r for v in node.values() for r in _refs(v)]
    if isinstance(node, list):
        return [r for v in node for r in _refs(v)]
    return []


def nested_models(kind: Kind) -> list[tuple[str, str, list[tuple[str, str, str, str]]]]:
    """``(model name, description, rows)`` of each model that a kind's params nest (the
    ``ProceduralExample`` of ``generate.glint``'s ``example``, and the models inside it), in
    the order they are first named, with rows as :func:`param_rows` gives them: the fields
    and allowed values that a param's type names only by its model's name."""
    schema = params_schema(kind)
    defs = schema.get("$defs", {})
    order: list[str] = []
    todo = _refs(schema.get("properties", {}))
    while todo:
        name = todo.pop(0)
        if name in order or name not in defs:
            continue
        order.append(name)
        todo.extend(_refs(defs[name].get("properties", {})))
    return [
        (
            name,
            " ".join(str(defs[name].get("description", "")).split()),
            _rows(defs[name]),
        )
        for name in order
        if defs[name].get("properties")
    ]


def param_forms(kind: Kind) -> list[tuple[str, list[tuple[str, str]]]]:
    """``(param, [(form, description)])`` of each param that takes one of several object
    forms (a ``material``: one per registered material source, ``mitsuba``, ``merl``,
    ``external``, ...), in schema order: what ``matforge kinds KIND`` lists under the
    params, since the params table can call such a param only an ``object``."""
    schema = params_schema(kind)
    defs = schema.get("$defs", {})
    out = []
    for name, prop in schema.get("properties", {}).items():
        forms = []
        for alt in prop.get("oneOf", ()):
            while "$ref" in alt:
                alt = defs.get(str(alt["$ref"]).rsplit("/", 1)[-1], {})
            if alt.get("title"):
                forms.append((str(alt["title"]), " ".join(str(alt.get("description", "")).split())))
        if forms:
            out.append((name, forms))
    return out


def _rows(schema: dict[str, Any], *, markdown: bool = False) -> list[tuple[str, str, str, str]]:
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
        "params_schema": params_schema(kind),
        "plugin": plugin_of(kind.name),
    }
