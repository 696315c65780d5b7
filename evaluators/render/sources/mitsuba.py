"""``{"mitsuba": {<Mitsuba 3 BSDF plugin dict>}}``: any BSDF Mitsuba 3 builds in.

The dict is checked at spec time against the plugin names, conductor names and plugin
properties of the installed Mitsuba (listed in :mod:`evaluators.render.mitsuba_names`, so
the web process does not import Mitsuba), with no file paths anywhere in it, and
instantiated with ``mitsuba.load_dict`` inside the job.
"""

from __future__ import annotations

import difflib
from typing import TYPE_CHECKING, Annotated, Any

from pydantic import AfterValidator

from evaluators.render.mitsuba_names import (
    ANY_NAME_CHILDREN,
    BSDF_PLUGINS,
    CONDUCTOR_MATERIALS,
    MITSUBA_VERSION,
    OTHER_PLUGINS,
    PLUGIN_PROPERTIES,
    TEXTURE_PLUGINS,
)
from evaluators.render.sources.common import register_material_source

if TYPE_CHECKING:
    import types

    from jobapi.context import JobContext

#: Keys refused anywhere inside a ``{"mitsuba": ...}`` dict: they make Mitsuba open files on
#: the worker's disk. Materials made from files come in through artifact refs instead.
FORBIDDEN_KEYS = frozenset({"filename"})


#: Types Mitsuba's dict loader builds itself (not plugins): constant colours and spectra,
#: with the keys it takes besides ``type`` (its message: "'rgb' dictionary should contain 2
#: entries ('type' and either 'value' or 'filename')"; a test holds Mitsuba to it).
LOADER_PROPERTIES: dict[str, frozenset[str]] = {
    "rgb": frozenset({"value", "filename"}),
    "spectrum": frozenset({"value", "filename"}),
}
LOADER_TYPES = frozenset(LOADER_PROPERTIES)
#: Plugins whose string ``material`` names a conductor of Mitsuba's table.
CONDUCTOR_TYPES = frozenset({"conductor", "roughconductor"})
#: Words people type for a conductor, for the hint of the error (Mitsuba wants symbols).
CONDUCTOR_WORDS = {
    "gold": "Au",
    "silver": "Ag",
    "copper": "Cu",
    "aluminium": "Al",
    "aluminum": "Al",
    "chromium": "Cr",
    "chrome": "Cr",
    "tungsten": "W",
    "mercury": "Hg",
    "iridium": "Ir",
    "rhodium": "Rh",
    "tantalum": "Ta",
    "molybdenum": "Mo",
    "mirror": "none",
}


def _hint(value: str, known: frozenset[str]) -> str:
    by_case = {k.lower(): k for k in known}
    guess = by_case.get(value.lower()) or CONDUCTOR_WORDS.get(value.lower())
    if guess is None or guess not in known:
        close = difflib.get_close_matches(value, sorted(known), n=1, cutoff=0.75)
        guess = close[0] if close else None
    return f"; did you mean {guess!r}?" if guess else ""


def _check_type(node: dict[str, Any], path: str, top: bool) -> None:
    t = node.get("type")
    if not isinstance(t, str) or not t:
        if top:
            raise ValueError(
                'a Mitsuba plugin dict needs a \'type\' string, e.g. {"type": "diffuse"}'
            )
        return
    allowed = BSDF_PLUGINS if top else BSDF_PLUGINS | TEXTURE_PLUGINS | LOADER_TYPES
    if t in allowed:
        return
    what = "BSDF plugin" if top else "BSDF, texture or colour type"
    if t in BSDF_PLUGINS | TEXTURE_PLUGINS | OTHER_PLUGINS:
        raise ValueError(f"{path}type: {t!r} is a Mitsuba plugin, but not a {what}")
    listed = ", ".join(sorted(BSDF_PLUGINS if top else allowed))
    raise ValueError(
        f"{path}type: unknown Mitsuba {what} {t!r}{_hint(t, allowed)} "
        f"(Mitsuba {MITSUBA_VERSION} has: {listed})"
    )


def _check_conductor(node: dict[str, Any], path: str) -> None:
    name = node.get("material")
    if node.get("type") not in CONDUCTOR_TYPES or not isinstance(name, str):
        return
    if name not in CONDUCTOR_MATERIALS:
        raise ValueError(
            f"{path}material: unknown conductor {name!r}{_hint(name, CONDUCTOR_MATERIALS)} "
            f"(Mitsuba's named conductors: {', '.join(sorted(CONDUCTOR_MATERIALS))})"
        )


def _check_properties(node: dict[str, Any], path: str) -> None:
    """Refuse a key that the node's plugin does not read, as Mitsuba would in the job
    ("unreferenced property"). A plugin that takes nested plugins under any key
    (``twosided``, ``blendbsdf``, ...) takes any key whose value is a plugin dict; a plugin
    whose properties could not be probed (``bitmap``, ...) is left to Mitsuba."""
    t = node.get("type")
    if not isinstance(t, str):
        return
    known = PLUGIN_PROPERTIES.get(t) or LOADER_PROPERTIES.get(t)
    if known is None:
        return
    for key, value in node.items():
        if key == "type" or key in known or key in FORBIDDEN_KEYS:
            continue
        if t in ANY_NAME_CHILDREN and isinstance(value, dict) and "type" in value:
            continue
        raise ValueError(
            f"{path}{key}: unknown property {key!r} of Mitsuba's {t!r} plugin"
            f"{_hint(key, known)} ({t} reads: {', '.join(sorted(known))})"
        )


def _check_plugin_dict(value: dict[str, Any]) -> dict[str, Any]:
    """Check a ``{"mitsuba": ...}`` dict against the names Mitsuba knows
    (:mod:`evaluators.render.mitsuba_names`, generated from Mitsuba and checked against it
    by a test), so that a typo is refused before queueing, not in the worker: the top
    ``type`` is a BSDF plugin, nested ``type``s are BSDFs, textures or ``rgb`` /
    ``spectrum``, every key is a property the plugin reads (``"alpah"`` is refused with
    "did you mean 'alpha'?"), a conductor's ``material`` is in Mitsuba's table, and no
    ``filename``."""

    def walk(node: Any, path: str, top: bool = False) -> None:
        if isinstance(node, dict):
            _check_type(node, path, top)
            _check_conductor(node, path)
            _check_properties(node, path)
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

    walk(value, "", top=True)
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
