"""What the BTF BSDFs share: the patch frame, ``uv_scale``, cosine sampling.

A BTF (UBO2014's convention, :mod:`materials.btf.directions`) is ``BTF(u, wi, wo) = L_o /
E_perp`` with ``wi`` the **light** and ``wo`` the **view** direction, foreshortening
included (a Lambertian plane gives ``albedo / pi * cos(theta_i)``). Mitsuba's
``BSDF.eval(ctx, si, wo)`` returns ``f(si.wi, wo) cos(theta_wo)``, where, when radiance is
transported (Mitsuba's path tracers), ``si.wi`` points towards the previous path vertex
(the camera side: the **view**) and ``wo`` towards the next one (the light side: the
**light**), so ``eval`` is exactly ``BTF(uv, light = wo, view = si.wi)``, with no cosine to
add or remove (a BTF need not be reciprocal; this order is the one that matters).

Patch coordinates and frame
    The patch coordinates of a shading point are ``(u s_u, v s_v)`` for the shape's
    ``si.uv = (u, v)`` and ``uv_scale = (s_u, s_v)`` (the patch repeats ``s`` times per
    unit of uv; it is periodic). The BTF's frame has x along the patch's columns (u), y
    along its rows (v), z the normal. Mitsuba's shading frame has ``s`` along ``dp/du`` and
    ``t = n x s``, which is ``+dp/dv`` on a right-handed parameterisation (``rectangle``,
    the ``plane_points`` floor) and ``-dp/dv`` on a left-handed one (Mitsuba's ``sphere``,
    whose uv seen from outside is mirrored). There the local y components are negated, so
    that the directions stay consistent with the (mirrored) texture: the sphere shows the
    mirror image of the patch, with the mirror image's reflectance.
Sampling
    Cosine-weighted hemisphere sampling of the light direction (``pdf = cos / pi``); the
    weight is ``eval / pdf``. One-sided: 0 (value and pdf) below the horizon of either
    direction.
"""

from __future__ import annotations

from typing import Any

from evaluators.render.bsdfs.common import sample_record
from evaluators.render.plugins import VariantPlugin


def uv_scale_of(props: Any) -> tuple[float, float]:
    """``(s_u, s_v)`` from the plugin properties ``uv_scale_u``, ``uv_scale_v`` (default 1);
    ``ValueError`` unless both are positive."""
    su = float(props.get("uv_scale_u", 1.0))
    sv = float(props.get("uv_scale_v", 1.0))
    if not (su > 0.0 and sv > 0.0):
        raise ValueError(f"uv_scale must be positive, got ({su}, {sv})")
    return su, sv


class BtfReflector(VariantPlugin):
    """A BTF as a one-sided reflector (see the module docstring).

    A subclass sets ``self.uv_scale`` (``(s_u, s_v)``) in ``__init__`` and defines
    ``btf(uv, light, view, active)``: the BTF (``mi.Color3f``, foreshortening included) at
    patch coordinates ``uv`` (``mi.Point2f``, periodic) for local unit vectors ``light``
    and ``view`` (``mi.Vector3f``, both above the plane where ``active``).
    """

    uv_scale: tuple[float, float] = (1.0, 1.0)

    def __init__(self, props: Any) -> None:
        VariantPlugin.__init__(self, props)
        mi = self.mi
        flags = (
            mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.FrontSide
        )
        self.m_flags = flags
        self.m_components = [flags]

    def btf(self, uv: Any, light: Any, view: Any, active: Any) -> Any:
        """The BTF (``mi.Color3f``); defined by the subclass."""
        raise NotImplementedError

    def _enabled(self, ctx: Any, active: Any) -> Any:
        mi = self.mi
        on = ctx.is_enabled(mi.BSDFFlags.GlossyReflection, 0) or ctx.is_enabled(
            mi.BSDFFlags.DiffuseReflection, 0
        )
        return active & on

    def _value(self, si: Any, wo: Any, active: Any) -> Any:
        """``BTF(uv, light = wo, view = si.wi)``, 0 below either horizon."""
        mi, dr = self.mi, self.dr
        active = active & (wo.z > 0.0) & (si.wi.z > 0.0)
        # Left-handed uv (t = -dp/dv): mirror y, see the module docstring.
        sign = dr.select(dr.dot(si.sh_frame.t, si.dp_dv) < 0.0, -1.0, 1.0)
        light = mi.Vector3f(wo.x, wo.y * sign, wo.z)
        view = mi.Vector3f(si.wi.x, si.wi.y * sign, si.wi.z)
        uv = mi.Point2f(si.uv.x * self.uv_scale[0], si.uv.y * self.uv_scale[1])
        return dr.select(active, self.btf(uv, light, view, active), 0.0)

    def _pdf(self, si: Any, wo: Any, active: Any) -> Any:
        mi, dr = self.mi, self.dr
        active = active & (wo.z > 0.0) & (si.wi.z > 0.0)
        return dr.select(active, mi.warp.square_to_cosine_hemisphere_pdf(wo), 0.0)

    def eval(self, ctx: Any, si: Any, wo: Any, active: Any = True) -> Any:
        """``BTF(uv, light = wo, view = si.wi)`` (already ``f cos theta_wo``)."""
        return self._value(si, wo, self._enabled(ctx, active))

    def pdf(self, ctx: Any, si: Any, wo: Any, active: Any = True) -> Any:
        """``cos(theta_wo) / pi`` above both horizons, else 0."""
        return self._pdf(si, wo, self._enabled(ctx, active))

    def eval_pdf(self, ctx: Any, si: Any, wo: Any, active: Any = True) -> Any:
        """``(eval, pdf)`` in one call."""
        active = self._enabled(ctx, active)
        return self._value(si, wo, active), self._pdf(si, wo, active)

    def sample(self, ctx: Any, si: Any, sample1: Any, sample2: Any, active: Any = True) -> Any:
        """A cosine-weighted light direction; returns ``(BSDFSample3f, eval / pdf)``."""
        mi, dr = self.mi, self.dr
        active = self._enabled(ctx, active) & (si.wi.z > 0.0)
        wo = mi.warp.square_to_cosine_hemisphere(sample2)
        pdf = self._pdf(si, wo, active)
        active &= pdf > 0.0
        value = self._value(si, wo, active)
        bs = sample_record(mi, wo, pdf)
        return bs, dr.select(active, value / dr.maximum(pdf, 1e-30), 0.0)
