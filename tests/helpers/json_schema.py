"""A small JSON Schema (draft 2020-12) checker for the keywords our format schemas use.

``jsonschema`` is not a dependency of matforge; the schemas in ``storage/formats/schemas/``
use only: ``type``, ``const``, ``enum``, ``properties``, ``required``,
``additionalProperties`` (a boolean or a schema), ``items``, ``minItems``, ``maxItems``,
``minimum``, ``maximum``, ``exclusiveMinimum``, ``maxLength``, ``anyOf`` and local
``$ref`` (``#/$defs/...``). Anything else in a schema is an error here, so that a schema
cannot silently use a keyword this checker ignores (annotations excepted).
"""

from __future__ import annotations

from typing import Any

_ANNOTATIONS = {"$schema", "$id", "title", "description", "$defs", "contentEncoding"}
_TYPES = {
    "object": lambda v: isinstance(v, dict),
    "array": lambda v: isinstance(v, list),
    "string": lambda v: isinstance(v, str),
    "integer": lambda v: isinstance(v, int) and not isinstance(v, bool),
    "number": lambda v: isinstance(v, (int, float)) and not isinstance(v, bool),
    "boolean": lambda v: isinstance(v, bool),
    "null": lambda v: v is None,
}


def errors(
    schema: dict[str, Any], value: Any, root: dict[str, Any] | None = None, path: str = "$"
) -> list[str]:
    """Every violation of ``schema`` by ``value``, as ``"<json path>: <what>"``."""
    root = root if root is not None else schema
    out: list[str] = []
    for key, arg in schema.items():
        if key in _ANNOTATIONS or key in ("minimum", "maximum", "exclusiveMinimum"):
            continue
        if key == "$ref":
            assert arg.startswith("#/$defs/"), arg
            out += errors(root["$defs"][arg.rsplit("/", 1)[1]], value, root, path)
        elif key == "type":
            if not _TYPES[arg](value):
                out.append(f"{path}: not of type {arg}")
        elif key == "const":
            if value != arg:
                out.append(f"{path}: not {arg!r}")
        elif key == "enum":
            if value not in arg:
                out.append(f"{path}: {value!r} not one of {arg}")
        elif key == "anyOf":
            if all(errors(s, value, root, path) for s in arg):
                out.append(f"{path}: matches none of the anyOf schemas")
        elif key == "required":
            if isinstance(value, dict):
                out += [f"{path}: missing {k!r}" for k in arg if k not in value]
        elif key == "properties":
            if isinstance(value, dict):
                for k, s in arg.items():
                    if k in value:
                        out += errors(s, value[k], root, f"{path}.{k}")
        elif key == "additionalProperties":
            if isinstance(value, dict):
                extra = [k for k in value if k not in schema.get("properties", {})]
                for k in extra:
                    if arg is False:
                        out.append(f"{path}: unexpected key {k!r}")
                    elif isinstance(arg, dict):
                        out += errors(arg, value[k], root, f"{path}.{k}")
        elif key == "items":
            if isinstance(value, list):
                for i, v in enumerate(value):
                    out += errors(arg, v, root, f"{path}[{i}]")
        elif key in ("minItems", "maxItems", "maxLength"):
            if isinstance(value, (list, str)):
                n = len(value)
                if (key == "minItems" and n < arg) or (key != "minItems" and n > arg):
                    out.append(f"{path}: {key} {arg} violated ({n})")
        else:
            raise AssertionError(f"schema keyword {key!r} is not supported by this checker")
    if _TYPES["number"](value):
        if "minimum" in schema and value < schema["minimum"]:
            out.append(f"{path}: below the minimum {schema['minimum']}")
        if "maximum" in schema and value > schema["maximum"]:
            out.append(f"{path}: above the maximum {schema['maximum']}")
        if "exclusiveMinimum" in schema and value <= schema["exclusiveMinimum"]:
            out.append(f"{path}: not above {schema['exclusiveMinimum']}")
    return out
