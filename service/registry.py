"""The registry of job kinds: kind name → params model, runner and smoke params.

A job kind is exactly three things: a params model, a runner registered here under its
name, and its tests. Kind modules end with one registration line::

    register(Kind(name="render", params=RenderParams, runner=run_render, ...))

The built-in kinds are imported from the explicit list :data:`BUILTIN_MODULES`; the
registry never scans directories.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from pydantic import BaseModel

if TYPE_CHECKING:
    from service.context import JobContext

#: Modules that register the built-in job kinds, in display order.
BUILTIN_MODULES: tuple[str, ...] = (
    "evaluators.render",
    "evaluators.score",
    "generators.merl",
    "generators.fabric",
    "models.brdf.kind",
    "models.brdf.report_kind",
    "models.fabric.kind",
)

Runner = Callable[[Any, "JobContext"], None]


@dataclass(frozen=True)
class Kind:
    """One job kind.

    Attributes:
        name: the ``kind`` of a spec, e.g. ``"render"``.
        params: strict pydantic model of ``params`` (``extra="forbid"``).
        runner: ``runner(params, ctx)``; writes artifacts through ``ctx``.
        summary: one line for the README table and the OpenAPI description.
        artifacts: the fixed artifact names (``"<name>.binary"`` style patterns allowed).
        smoke: tiny params that run in seconds; the parametrised registry test runs them.
    """

    name: str
    params: type[BaseModel]
    runner: Runner
    summary: str
    artifacts: tuple[str, ...] = ()
    smoke: dict[str, Any] = field(default_factory=dict)


_KINDS: dict[str, Kind] = {}
_loaded = False


def register(kind: Kind) -> Kind:
    """Add ``kind`` to the registry (re-registering the same name replaces it)."""
    _KINDS[kind.name] = kind
    return kind


def load_builtin() -> None:
    """Import the built-in kind modules once."""
    global _loaded
    if _loaded:
        return
    for module in BUILTIN_MODULES:
        importlib.import_module(module)
    _loaded = True


def get(name: str) -> Kind:
    """The kind called ``name``; ``KeyError`` if there is none."""
    load_builtin()
    return _KINDS[name]


def kinds() -> dict[str, Kind]:
    """All registered kinds, by name."""
    load_builtin()
    return dict(_KINDS)
