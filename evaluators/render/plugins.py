"""Registration of our Python Mitsuba plugins, once per variant.

``mi.register_bsdf`` binds a plugin to the variant set when it is called, and the class
must subclass that variant's ``mi.BSDF``: so each plugin module defines its plugin as a
module-level :class:`VariantPlugin` (the body) and
registers it through :func:`register_vectorised_bsdf` (or ``..._integrator``), which makes
the per-variant class (:func:`class_for_variant`, the one cache of them),
registers it once per variant and refuses variants our plugins are not written for.
"""

from __future__ import annotations

import types
from typing import Any, ClassVar

#: Classes made by :func:`class_for_variant`, by (body class, Mitsuba variant).
_VARIANT_CLASSES: dict[tuple[str, str], type] = {}


class VariantPlugin:
    """The body of one of our Python Mitsuba plugins, written at module level.

    A Python plugin must derive from a class of Mitsuba's *current variant* (``mi.BSDF``,
    ``mi.SamplingIntegrator``, ...), which exists only once Mitsuba is loaded, so its
    methods live in a plain class derived from this one, where mypy and IDEs see them, and
    :func:`class_for_variant` makes the class Mitsuba instantiates, once per variant.

    Rules for a body (the class Mitsuba instantiates derives from the Mitsuba class alone,
    with the body's methods copied into it; nanobind allows a single base):

    - reach Mitsuba and Dr.Jit through :attr:`mi` and :attr:`dr` (the top-level ``mitsuba``
      and ``drjit`` modules, whose types follow the variant), typically as
      ``mi, dr = self.mi, self.dr`` on a method's first line;
    - call a base body's method by name, e.g. ``MixtureReflector.__init__(self, props)``,
      never ``super()`` (its class would be the body, not the class Mitsuba made):
      :func:`class_for_variant` refuses a body that does;
    - the body itself is never instantiated, and ``isinstance(obj, Body)`` is false.
    """

    #: The ``mitsuba`` module (from :func:`materials.backend.load_mitsuba`), bound per variant.
    mi: ClassVar[types.ModuleType]
    #: The ``drjit`` module, bound per variant.
    dr: ClassVar[types.ModuleType]

    @classmethod
    def mitsuba_base(cls, mi: types.ModuleType) -> type:
        """The Mitsuba class the plugin extends under ``mi``'s current variant: ``mi.BSDF``
        (an integrator overrides this)."""
        base: type = mi.BSDF
        return base

    def __init__(self, props: Any) -> None:
        base: Any = self.mitsuba_base(self.mi)
        base.__init__(self, props)


#: Names of a body's namespace that are not copied into the class Mitsuba instantiates.
_NOT_COPIED = frozenset(
    ("__dict__", "__weakref__", "__module__", "__qualname__", "__doc__", "__annotations__")
)


def class_for_variant(mi: types.ModuleType, body: type[VariantPlugin]) -> type:
    """The class Mitsuba instantiates for ``body`` under its current variant, made once per
    variant and then reused: derived from ``body.mitsuba_base(mi)``, holding the methods
    and attributes of ``body`` and of its bases up to :class:`VariantPlugin` (a subclass's
    override wins), with :attr:`~VariantPlugin.mi` and :attr:`~VariantPlugin.dr` bound.

    It keeps ``body``'s name, qualified name, module and docstring. ``TypeError`` if a
    method of ``body`` calls ``super()`` (see :class:`VariantPlugin`).
    """
    key = (f"{body.__module__}.{body.__qualname__}", str(mi.variant()))
    cls = _VARIANT_CLASSES.get(key)
    if cls is None:
        import drjit as dr

        namespace: dict[str, Any] = {}
        for klass in reversed(body.__mro__):
            if issubclass(klass, VariantPlugin):
                for name, value in vars(klass).items():
                    if name not in _NOT_COPIED:
                        _refuse_super(klass, name, value)
                        namespace[name] = value
        namespace.update(
            mi=mi,
            dr=dr,
            __module__=body.__module__,
            __qualname__=body.__qualname__,
            __doc__=body.__doc__,
        )
        bases = (body.mitsuba_base(mi),)
        cls = types.new_class(body.__name__, bases, exec_body=lambda ns: ns.update(namespace))
        _VARIANT_CLASSES[key] = cls
    return cls


def _refuse_super(klass: type, name: str, value: Any) -> None:
    """``TypeError`` if ``value`` (``klass.name``) is a function that calls ``super()``."""
    function = getattr(value, "__func__", value)
    code = getattr(function, "__code__", None)
    if code is not None and "__class__" in code.co_freevars:
        raise TypeError(
            f"{klass.__qualname__}.{name} calls super(): a plugin body calls its base body "
            f"by name (e.g. Base.__init__(self, props)); see VariantPlugin"
        )


#: The (plugin, name, variant) triples registered so far.
_REGISTERED: set[tuple[str, str, str]] = set()


def _register_plugin(
    mi: types.ModuleType, plugin: str, name: str, body: type[VariantPlugin], what: str
) -> type:
    """Register ``body``'s class for the current variant as a ``plugin`` (``"bsdf"`` or
    ``"integrator"``) named ``name``, once per variant; returns the class."""
    variant = mi.variant()
    if not variant.startswith(("llvm_", "cuda_")) or not variant.endswith("_rgb"):
        raise RuntimeError(
            f"the {what} needs a vectorised RGB Mitsuba variant such as llvm_ad_rgb, "
            f"but Mitsuba runs {variant!r}"
        )
    cls = class_for_variant(mi, body)
    if (plugin, name, variant) not in _REGISTERED:
        register = mi.register_bsdf if plugin == "bsdf" else mi.register_integrator
        register(name, lambda props: cls(props))
        _REGISTERED.add((plugin, name, variant))
    return cls


def register_vectorised_bsdf(
    mi: types.ModuleType, name: str, body: type[VariantPlugin], what: str
) -> type:
    """Register the Python BSDF plugin ``name``, whose methods are ``body``'s, for
    Mitsuba's current variant, once per variant; returns the class.

    Our Python BSDFs are written for vectorised RGB variants (``llvm_ad_rgb``,
    ``cuda_ad_rgb``); under any other variant this raises ``RuntimeError`` naming ``what``.
    """
    return _register_plugin(mi, "bsdf", name, body, what)


def register_vectorised_integrator(
    mi: types.ModuleType, name: str, body: type[VariantPlugin], what: str
) -> type:
    """:func:`register_vectorised_bsdf` for a Python integrator plugin ``name`` (``body``'s
    :meth:`VariantPlugin.mitsuba_base` is its base)."""
    return _register_plugin(mi, "integrator", name, body, what)
