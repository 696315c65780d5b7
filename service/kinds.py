"""The job kinds this service runs: the one explicit list of the modules that define them.

``service`` reaches the kinds' packages through :data:`BUILTIN_MODULES` only: each module
ends with ``register(Kind(...))`` (:mod:`jobapi.kinds`), and importing the list once fills
the registry. Nothing scans directories. To add a kind, write its module in the package of
its family (``generators/<family>/kind.py``, ``models/<model>/kind.py``, ...) and add it
here.
"""

from __future__ import annotations

import importlib
import threading

from jobapi.kinds import Kind, registered

#: Modules that register the built-in job kinds, in display order.
BUILTIN_MODULES: tuple[str, ...] = (
    "evaluators.render.kind",
    "evaluators.score.kind",
    "evaluators.tss.kind",
    "generators.merl.kind",
    "generators.fabric.kind",
    "generators.glint.kind",
    "generators.btf.kind",
    "generators.btf.importer",
    "models.btf.kind",
    "models.brdf.kind",
    "models.brdf.report_kind",
    "models.fabric.kind",
    "evaluators.report.kind",
    "evaluators.report.stability",
    "evaluators.report.select",
)

_lock = threading.Lock()
_loaded = False


def load_builtin() -> None:
    """Import the built-in kind modules once (thread-safe)."""
    global _loaded
    with _lock:
        if _loaded:
            return
        for module in BUILTIN_MODULES:
            importlib.import_module(module)
        _loaded = True


def get_kind(name: str) -> Kind:
    """The kind called ``name``; ``KeyError`` if there is none."""
    load_builtin()
    return registered()[name]


def all_kinds() -> dict[str, Kind]:
    """Every registered kind, by name."""
    load_builtin()
    return registered()
