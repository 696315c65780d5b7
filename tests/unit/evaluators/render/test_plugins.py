"""How a module-level plugin body becomes the class Mitsuba instantiates
(:func:`evaluators.render.plugins.class_for_variant`).

Oracles: Mitsuba itself (the made class subclasses the variant's ``mi.BSDF``, loads through
``mi.load_dict`` and its ``eval`` is the body's, against the closed form of a Lambertian
BRDF, ``albedo / pi * cos``); identity (one class per body and variant); the refusal of a
body whose method calls ``super()``, which could not work in the made class.
"""

from __future__ import annotations

import math
import types
from typing import Any

import numpy as np
import pytest

from evaluators.render.plugins import (
    VariantPlugin,
    class_for_variant,
    register_vectorised_bsdf,
)


class _Lambert(VariantPlugin):
    """A test body: a Lambertian reflector of albedo 0.5 (``eval`` only)."""

    def __init__(self, props: Any) -> None:
        VariantPlugin.__init__(self, props)
        mi = self.mi
        flags = mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.FrontSide
        self.m_flags = flags
        self.m_components = [flags]

    def eval(self, ctx: Any, si: Any, wo: Any, active: Any = True) -> Any:
        mi, dr = self.mi, self.dr
        value = 0.5 / math.pi * dr.maximum(wo.z, 0.0)
        return mi.Color3f(value, value, value)


class _WarmLambert(_Lambert):
    """A subclass body: inherits ``eval``, overrides ``to_string``."""

    def to_string(self) -> str:
        return "WarmLambert"


class _CallsSuper(VariantPlugin):
    def __init__(self, props: Any) -> None:
        super().__init__(props)


def test01_made_class_subclasses_the_variant_bsdf_once(mi: types.ModuleType) -> None:
    cls = class_for_variant(mi, _Lambert)
    assert issubclass(cls, mi.BSDF) and cls.__bases__ == (mi.BSDF,)
    assert class_for_variant(mi, _Lambert) is cls  # the one cache
    assert cls.__name__ == "_Lambert" and cls.__module__ == __name__
    assert cls.mi is mi and cls.eval is _Lambert.eval
    # a subclass body gets its base body's methods and its own
    warm = class_for_variant(mi, _WarmLambert)
    assert warm is not cls and warm.eval is _Lambert.eval
    assert warm.to_string is _WarmLambert.to_string


def test02_registered_body_evaluates_in_mitsuba(mi: types.ModuleType) -> None:
    register_vectorised_bsdf(mi, "test_plugins_lambert", _Lambert, "test BSDF")
    bsdf = mi.load_dict({"type": "test_plugins_lambert"})
    si = mi.SurfaceInteraction3f()
    si.wi = mi.Vector3f(0.0, 0.0, 1.0)
    theta = np.array([0.0, 0.5, 1.2], np.float32)
    wo = mi.Vector3f(mi.Float(np.sin(theta)), mi.Float(0.0), mi.Float(np.cos(theta)))
    value = np.array(bsdf.eval(mi.BSDFContext(), si, wo))
    want = 0.5 / math.pi * np.cos(theta)
    # float32 arithmetic on both sides: a few ulps
    np.testing.assert_allclose(value[0], want, rtol=1e-6)


def test03_a_body_calling_super_is_refused_by_name(mi: types.ModuleType) -> None:
    with pytest.raises(TypeError, match=r"_CallsSuper.__init__ calls super\(\)"):
        class_for_variant(mi, _CallsSuper)
