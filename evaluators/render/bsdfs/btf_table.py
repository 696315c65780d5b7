"""Mitsuba BSDF ``btf_table``: a tabulated BTF (a ``generate.btf`` or ``import.btf`` job's
slices) interpolated in all six dimensions: the full reference that Xu et al. could not
afford in real time, and the ground truth their models are rendered against.

Evaluation at patch coordinates ``uv`` for light ``wi`` and view ``wo`` (local frame, z up;
the frame, ``uv_scale`` and sampling are those of :mod:`.btf_common`):

Angularly
    The distinct light directions and the distinct view directions of the slices each form
    a :class:`~materials.btf.angular.DirectionMesh`: ``wi`` gets up to three lights and
    barycentric weights ``a_i``, ``wo`` up to three views and weights ``b_j``
    (:func:`~materials.btf.angular.direction_weights`: exact at the measured directions,
    continuous, held constant beyond the outermost ring). The up-to-nine slices ``(i, j)``
    are blended with weights ``a_i b_j``; a pair missing from a direction list that is not
    a full light x view product is skipped and the weights of those present renormalised
    (no pair present: 0).
Foreshortening
    What is interpolated over the lights is the apparent BRDF ``BTF / cos(theta_i)``, and
    the result multiplied by the query's ``cos(theta_i)`` (UBO2014-style): a Lambertian
    BTF, ``albedo / pi cos(theta_i)``, is then reproduced exactly at every direction,
    between and beyond the measured ones; at a measured light the factor is exactly 1.
Spatially
    Bilinear between texel centres ``((i + 0.5) / W, (j + 0.5) / H)``, periodic; slice
    ``[row = y = v, column = x = u]``. At a texel centre and measured directions ``eval``
    returns the stored float32 value exactly.

The table lives in Dr.Jit arrays (the whole BTF, float32); the material source refuses
BTFs above :data:`MAX_TABLE_BYTES`. It is handed to the plugin through :func:`put_table`,
whose key the ``table`` property names (Dr.Jit arrays cannot travel in Mitsuba
properties); the plugin takes the table over, the registry keeps no reference.
"""

from __future__ import annotations

import types
import uuid
import weakref
from dataclasses import dataclass
from typing import Any

import numpy as np

from evaluators.render.bsdfs.btf_common import BtfReflector, uv_scale_of
from evaluators.render.plugins import register_vectorised_bsdf
from materials.btf.angular import (
    JitDirectionMesh,
    build_direction_mesh,
    direction_weights,
    jit_direction_mesh,
)

#: The plugin name.
BTF_TABLE_NAME = "btf_table"
#: Largest BTF (float32 bytes) the table holds: 2 GiB.
MAX_TABLE_BYTES = 2 * 2**30
#: Floor of ``cos(theta_i)`` of a measured light when dividing by it.
MIN_COS = 1e-4


@dataclass(eq=False)
class BtfTable:
    """A BTF in Dr.Jit arrays.

    ``rgb``: ``Float`` of ``N * H * W * 3`` (slice-major, then rows, columns, channels);
    ``lights``/``views``: the distinct directions' meshes; ``pairs``: ``Int32`` of
    ``n_lights * n_views``, the slice of each (light, view) pair or -1; ``light_cos``:
    ``Float`` of ``n_lights``, each light's ``cos(theta_i)`` (floored at :data:`MIN_COS`).
    """

    count: int
    height: int
    width: int
    rgb: Any
    lights: JitDirectionMesh
    views: JitDirectionMesh
    pairs: Any
    light_cos: Any
    complete: bool


def _distinct(w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(distinct directions (first occurrences, exact), index of each row's)``."""
    _, first, inverse = np.unique(
        np.round(np.asarray(w, np.float64), 6), axis=0, return_index=True, return_inverse=True
    )
    return np.asarray(w, np.float32)[first], np.asarray(inverse).reshape(-1)


def build_table(
    mi: types.ModuleType, wi: np.ndarray, wo: np.ndarray, slices: np.ndarray
) -> BtfTable:
    """Upload a BTF: light ``wi`` and view ``wo`` directions ``(N, 3)`` and ``slices``
    ``(N, H, W, 3)`` (any float type; stored as float32)."""
    n = int(np.shape(slices)[0])
    if np.shape(wi) != (n, 3) or np.shape(wo) != (n, 3) or np.ndim(slices) != 4:
        raise ValueError("build_table needs wi, wo (N, 3) and slices (N, H, W, 3)")
    lights, li = _distinct(wi)
    views, vi = _distinct(wo)
    pairs = np.full((len(lights), len(views)), -1, np.int32)
    pairs[li, vi] = np.arange(n, dtype=np.int32)
    h, w = int(slices.shape[1]), int(slices.shape[2])
    flat = np.ascontiguousarray(slices, dtype=np.float32).reshape(-1)
    return BtfTable(
        count=n,
        height=h,
        width=w,
        rgb=mi.Float(flat),
        lights=jit_direction_mesh(mi, build_direction_mesh(lights)),
        views=jit_direction_mesh(mi, build_direction_mesh(views)),
        pairs=mi.Int32(pairs.reshape(-1)),
        light_cos=mi.Float(np.maximum(lights[:, 2], MIN_COS).astype(np.float32)),
        complete=bool(np.all(pairs >= 0)),
    )


_TABLES: weakref.WeakValueDictionary[str, BtfTable] = weakref.WeakValueDictionary()


def put_table(table: BtfTable) -> str:
    """Register ``table`` for the ``table`` property; returns its key. The registry holds
    it weakly: keep ``table`` alive until the plugin is built (which then holds it)."""
    key = uuid.uuid4().hex
    _TABLES[key] = table
    return key


def register_btf_table_bsdf(mi: types.ModuleType) -> type:
    """Register ``btf_table`` for Mitsuba's (vectorised RGB) variant; returns the class."""
    return register_vectorised_bsdf(mi, BTF_TABLE_NAME, BtfTableBSDF, "BTF table BSDF")


class BtfTableBSDF(BtfReflector):
    """A tabulated BTF (plugin ``"btf_table"``).

    ==============  ======  =======  ================================================
    parameter       type    default  meaning
    ==============  ======  =======  ================================================
    ``table``       string  --       key of a :class:`BtfTable` from :func:`put_table`
    ``uv_scale_u``  float   1        patch repeats per unit of u
    ``uv_scale_v``  float   1        patch repeats per unit of v
    ==============  ======  =======  ================================================

    Example::

        mi.load_dict({"type": "btf_table", "table": put_table(table), "uv_scale_u": 4.0,
                      "uv_scale_v": 4.0})
    """

    def __init__(self, props: Any) -> None:
        BtfReflector.__init__(self, props)
        key = str(props.get("table", ""))
        table = _TABLES.get(key)
        if table is None:
            raise ValueError(f"btf_table: no table registered under {key!r}")
        self.table: BtfTable = table
        self.uv_scale = uv_scale_of(props)

    def btf(self, uv: Any, light: Any, view: Any, active: Any) -> Any:
        mi, dr = self.mi, self.dr
        t = self.table
        li, la = direction_weights(mi, t.lights, light, active)
        vi, va = direction_weights(mi, t.views, view, active)
        # Bilinear texel taps, periodic (the same four texels in every slice).
        x = uv.x * t.width - 0.5
        y = uv.y * t.height - 0.5
        x0, y0 = dr.floor(x), dr.floor(y)
        fx, fy = x - x0, y - y0
        i0 = mi.Int32(x0) % t.width
        j0 = mi.Int32(y0) % t.height
        i0 = dr.select(i0 < 0, i0 + t.width, i0)
        j0 = dr.select(j0 < 0, j0 + t.height, j0)
        i1 = dr.select(i0 + 1 >= t.width, 0, i0 + 1)
        j1 = dr.select(j0 + 1 >= t.height, 0, j0 + 1)
        taps = [
            (mi.UInt32(j0 * t.width + i0), (1.0 - fx) * (1.0 - fy)),
            (mi.UInt32(j0 * t.width + i1), fx * (1.0 - fy)),
            (mi.UInt32(j1 * t.width + i0), (1.0 - fx) * fy),
            (mi.UInt32(j1 * t.width + i1), fx * fy),
        ]
        texels = t.height * t.width
        acc = mi.Color3f(0.0)
        total = mi.Float(0.0)
        for i in range(3):
            # Apparent BRDF interpolated, times the query's foreshortening.
            cos_l = dr.gather(mi.Float, t.light_cos, li[i], active & (la[i] > 0.0))
            ratio = dr.maximum(light.z, 0.0) / dr.maximum(cos_l, MIN_COS)
            for j in range(3):
                w = la[i] * va[j]
                ok = active & (w > 0.0)
                k = dr.gather(mi.Int32, t.pairs, li[i] * t.views.n + vi[j], ok)
                ok &= k >= 0
                total += dr.select(ok, w, 0.0)
                base = mi.UInt32(dr.maximum(k, 0)) * texels
                value = mi.Color3f(0.0)
                for texel, tw in taps:
                    value += tw * dr.gather(mi.Color3f, t.rgb, base + texel, ok & (tw > 0.0))
                acc += dr.select(ok, w * ratio, 0.0) * value
        return dr.select(total > 0.0, acc / dr.select(total > 0.0, total, 1.0), 0.0)

    def to_string(self) -> str:
        t = self.table
        return (
            f"BtfTable[{t.count} slices of {t.height}x{t.width}, {t.lights.n} lights x "
            f"{t.views.n} views, uv_scale={self.uv_scale}]"
        )
