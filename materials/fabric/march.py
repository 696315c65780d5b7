"""A max mip-map over one tile's height field, so the visibility march skips clear space.

The march of ``integrand.visibility`` tests the height field at the rises
``r_k = (k + 1 - j) / n (h_max - h)`` along a ray. Most of those tests are far from any
yarn: the ray is already above everything beneath it. The hierarchy proves that in bulk.
Each level cuts the tile into texels (``per_cell`` x ``per_cell`` per pattern cell, for
``per_cell`` in :data:`LEVELS`) and stores an upper bound of the height over each closed
texel. At the current point of the ray, if the ray (which only rises) is above a texel's
bound, no test point inside that texel can be blocked, so the march jumps to the first
``k`` past the texel's exit, taking the coarsest level that allows it; otherwise it tests
the height at ``r_k`` as before and moves on to ``k + 1``.

So the hierarchical march tests a subset of the plain march's points and skips only points
that cannot be blocked: it returns the plain march's visibility (same steps, same jitter,
same tolerance), up to float32 round-off in the jumps, in fewer iterations
(``tests/unit/materials/fabric/test_march.py`` checks it against the plain march and
against a brute-force fine march).

The bounds are exact (up to a slack of 1e-4 cells). Inside one float the height is
``beta [c_a A(xi) S(eta) + c_l B(eta) S(xi)]`` (``yarn.py``) with ``A``, ``B`` and the taper
``S`` even, non-negative and non-increasing in ``|xi|`` or ``|eta|``; so over a texel (a
rectangle in ``(xi, eta)``, as texels never straddle a cell) the height is largest at the
texel's point nearest the float's centre in both coordinates, and one height evaluation
there gives the texel's maximum (0 in gap strips). Coarser levels take the maximum of
their children. Built with numpy in milliseconds per material and cached by geometry.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass
from typing import Literal, NamedTuple

import numpy as np

from materials.fabric import yarn
from materials.fabric.array_ops import Array, ArrayOps, NumpyOps

March = Literal["batched", "hierarchical", "plain"]
MARCHES: tuple[March, ...] = ("batched", "hierarchical", "plain")

#: Texels per pattern cell side, finest first; each level halves the one before.
LEVELS: tuple[int, ...] = (16, 8, 4, 2, 1)
#: Added to every bound (physical units, 1e-4 of a cell): the height polynomial's wiggle
#: (``yarn.neg_log_cos`` is within 2e-5 of a monotone function), float32 round-off, and the
#: ``1e-6`` inset of the evaluation point.
_SLACK = 1e-4


@dataclass(frozen=True, eq=False)
class MaxMip:
    """Upper bounds of the height over texels, all levels in one flat float32 table.

    Level ``i`` has ``rows * LEVELS[i]`` x ``cols * LEVELS[i]`` texels, row-major with row 0
    at small ``t``, starting at ``offsets[i]`` in ``table``.
    """

    rows: int
    cols: int
    levels: tuple[int, ...]
    offsets: tuple[int, ...]
    table: np.ndarray

    def level(self, i: int) -> np.ndarray:
        """Level ``i``'s bounds as a ``(rows * n, cols * n)`` array."""
        n = self.levels[i]
        size = self.rows * n * self.cols * n
        flat = self.table[self.offsets[i] : self.offsets[i] + size]
        return flat.reshape(self.rows * n, self.cols * n)


#: Recently built mip-maps by geometry (``estimate`` builds a new geometry per call).
_CACHE: OrderedDict[tuple[object, ...], MaxMip] = OrderedDict()
_CACHE_SIZE = 16


def _key(geo: yarn.YarnGeometry) -> tuple[object, ...]:
    return (
        geo.rows,
        geo.cols,
        geo.cell,
        geo.tile,
        geo.gap,
        tuple(geo.u_max),
        tuple(geo.psi),
        tuple(geo.beta),
        geo.cells.tobytes(),
        geo.h_max,
        geo.taper,
        LEVELS,
    )


def max_mip(geo: yarn.YarnGeometry) -> MaxMip:
    """The :class:`MaxMip` of ``geo``, cached by geometry (see the module docstring)."""
    key = _key(geo)
    cached = _CACHE.get(key)
    if cached is not None:
        _CACHE.move_to_end(key)
        return cached
    ops = NumpyOps()
    tab = yarn.tables(ops, geo)
    n = LEVELS[0]
    # Texel (iy, ix) of the finest level: cell (iy // n, ix // n), local ranges of width 1/n.
    iy, ix = np.meshgrid(np.arange(geo.rows * n), np.arange(geo.cols * n), indexing="ij")
    i, j = iy // n, ix // n
    lo_x, lo_y = (ix % n) / n, (iy % n) / n
    code = geo.cells[i * geo.cols + j]
    warp_up = code > 0.0
    packed = np.abs(code)
    count = np.floor(packed / yarn.PACK)
    off = packed - count * yarn.PACK
    # The float's centre (xi = 0, eta = 0) in the cell's local coordinates (yarn._locate).
    centre_along = count / 2.0 - off
    cx = np.where(warp_up, 0.5, centre_along)
    cy = np.where(warp_up, centre_along, 0.5)
    # The texel's point nearest the centre in both xi and eta, just inside the texel (the
    # cell lookup floors: a point on the far wall would fall into the next cell).
    inset = 1e-6
    px = np.clip(cx, lo_x + inset, lo_x + 1.0 / n - inset)
    py = np.clip(cy, lo_y + inset, lo_y + 1.0 / n - inset)
    h = yarn.height(ops, geo, tab, (j + px) / geo.cols, (i + py) / geo.rows)
    finest = np.asarray(h, dtype=np.float64) + _SLACK
    levels = [finest]
    for n_prev, n in zip(LEVELS, LEVELS[1:], strict=False):
        f = n_prev // n
        prev = levels[-1]
        r, c = prev.shape
        levels.append(prev.reshape(r // f, f, c // f, f).max(axis=(1, 3)))
    offsets, start = [], 0
    for lv in levels:
        offsets.append(start)
        start += lv.size
    table = np.concatenate([lv.ravel() for lv in levels]).astype(np.float32)
    # float32 rounding of the bound must not fall below the float64 value.
    table = np.nextafter(table, np.float32(np.inf))
    mip = MaxMip(geo.rows, geo.cols, LEVELS, tuple(offsets), table)
    _CACHE[key] = mip
    while len(_CACHE) > _CACHE_SIZE:
        _CACHE.popitem(last=False)
    return mip


class MipTables(NamedTuple):
    """A :class:`MaxMip` with its table uploaded to a backend (:meth:`ArrayOps.table`)."""

    mip: MaxMip
    table: Array


def upload(ops: ArrayOps, mip: MaxMip) -> MipTables:
    """Upload ``mip``'s table to ``ops``'s backend."""
    return MipTables(mip, ops.table(mip.table))


def clear_jump(
    ops: ArrayOps,
    tabs: MipTables,
    x: Array,
    y: Array,
    ray_height: Array,
    inv_ds: Array,
    inv_dt: Array,
    pos_s: Array,
    pos_t: Array,
) -> tuple[Array, Array]:
    """``(clear, reach)`` at tile points ``(x, y)`` in ``[0, 1)^2`` on rays of height
    ``ray_height`` (including the march's tolerance).

    ``clear``: the finest texel there lies wholly below the ray. ``reach``: the extra rise
    after which the ray leaves the coarsest texel that does (meaningful where ``clear``).
    ``inv_ds = 1 / |ds|``, ``inv_dt = 1 / |dt|`` (per unit rise, tile units; large where
    the ray does not move along that axis) and ``pos_s``, ``pos_t`` (bools: moving towards
    +s, +t) describe the ray.
    """
    mip = tabs.mip
    clear = None
    reach = None
    for i, n in enumerate(mip.levels):
        nx, ny = float(mip.cols * n), float(mip.rows * n)
        fx, fy = x * nx, y * ny
        ix = ops.minimum(ops.floor(fx), nx - 1.0)
        iy = ops.minimum(ops.floor(fy), ny - 1.0)
        bound = ops.gather(tabs.table, ops.index(iy * nx + ix + float(mip.offsets[i])))
        ok = ray_height >= bound
        # Rise to the texel's exit: the nearer of its s and t walls ahead of the ray.
        to_s = ops.where(pos_s, ix + 1.0 - fx, fx - ix) * (1.0 / nx) * inv_ds
        to_t = ops.where(pos_t, iy + 1.0 - fy, fy - iy) * (1.0 / ny) * inv_dt
        exit_rise = ops.minimum(to_s, to_t)
        if clear is None:
            clear, reach = ok, ops.where(ok, exit_rise, 0.0)
        else:
            # Levels nest (a coarse bound is the max of its children's), so a clear coarse
            # texel contains the clear fine one and reaches farther.
            reach = ops.where(ok, exit_rise, reach)
    assert clear is not None and reach is not None
    return clear, reach


__all__ = ["LEVELS", "MARCHES", "March", "MaxMip", "MipTables", "clear_jump", "max_mip", "upload"]
