"""Registration of our Python Mitsuba plugins, once per variant.

``mi.register_bsdf`` binds a plugin to the variant set when it is called, and the class
must subclass that variant's ``mi.BSDF``: so each plugin module has a ``_define_class(mi)``
and registers it through :func:`register_vectorised_bsdf` (or ``..._integrator``), which
defines and registers it once per variant and refuses variants our plugins are not written
for.
"""

from __future__ import annotations

import types
from collections.abc import Callable

_PLUGIN_CLASSES: dict[tuple[str, str, str], type] = {}


def _register_plugin(
    mi: types.ModuleType,
    plugin: str,
    name: str,
    define: Callable[[types.ModuleType], type],
    what: str,
) -> type:
    """``define(mi)`` and register it as a ``plugin`` (``"bsdf"`` or ``"integrator"``)
    named ``name`` for the current variant, once per variant; returns the class."""
    variant = mi.variant()
    cls = _PLUGIN_CLASSES.get((plugin, name, variant))
    if cls is None:
        if not variant.startswith(("llvm_", "cuda_")) or not variant.endswith("_rgb"):
            raise RuntimeError(
                f"the {what} needs a vectorised RGB Mitsuba variant such as llvm_ad_rgb, "
                f"but Mitsuba runs {variant!r}"
            )
        cls = define(mi)
        register = mi.register_bsdf if plugin == "bsdf" else mi.register_integrator
        register(name, lambda props: cls(props))
        _PLUGIN_CLASSES[(plugin, name, variant)] = cls
    return cls


def register_vectorised_bsdf(
    mi: types.ModuleType, name: str, define: Callable[[types.ModuleType], type], what: str
) -> type:
    """Define (``define(mi)``) and register a Python BSDF plugin ``name`` for Mitsuba's
    current variant, once per variant; returns the class.

    Our Python BSDFs are written for vectorised RGB variants (``llvm_ad_rgb``,
    ``cuda_ad_rgb``); under any other variant this raises ``RuntimeError`` naming ``what``.
    """
    return _register_plugin(mi, "bsdf", name, define, what)


def register_vectorised_integrator(
    mi: types.ModuleType, name: str, define: Callable[[types.ModuleType], type], what: str
) -> type:
    """:func:`register_vectorised_bsdf` for a Python integrator plugin ``name``."""
    return _register_plugin(mi, "integrator", name, define, what)
