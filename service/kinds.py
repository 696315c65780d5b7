"""The job kinds this service runs: the one explicit list of the modules that define them,
and the kinds of installed plugins.

``service`` reaches the kinds' packages through :data:`BUILTIN_MODULES` only: each module
ends with ``register(Kind(...))`` (:mod:`jobapi.kinds`), and importing the list once fills
the registry. Nothing scans directories. To add a kind, write its module in the package of
its family (``generators/<family>/kind.py``, ``models/<model>/kind.py``, ...) and add it
here.

Plugins: a package installed beside matforge adds kinds through the entry-point group
:data:`ENTRY_POINT_GROUP` (``matforge.kinds``). Each entry point names a module that
registers its kinds on import, exactly as a built-in kind module does
(``my-kind = "my_package.kind"``), or a :class:`~jobapi.kinds.Kind` object
(``"my_package.kind:KIND"``). They load after the built-in kinds, in the order of their
names. A plugin is code the operator installed; nothing that arrives over the API ever
picks what is imported here.

A broken plugin never takes the service down: one that fails to import, registers nothing,
registers a kind whose name is taken (by a built-in kind or an earlier plugin), or whose
params have no JSON schema, is logged, its registrations are undone, and it is listed with
its error by :func:`plugins` (``matforge kinds``, ``GET /api/plugins``). The other kinds
keep working.
"""

from __future__ import annotations

import importlib
import logging
import re
import threading
import types
from dataclasses import dataclass
from importlib.metadata import EntryPoint, entry_points
from typing import Any

from pydantic import BaseModel

from jobapi.kinds import Kind, register, registered, restore

log = logging.getLogger("matforge.kinds")

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
#: The entry-point group through which installed packages add kinds.
ENTRY_POINT_GROUP = "matforge.kinds"
#: What a plugin kind's name must look like: lowercase words joined by ``.``, ``_``, ``-``.
KIND_NAME = re.compile(r"^[a-z][a-z0-9_-]*(\.[a-z0-9_-]+)*$")
MAX_KIND_NAME = 64


@dataclass(frozen=True)
class Plugin:
    """One entry point of :data:`ENTRY_POINT_GROUP`, as loaded.

    Attributes:
        name: the entry point's name.
        value: what it points at (``"package.module"`` or ``"package.module:KIND"``).
        distribution: the installed distribution that declares it (``None`` if unknown).
        kinds: the kinds it registered (empty when it is broken).
        error: why it was not loaded, one line; ``None`` when it loaded.
    """

    name: str
    value: str
    distribution: str | None
    kinds: tuple[str, ...] = ()
    error: str | None = None

    def document(self) -> dict[str, Any]:
        """The JSON form (``GET /api/plugins``)."""
        return {
            "name": self.name,
            "value": self.value,
            "distribution": self.distribution,
            "kinds": list(self.kinds),
            "error": self.error,
        }


_lock = threading.RLock()
_loaded = False
_plugins: list[Plugin] | None = None
_builtin_names: frozenset[str] = frozenset()


def load_builtin() -> None:
    """Import the built-in kind modules once (thread-safe)."""
    global _loaded, _builtin_names
    with _lock:
        if _loaded:
            return
        for module in BUILTIN_MODULES:
            importlib.import_module(module)
        _builtin_names = frozenset(registered())
        _loaded = True


def load() -> None:
    """The built-in kinds, then the installed plugins' (once; thread-safe)."""
    load_builtin()
    load_plugins()


def _distribution(ep: EntryPoint) -> str | None:
    dist = getattr(ep, "dist", None)
    return getattr(dist, "name", None) if dist is not None else None


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _check_kind(kind: Any, builtin: frozenset[str], taken: dict[str, Kind]) -> str | None:
    """Why ``kind`` cannot be a plugin's kind, or ``None``."""
    if not isinstance(kind, Kind):
        return f"registered {type(kind).__name__!r}, not a jobapi.kinds.Kind"
    name = kind.name
    if not isinstance(name, str) or len(name) > MAX_KIND_NAME or not KIND_NAME.match(name):
        return (
            f"kind name {name!r} is not lowercase words joined by '.', '_' or '-' "
            f"(at most {MAX_KIND_NAME} characters)"
        )
    if name in builtin:
        return f"kind {name!r} collides with the built-in kind of that name"
    if name in taken:
        return f"kind {name!r} is already registered by an earlier plugin"
    if not (isinstance(kind.params, type) and issubclass(kind.params, BaseModel)):
        return f"kind {name!r}: params is not a pydantic model"
    if not callable(kind.runner):
        return f"kind {name!r}: runner is not callable"
    try:
        kind.params.model_json_schema()
    except Exception as exc:  # the OpenAPI document and `matforge kinds` need it
        return f"kind {name!r}: its params have no JSON schema: {_one_line(exc)}"
    return None


def _load_entry_point(ep: EntryPoint, builtin: frozenset[str]) -> Plugin:
    """Import one entry point and keep what it registered, or undo it all."""
    before = registered()
    dist = _distribution(ep)
    made: list[Any] = []
    error: str | None = None
    try:
        obj = ep.load()
    except (Exception, SystemExit) as exc:
        error = f"cannot import {ep.value!r}: {_one_line(exc)}"
        log.debug("plugin %s: import failed", ep.name, exc_info=True)
        obj = None
    after = registered()
    # Whatever the import registered (or replaced), in registration order.
    made = [k for n, k in after.items() if before.get(n) is not k]
    if error is None:
        if isinstance(obj, Kind):
            if obj not in made:
                made.append(obj)
        elif isinstance(obj, list | tuple) and all(isinstance(k, Kind) for k in obj):
            made += [k for k in obj if k not in made]
        elif not isinstance(obj, types.ModuleType):
            error = (
                f"{ep.value!r} is a {type(obj).__name__}; an entry point of "
                f"{ENTRY_POINT_GROUP} names a module that registers kinds, or a Kind"
            )
        if error is None and not made:
            error = f"{ep.value!r} registered no kind"
    if error is None:
        taken = {n: k for n, k in before.items() if n not in builtin}
        for kind in made:
            error = _check_kind(kind, builtin, taken)
            if error is not None:
                break
            taken[kind.name] = kind
    # Undo everything the import did to the registry, then add back what is kept.
    restore(before)
    if error is not None:
        log.error(
            "plugin %s (%s, from %s) not loaded: %s; the other kinds are unaffected",
            ep.name, ep.value, dist or "unknown distribution", error,
        )  # fmt: skip
        return Plugin(ep.name, ep.value, dist, (), error)
    for kind in made:
        register(kind)
    names = tuple(k.name for k in made)
    log.info("plugin %s (from %s): kinds %s", ep.name, dist or "?", ", ".join(names))
    return Plugin(ep.name, ep.value, dist, names, None)


def load_plugins() -> None:
    """Load every entry point of :data:`ENTRY_POINT_GROUP` once, after the built-in kinds;
    a broken one is logged and listed by :func:`plugins`, never raised."""
    global _plugins
    with _lock:
        if _plugins is not None:
            return
        load_builtin()
        found: list[Plugin] = []
        try:
            eps = sorted(entry_points(group=ENTRY_POINT_GROUP), key=lambda e: (e.name, e.value))
        except Exception as exc:  # a corrupt installed distribution's metadata
            log.error("cannot list the %s entry points: %s", ENTRY_POINT_GROUP, _one_line(exc))
            eps = []
        seen: set[str] = set()
        for ep in eps:
            if ep.name in seen:
                found.append(
                    Plugin(ep.name, ep.value, _distribution(ep), (),
                           f"another installed package declares entry point {ep.name!r} too")
                )  # fmt: skip
                log.error("plugin %s (%s): duplicate entry point name", ep.name, ep.value)
                continue
            seen.add(ep.name)
            found.append(_load_entry_point(ep, _builtin_names))
        _plugins = found


def plugins() -> list[Plugin]:
    """Every plugin entry point, loaded or broken (loads them first)."""
    load()
    return list(_plugins or [])


def plugin_of(name: str) -> str | None:
    """The distribution (or entry point) whose plugin registered kind ``name``, or
    ``None`` for a built-in kind."""
    for p in plugins():
        if name in p.kinds:
            return p.distribution or p.name
    return None


def get_kind(name: str) -> Kind:
    """The kind called ``name``; ``KeyError`` if there is none."""
    load()
    return registered()[name]


def all_kinds() -> dict[str, Kind]:
    """Every registered kind, by name: the built-in ones, then the plugins'."""
    load()
    return registered()
