"""``{"mitsuba": {<Mitsuba 3 BSDF plugin dict>}}``: any BSDF Mitsuba 3 builds in.

The dict is checked at spec time (a ``type`` string, no file paths anywhere in it) and
instantiated with ``mitsuba.load_dict`` inside the job.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Annotated, Any

from pydantic import AfterValidator

from evaluators.render.sources.common import register_material_source

if TYPE_CHECKING:
    import types

    from jobapi.context import JobContext

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
