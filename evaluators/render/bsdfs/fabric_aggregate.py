"""Mitsuba BSDF ``fabric_aggregate``: the aggregated fabric BSDF of Eq. 3-8, one sample per call.

Chen, Wang & Wang 2024, Sec. 3 and 6: the reference ("ground truth") is the aggregated patch
BSDF ``f_P(wi, wo)`` of the pixel footprint P, evaluated by Monte Carlo; with 256 samples it
is the paper's ground truth, with 1 its noisy baseline. This plugin makes every ``eval`` an
*unbiased one-sample estimate* of ``f_P`` (Eq. 8 with the material's albedos), so that the
renderer's average over samples per pixel converges to the aggregate itself.

Why not ``c / area`` of one uniform footprint sample: Eq. 3 divides by ``A_P(wo)`` (Eq. 5),
and the ratio of one sample is biased (the ``aggregate`` estimator's ratio of means is
consistent, not unbiased). Instead, the footprint point is drawn with density proportional
to its visible projected area ``A(p, wo) k_P(p)`` (Eq. 4) -- what a camera ray hitting the
micro-geometry does -- and then ``f_P = E[c(p) / area(p)]`` exactly. The draw is rejection
sampling: propose ``p ~ k_P`` and a march jitter ``j``, accept with probability
``<wo.n_p> / <n_s.n_p> V_o(p, j) / A_max(wo)``, where
``A_max(wo) = cos theta_o + sin theta_o max|tan slope|`` bounds the unoccluded area exactly
(``<wo.n_p> / n_z = wo_z + wo_xy . n_xy / n_z``; the steepest slope is at the yarn edges
and float ends, :func:`max_slope`). The accepted ``(p, j)`` are then fed to the very
``integrand.sample_terms`` the numpy estimator uses (same visibility march, same jitter), so
this is an unbiased sampler of exactly the ratio ``aggregate.estimate`` computes. At most
:data:`MAX_TRIES` proposals are made per call (expected tries ``A_max / A_P``: about 2-15
for footprints of a tile or more, but hundreds for small footprints on a yarn flank turned
away from a grazing viewer, where the local ``A_P`` is tiny); a call that finds none
returns 0, a downward bias of ``(1 - A_P / A_max)^MAX_TRIES``. Measured on ``cloth_plane``
(256x256, 16 tiles per uv, views up to about 80 degrees), the image mean moves by -1.7 %
with 128 tries, -0.5 % with 512, -0.2 % with 1024 (the default) against 4096, at 1.0,
2.0, 2.3 and 3.6 times the render time of 128 tries (one run each, on a loaded machine). A
tighter, footprint-local bound (per covered cell, from the yarn coordinates' ranges) would
remove most of the residual; it is not done.

Footprint, sides, sampling and Eq. 8 are shared with the network BSDF and documented in
:mod:`evaluators.render.bsdfs.fabric_footprint`: the footprint is the pixel's uv parallelogram
(``si.duv_dx``, ``si.duv_dy``, from the ``fabric_path`` integrator's ray differentials),
sampled uniformly -- a box k_P, the pixel's box filter pulled back to the surface (an
axis-aligned square of side ``size`` is ``aggregate.estimate``'s box kernel) -- or one
tile where no partials are given.

Random numbers: ``eval`` has no sampler argument, so each call hashes (TEA)
``si.time``, ``si.uv``, ``si.wi`` and the light direction into a seed. The
``fabric_path`` integrator stores a fresh uniform number in ``si.time`` before shading
(scenes here have no motion), so repeated samples of the same pixel are independent; with
another integrator the hash of the (jittered) hit point still decorrelates them.
"""

from __future__ import annotations

import types
from typing import Any

from evaluators.render.bsdfs.fabric_footprint import FabricFootprintBSDF
from evaluators.render.plugins import register_vectorised_bsdf
from materials.fabric import integrand, yarn
from materials.fabric.array_ops import dot
from materials.fabric.march import max_mip, upload
from materials.fabric.params import FabricParams, params_json
from materials.fabric.yarn import YarnGeometry, max_slope

#: The plugin name.
FABRIC_BSDF_NAME = "fabric_aggregate"
#: Most footprint proposals per call (see the module docstring for the bias it implies).
MAX_TRIES = 1024


def register_fabric_bsdf(mi: types.ModuleType) -> type:
    """Register ``fabric_aggregate`` for Mitsuba's (vectorised RGB) variant; returns the class."""
    return register_vectorised_bsdf(mi, FABRIC_BSDF_NAME, FabricAggregateBSDF, "fabric BSDF")


def fabric_bsdf(
    mi: types.ModuleType,
    params: FabricParams,
    *,
    tiles_per_uv: float = 16.0,
    visibility: bool = True,
) -> Any:
    """An instantiated ``fabric_aggregate`` BSDF (``mi.BSDF``) for ``params``."""
    register_fabric_bsdf(mi)
    return mi.load_dict(
        {
            "type": FABRIC_BSDF_NAME,
            "params": params_json(params),
            "tiles_per_uv": float(tiles_per_uv),
            "visibility": bool(visibility),
        }
    )


class FabricAggregateBSDF(FabricFootprintBSDF):
    """Aggregated woven-fabric BSDF (plugin ``"fabric_aggregate"``), one-sample estimate.

    ================  ======  ========  ================================================
    parameter         type    default   meaning
    ================  ======  ========  ================================================
    ``params``        string  --        the material, JSON of the
                                        :class:`~materials.fabric.params.FabricParams`
                                        fields (:func:`params_json`)
    ``tiles_per_uv``  float   16        pattern tiles across the uv range [0, 1]
    ``visibility``    bool    true      yarn-to-yarn visibility V of Eq. 3-4
    ================  ======  ========  ================================================

    Example: ``fabric_bsdf(mi, FabricParams("twill_3x3", alpha=0.3), tiles_per_uv=8)``.
    """

    def __init__(self, props: Any) -> None:
        FabricFootprintBSDF.__init__(self, props)
        from materials.fabric.aggregate_drjit import DrJitOps

        mi = self.mi
        self.visibility = bool(props.get("visibility", True))
        self.geo = YarnGeometry.from_params(self.params)
        self.ops = DrJitOps(mi.Float, mi.UInt32)
        self.tab = yarn.tables(self.ops, self.geo)
        self.slope = max_slope(self.params)
        # The hierarchical march of sample_terms, also in the rejection loop below.
        self.mip = upload(self.ops, max_mip(self.geo))

    def estimate(self, si: Any, light: Any, active: Any = True) -> Any:
        """One-sample estimate of ``f_P`` (Eq. 8, incident cosine included), ``mi.Color3f``.

        ``si.wi`` is the view, ``light`` the light direction, both local; footprint from
        ``si.uv``, ``si.duv_dx``, ``si.duv_dy`` (module docstring).
        """
        mi, dr = self.mi, self.dr
        ops, geo, tab, params = self.ops, self.geo, self.tab, self.params
        bits = self._bits
        view, lit, active = self.directions(si, light, active)
        cs, ct, ax, ay, bx, by = self.footprint(si)
        h = mi.sample_tea_32(bits(si.time) ^ bits(light.x), bits(si.uv.x) ^ bits(light.y))[0]
        seed = mi.sample_tea_32(h ^ bits(light.z), bits(si.uv.y) ^ bits(si.wi.x))[0]
        a_max = view[2] + dr.sqrt(view[0] * view[0] + view[1] * view[1]) * self.slope

        def cond(k: Any, found: Any, s: Any, t: Any, jit: Any) -> Any:
            return active & ~found & (k < MAX_TRIES)

        def body(k: Any, found: Any, s: Any, t: Any, jit: Any) -> Any:
            u = [mi.sample_tea_float32(seed, k * 4 + d, 4) for d in range(4)]
            s = cs + (u[0] - 0.5) * ax + (u[1] - 0.5) * bx
            t = ct + (u[0] - 0.5) * ay + (u[1] - 0.5) * by
            surf = yarn.surface(ops, geo, tab, s, t)
            n = surf.normal
            area0 = dr.maximum(dot(view, n), 0.0) / n[2]
            found = u[3] * a_max < area0
            if self.visibility:
                v_o = integrand.visibility(
                    ops, geo, tab, s, t, surf.height, view, u[2], need=found, mip=self.mip
                )
                found &= v_o > 0.0
            return k + 1, found, s, t, u[2]

        zero = dr.zeros(mi.Float)
        _, found, s, t, jit = dr.while_loop(
            (mi.UInt32(0), mi.Bool(False), zero, zero, zero),
            cond,
            body,
            label="fabric_aggregate: footprint sample",
        )
        terms = integrand.sample_terms(
            ops, params, geo, tab, s, t, lit, view, jit, with_visibility=self.visibility
        )
        inv = dr.select(found & (terms.area > 0.0), 1.0 / dr.maximum(terms.area, 1e-20), 0.0)
        value = self.recombine((terms.c_warp, terms.c_weft, terms.s_warp, terms.s_weft))
        return dr.select(active, value * inv, 0.0)

    def _bits(self, x: Any) -> Any:
        """The bits of ``mi.Float`` ``x`` as ``mi.UInt32`` (to hash them)."""
        return self.dr.reinterpret_array(self.mi.UInt32, x)

    def to_string(self) -> str:
        return (
            f"FabricAggregateBSDF[pattern={self.params.pattern.name}, "
            f"tiles_per_uv={self.tiles_per_uv:g}, visibility={self.visibility}]"
        )
