"""Material sources: the one extension point from a ``material`` param to a Mitsuba BSDF.

A ``material`` param is an object with exactly one *source* key, whose value says where
the material comes from::

    {"mitsuba": {"type": "roughconductor", "alpha": 0.2}}     # a Mitsuba 3 BSDF plugin dict
    {"merl": "sha256:..."}                                     # a measured MERL table
    {"model": "job:<id>/model.json", "material": "gold"}       # one material of a model

Each source is registered once with :func:`register_material_source`: a pydantic type for
its value (checked when the spec is validated, before anything is queued) and a resolver
``(value, ctx, mi) -> BSDF dict or mi.BSDF`` that runs inside the job. Nothing else in the
code base knows the list of sources; the ``material`` field of a params model is simply
:data:`MaterialParam`.

Result rows: a source may declare ``row_facts(src, material) -> MaterialRowFacts``, what a
render of its material adds to the render's result rows and to the rows of images scored
against it (its ``config`` entries, its ``bytes_per_material``); ``src`` is the render job
(:class:`jobapi.rows.RowSource`), ``material`` the render's whole ``material`` object as
the spec holds it. :func:`evaluators.render.rows.render_facts` asks the source; it never
names one.

Sibling keys: a source may declare a pydantic model of *sibling* keys that sit next to its
key in the same object (``"material"`` above). The object then has exactly one source key
plus any of that source's siblings, and the source's resolver receives the whole validated
object ``{key: value, **siblings}`` instead of the value alone. Sources without siblings
keep the strict one-key form. The siblings are validated with the source's own value as
pydantic's validation context (``info.context == {key: value}``), so that what they allow
may depend on it. A sibling may share its name with another source
(``{"model": REF, "fabric": {...}}``): when one source key's siblings cover all the other
source keys present, that source owns the object.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Annotated, Any

from pydantic import (
    BaseModel,
    GetCoreSchemaHandler,
    GetJsonSchemaHandler,
    TypeAdapter,
    ValidationError,
)
from pydantic.json_schema import JsonSchemaValue
from pydantic_core import PydanticCustomError, core_schema

from jobapi.errors import JobFailed

if TYPE_CHECKING:
    import types

    from jobapi.context import JobContext
    from jobapi.rows import RowSource

#: ``resolver(value, ctx, mi)``: returns a Mitsuba BSDF plugin dict or an instantiated BSDF.
Resolver = Callable[[Any, "JobContext", "types.ModuleType"], Any]


@dataclass(frozen=True)
class MaterialRowFacts:
    """What a render's material adds to its result rows: ``config`` entries (merged into
    the row's ``config``) and the memory of the material, ``bytes_per_material``
    (``None``: unknown)."""

    config: dict[str, Any]
    bytes_per_material: float | None = None


#: ``row_facts(src, material)``: see the module docstring.
RowFacts = Callable[["RowSource", Mapping[str, Any]], MaterialRowFacts]


@dataclass(frozen=True)
class MaterialSource:
    """A registered material source.

    Attributes:
        key: the source's key in a ``material`` object, e.g. ``"mitsuba"``.
        value_type: the pydantic type of the key's value (validated at spec time).
        resolver: turns a validated value into a Mitsuba BSDF inside the job.
        summary: one line for documentation and the OpenAPI schema.
        siblings: a pydantic model of the keys allowed next to ``key`` (``None``: none);
            when set, the resolver receives the whole object ``{key: value, **siblings}``.
        row_facts: what a render of the material adds to result rows (``None``: nothing).
    """

    key: str
    value_type: Any
    resolver: Resolver
    summary: str
    siblings: type[BaseModel] | None = None
    row_facts: RowFacts | None = None
    adapter: TypeAdapter[Any] = field(init=False, repr=False, compare=False)
    sibling_adapter: TypeAdapter[Any] | None = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        # Built once: validating a spec must not rebuild pydantic's schema every time.
        object.__setattr__(self, "adapter", TypeAdapter(self.value_type))
        sib = None if self.siblings is None else TypeAdapter(self.siblings)
        object.__setattr__(self, "sibling_adapter", sib)


_SOURCES: dict[str, MaterialSource] = {}


def register_material_source(
    key: str,
    resolver: Resolver,
    *,
    value_type: Any,
    summary: str,
    siblings: type[BaseModel] | None = None,
    row_facts: RowFacts | None = None,
) -> MaterialSource:
    """Register a material source under ``key`` (re-registering a key replaces it).

    ``siblings`` (optional) is a pydantic model of the extra keys the source allows next to
    its own, ``row_facts`` (optional) what its renders add to result rows; see the module
    docstring.
    """
    if not re.fullmatch(r"[a-z][a-z0-9_]{0,31}", key):
        raise ValueError(f"material source keys are short lower-case identifiers, got {key!r}")
    if siblings is not None and key in siblings.model_fields:
        raise ValueError(f"material source {key!r} cannot also be one of its sibling keys")
    source = MaterialSource(
        key=key,
        value_type=value_type,
        resolver=resolver,
        summary=summary,
        siblings=siblings,
        row_facts=row_facts,
    )
    _SOURCES[key] = source
    return source


def material_sources() -> dict[str, MaterialSource]:
    """The registered material sources, by key."""
    return dict(_SOURCES)


# -- the params type -----------------------------------------------------------------------


def _invalid(message: str) -> PydanticCustomError:
    # A custom error type keeps pydantic from prefixing "Value error, " to the message.
    return PydanticCustomError("material", message)


def _source_keys(value: Mapping[str, Any]) -> list[str]:
    """The source keys in ``value``; when one source takes the others as sibling keys
    (``"model"`` with a ``"fabric"`` sibling), that source alone."""
    keys = [k for k in value if k in _SOURCES]
    if len(keys) > 1:
        owners = [
            k
            for k in keys
            if (sib := _SOURCES[k].siblings) is not None
            and all(o in sib.model_fields for o in keys if o != k)
        ]
        if len(owners) == 1:
            return owners
    return keys


def _validate_material(value: Any) -> dict[str, Any]:
    if not isinstance(value, Mapping):
        raise _invalid(
            f"must be an object with one material source key, e.g. "
            f'{{"mitsuba": {{"type": "diffuse"}}}}; got {type(value).__name__}'
        )
    known = ", ".join(sorted(_SOURCES)) or "none registered"
    keys = _source_keys(value)
    if len(value) == 1 and not keys:
        raise _invalid(f"unknown material source {next(iter(value))!r}; known: {known}")
    source = _SOURCES[keys[0]] if len(keys) == 1 else None
    if source is None or (len(value) != 1 and source.siblings is None):
        given = ", ".join(map(repr, value)) or "none"
        raise _invalid(f"must have exactly one material source key (one of: {known}); got {given}")
    key = source.key
    checked = {key: _checked(key, source.adapter, value[key])}
    if source.siblings is not None and source.sibling_adapter is not None:
        rest = {k: v for k, v in value.items() if k != key}
        allowed = ", ".join(source.siblings.model_fields)
        for k in rest:
            if k not in source.siblings.model_fields:
                raise _invalid(f"{k}: not a key of a {key!r} material (allowed: {key}, {allowed})")
        # The source's own (checked) value travels as validation context: a sibling model
        # may depend on it (``model``: a whole-job ref is a BTF model, which takes no
        # ``material``).
        siblings = _checked(None, source.sibling_adapter, rest, context={key: checked[key]})
        checked.update(siblings.model_dump(exclude_none=True))
    return checked


def _checked(
    key: str | None, adapter: TypeAdapter[Any], value: Any, context: dict[str, Any] | None = None
) -> Any:
    """``adapter.validate_python(value, strict=True)``, errors as one ``loc: msg`` line;
    ``context`` is pydantic's validation context (``ValidationInfo.context``)."""
    try:
        return adapter.validate_python(value, strict=True, context=context)
    except ValidationError as exc:
        first = exc.errors()[0]
        loc = ".".join(str(p) for p in (key, *first.get("loc", ())) if p is not None)
        msg = first["msg"].removeprefix("Value error, ")
        if first["type"] == "missing":
            msg = "this key is required"
        raise _invalid(f"{loc}: {msg}" if loc else msg) from None


def inline_schema(model: type[BaseModel]) -> dict[str, Any]:
    """``model``'s JSON schema with its ``$defs`` inlined where they are referenced: a
    material value's schema is embedded in the ``material`` schema, which has no ``$defs``
    of its own."""
    schema = model.model_json_schema()
    defs = schema.pop("$defs", {})

    def inline(node: Any) -> Any:
        if isinstance(node, dict):
            ref = node.get("$ref")
            if isinstance(ref, str) and ref.startswith("#/$defs/"):
                return inline(
                    {
                        **defs[ref.rsplit("/", 1)[-1]],
                        **{k: v for k, v in node.items() if k != "$ref"},
                    }
                )
            return {k: inline(v) for k, v in node.items()}
        if isinstance(node, list):
            return [inline(v) for v in node]
        return node

    result: dict[str, Any] = inline(schema)
    return result


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
            properties = {key: src.adapter.json_schema()}
            required = [key]
            if src.siblings is not None:
                extra = src.siblings.model_json_schema()
                properties.update(extra.get("properties", {}))
                required += extra.get("required", [])
            options.append(
                {
                    "type": "object",
                    "title": key,
                    "description": src.summary,
                    "properties": properties,
                    "required": required,
                    "additionalProperties": False,
                }
            )
        return {"oneOf": options} if options else {"type": "object"}


#: The type of a ``material`` field: ``{"<source>": <value>}`` with exactly one source key
#: (plus that source's sibling keys, if it declares any).
MaterialParam = Annotated[dict[str, Any], _MaterialSchema()]


# -- resolving inside a job ----------------------------------------------------------------


def mitsuba_message(exc: BaseException) -> str:
    """Mitsuba's whole message on one line: its lines joined (the name of an unreferenced
    property is on the second line: "Found 1 unreferenced property in bsdf plugin of type
    "roughconductor":" then "- float "alpah": 0.2"), without its source locations."""
    text = " ".join(str(exc).split())
    if not text:
        return type(exc).__name__
    # Mitsuba prefixes messages with source locations: "[parser.cpp:1718] At ...".
    return re.sub(r"\[[A-Za-z0-9_]+\.(?:cpp|h|py):\d+\]\s*", "", text).strip()


def load_bsdf(plugin: Any, mi: types.ModuleType, where: str) -> Any:
    """Instantiate a Mitsuba BSDF from a plugin dict (or check an instantiated object).

    ``where`` names the param in error messages, e.g. ``"material.mitsuba"``. Raises
    :class:`JobFailed` with Mitsuba's whole message, on one line, when the dict is not a
    valid BSDF.
    """
    obj = plugin
    if isinstance(plugin, Mapping):
        try:
            obj = mi.load_dict(dict(plugin))
        except Exception as exc:  # Mitsuba raises RuntimeError/TypeError with C++ text
            raise JobFailed(f"{where}: {mitsuba_message(exc)}") from None
    if not isinstance(obj, mi.BSDF):
        kind = type(obj).__name__
        raise JobFailed(f"{where}: plugin is a {kind}, not a BSDF")
    return obj


def resolve_material(material: Mapping[str, Any], ctx: JobContext, mi: types.ModuleType) -> Any:
    """Turn a validated ``material`` param into an instantiated ``mi.BSDF``."""
    keys = _source_keys(material)
    if len(keys) != 1:
        raise JobFailed(f"material: no single known material source in {sorted(material)}")
    source = _SOURCES[keys[0]]
    value = dict(material) if source.siblings is not None else material[source.key]
    return load_bsdf(source.resolver(value, ctx, mi), mi, f"material.{source.key}")
