"""Mitsuba BSDF ``btf_surface``: a procedural BTF surface's material, carrying its relief.

A ``generate.btf`` procedural surface is geometry (a displaced mesh) and a material (the
``principled`` BSDF with albedo and roughness bitmaps, :mod:`evaluators.render.btf.patch`).
A material source can only hand a BSDF to a scene, so this plugin wraps the principled BSDF
(``bsdf``, evaluated, sampled and its pdf taken unchanged) and carries the height field as
the Python attribute ``relief`` (a :class:`~evaluators.render.btf.relief.Relief`, set by the
material source). Scenes that can (``plane_points``, ``cloth_plane``;
:mod:`evaluators.render.scenes`) replace their floor with the relief mesh carrying the inner
BSDF itself (``inner``), so the render sees exactly the geometry and BSDF ``generate.btf``
path-traced; the other scenes refuse a BSDF with a relief rather than render it flat.
"""

from __future__ import annotations

import types
from typing import Any

from evaluators.render.plugins import VariantPlugin, register_vectorised_bsdf

#: The plugin name.
BTF_SURFACE_NAME = "btf_surface"


def register_btf_surface_bsdf(mi: types.ModuleType) -> type:
    """Register ``btf_surface`` for Mitsuba's (vectorised RGB) variant; returns the class."""
    return register_vectorised_bsdf(mi, BTF_SURFACE_NAME, BtfSurfaceBSDF, "BTF surface BSDF")


class BtfSurfaceBSDF(VariantPlugin):
    """A wrapped BSDF with a relief (plugin ``"btf_surface"``).

    =========  ====  =======  ====================================================
    parameter  type  default  meaning
    =========  ====  =======  ====================================================
    ``bsdf``   bsdf  --       the surface's material (nested BSDF)
    =========  ====  =======  ====================================================

    Attributes: ``inner`` (the nested BSDF), ``relief`` (``None`` until the material
    source sets it).
    """

    def __init__(self, props: Any) -> None:
        VariantPlugin.__init__(self, props)
        mi = self.mi
        inner = props.get("bsdf", None)
        if not isinstance(inner, mi.BSDF):
            raise ValueError("btf_surface: a nested 'bsdf' is required")
        self.inner = inner
        self.relief: Any = None
        self.m_flags = inner.flags()
        self.m_components = [inner.flags(i) for i in range(inner.component_count())]

    def eval(self, ctx: Any, si: Any, wo: Any, active: Any = True) -> Any:
        return self.inner.eval(ctx, si, wo, active)

    def pdf(self, ctx: Any, si: Any, wo: Any, active: Any = True) -> Any:
        return self.inner.pdf(ctx, si, wo, active)

    def eval_pdf(self, ctx: Any, si: Any, wo: Any, active: Any = True) -> Any:
        return self.inner.eval_pdf(ctx, si, wo, active)

    def sample(self, ctx: Any, si: Any, sample1: Any, sample2: Any, active: Any = True) -> Any:
        return self.inner.sample(ctx, si, sample1, sample2, active)

    def to_string(self) -> str:
        return f"BtfSurface[relief={self.relief is not None}, {self.inner}]"
