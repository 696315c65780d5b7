"""Material sources: the one extension point from a ``material`` param to a Mitsuba BSDF.

A ``material`` param is an object with exactly one key, the *source*, whose value says
where the material comes from::

    {"mitsuba": {"type": "roughconductor", "alpha": 0.2}}     # a Mitsuba 3 BSDF plugin dict
    {"merl": "sha256:..."}                                     # later: a measured MERL table
    {"model": "job:.../model.pt", ...}                         # later: a fitted model

Each source is registered once with :func:`register_material_source`: a pydantic type for
its value (checked when the spec is validated, before anything is queued) and a resolver
``(value, ctx, mi) -> BSDF dict or mi.BSDF`` that runs inside the job. Nothing else in the
code base knows the list of sources; the ``material`` field of a params model is simply
:data:`MaterialParam`.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Annotated, Any

from pydantic import (
    AfterValidator,
    GetCoreSchemaHandler,
    GetJsonSchemaHandler,
    TypeAdapter,
    ValidationError,
)
from pydantic.json_schema import JsonSchemaValue
from pydantic_core import PydanticCustomError, core_schema

from service.errors import JobFailed

if TYPE_CHECKING:
    import types

    from service.context import JobContext

#: ``resolver(value, ctx, mi)``: returns a Mitsuba BSDF plugin dict or an instantiated BSDF.
Resolver = Callable[[Any, "JobContext", "types.ModuleType"], Any]


@dataclass(frozen=True)
class MaterialSource:
    """A registered material source.

    Attributes:
        key: the source's key in a ``material`` object, e.g. ``"mitsuba"``.
        value_type: the pydantic type of the key's value (validated at spec time).
        resolver: turns a validated value into a Mitsuba BSDF inside the job.
        summary: one line for documentation and the OpenAPI schema.
    """

    key: str
    value_type: Any
    resolver: Resolver
    summary: str
    adapter: TypeAdapter[Any] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        # Built once: validating a spec must not rebuild pydantic's schema every time.
        object.__setattr__(self, "adapter", TypeAdapter(self.value_type))


_SOURCES: dict[str, MaterialSource] = {}


def register_material_source(
    key: str, resolver: Resolver, *, value_type: Any, summary: str
) -> MaterialSource:
    """Register a material source under ``key`` (re-registering a key replaces it)."""
    if not re.fullmatch(r"[a-z][a-z0-9_]{0,31}", key):
        raise ValueError(f"material source keys are short lower-case identifiers, got {key!r}")
    source = MaterialSource(key=key, value_type=value_type, resolver=resolver, summary=summary)
    _SOURCES[key] = source
    return source


def material_sources() -> dict[str, MaterialSource]:
    """The registered material sources, by key."""
    return dict(_SOURCES)


# -- the params type -----------------------------------------------------------------------


def _invalid(message: str) -> PydanticCustomError:
    # A custom error type keeps pydantic from prefixing "Value error, " to the message.
    return PydanticCustomError("material", message)


def _validate_material(value: Any) -> dict[str, Any]:
    if not isinstance(value, Mapping):
        raise _invalid(
            f"must be an object with one material source key, e.g. "
            f'{{"mitsuba": {{"type": "diffuse"}}}}; got {type(value).__name__}'
        )
    known = ", ".join(sorted(_SOURCES)) or "none registered"
    if len(value) != 1:
        given = ", ".join(map(repr, value)) or "none"
        raise _invalid(f"must have exactly one material source key (one of: {known}); got {given}")
    ((key, inner),) = value.items()
    source = _SOURCES.get(key)
    if source is None:
        raise _invalid(f"unknown material source {key!r}; known: {known}")
    try:
        checked = source.adapter.validate_python(inner, strict=True)
    except ValidationError as exc:
        first = exc.errors()[0]
        loc = ".".join(str(p) for p in (key, *first.get("loc", ())))
        msg = first["msg"].removeprefix("Value error, ")
        raise _invalid(f"{loc}: {msg}") from None
    return {key: checked}


class _MaterialSchema:
    """Pydantic hooks of :data:`MaterialParam`: validate against the registry as it is at
    validation time, and describe the registered sources in the JSON schema."""

    def __get_pydantic_core_schema__(
        self, source: Any, handler: GetCoreSchemaHandler
    ) -> core_schema.CoreSchema:
        return core_schema.no_info_plain_validator_function(_validate_material)

    def __get_pydantic_json_schema__(
        self, schema: core_schema.CoreSchema, handler: GetJsonSchemaHandler
    ) -> JsonSchemaValue:
        options = []
        for key, src in sorted(_SOURCES.items()):
            inner = src.adapter.json_schema()
            options.append(
                {
                    "type": "object",
                    "title": key,
                    "description": src.summary,
                    "properties": {key: inner},
                    "required": [key],
                    "additionalProperties": False,
                }
            )
        return {"oneOf": options} if options else {"type": "object"}


#: The type of a ``material`` field: ``{"<source>": <value>}`` with exactly one key.
MaterialParam = Annotated[dict[str, Any], _MaterialSchema()]


# -- resolving inside a job ----------------------------------------------------------------


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    line = text.splitlines()[0] if text else type(exc).__name__
    # Mitsuba prefixes messages with source locations: "[parser.cpp:1718] At ...".
    return re.sub(r"\[[A-Za-z0-9_]+\.(?:cpp|h|py):\d+\]\s*", "", line).strip()


def load_bsdf(plugin: Any, mi: types.ModuleType, where: str) -> Any:
    """Instantiate a Mitsuba BSDF from a plugin dict (or check an instantiated object).

    ``where`` names the param in error messages, e.g. ``"material.mitsuba"``. Raises
    :class:`JobFailed` with Mitsuba's own first line when the dict is not a valid BSDF.
    """
    obj = plugin
    if isinstance(plugin, Mapping):
        try:
            obj = mi.load_dict(dict(plugin))
        except Exception as exc:  # Mitsuba raises RuntimeError/TypeError with C++ text
            raise JobFailed(f"{where}: {_first_line(exc)}") from None
    if not isinstance(obj, mi.BSDF):
        kind = type(obj).__name__
        raise JobFailed(f"{where}: plugin is a {kind}, not a BSDF")
    return obj


def resolve_material(material: Mapping[str, Any], ctx: JobContext, mi: types.ModuleType) -> Any:
    """Turn a validated ``material`` param into an instantiated ``mi.BSDF``."""
    ((key, value),) = material.items()
    source = _SOURCES.get(key)
    if source is None:
        raise JobFailed(f"material: unknown material source {key!r}")
    return load_bsdf(source.resolver(value, ctx, mi), mi, f"material.{key}")


# -- the built-in source: a Mitsuba 3 plugin dict ----------------------------------------

#: Keys refused anywhere inside a ``{"mitsuba": ...}`` dict: they make Mitsuba open files on
#: the worker's disk. Materials made from files come in through artifact refs instead.
FORBIDDEN_KEYS = frozenset({"filename"})


def _check_plugin_dict(value: dict[str, Any]) -> dict[str, Any]:
    if not isinstance(value.get("type"), str) or not value["type"]:
        raise ValueError('a Mitsuba plugin dict needs a \'type\' string, e.g. {"type": "diffuse"}')

    def walk(node: Any, path: str) -> None:
        if isinstance(node, dict):
            for k, v in node.items():
                if k in FORBIDDEN_KEYS:
                    raise ValueError(
                        f"{path}{k}: file paths are not allowed in a Mitsuba "
                        f"dict; bring files in as artifact references"
                    )
                walk(v, f"{path}{k}.")
        elif isinstance(node, list):
            for i, v in enumerate(node):
                walk(v, f"{path}{i}.")

    walk(value, "")
    return value


def _resolve_mitsuba(
    value: dict[str, Any], ctx: JobContext, mi: types.ModuleType
) -> dict[str, Any]:
    return value


register_material_source(
    "mitsuba",
    _resolve_mitsuba,
    value_type=Annotated[dict[str, Any], AfterValidator(_check_plugin_dict)],
    summary='A Mitsuba 3 BSDF plugin dict, e.g. {"type": "roughconductor", '
    '"alpha": 0.2}; instantiated with mitsuba.load_dict in the job.',
)
