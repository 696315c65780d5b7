"""Yarn geometry after Jin et al. 2022: ply normal n_p, ply orientation t_p, height, yarn id.

Each float of the pattern (``patterns.py``) is a curved cylinder: across the yarn it rolls
through the angle ``v``, along it the axis inclines through ``u``, and the ply fibres wind
around the axis at the twist angle ``psi``. The code is element-wise over an
:class:`~materials.fabric.array_ops.ArrayOps` backend, so numpy and Dr.Jit share it.

Conventions (all lengths physical: the unit is one warp cell's width, see ``patterns.py``)
-------------------------------------------------------------------------------------------
- Macro frame: ``x`` along the tile's ``s`` axis (the weft direction), ``y`` along ``t``
  (the warp direction), ``z = n_s`` the macro-surface normal.
- Yarn width: ``(1 - gap)`` times the cell's extent across the yarn (``gap`` = 0.2,
  Sec. 5.1: "the gap takes up 20% of the yarn"); the gap strips sit on both sides of the
  yarn and span its whole length, as in Jin et al.'s maps. Yarn length: the float's length.
  Gap points have no yarn: ``n_p = n_s``, height 0, and zero BSDF (their delta
  transmission is excluded, as in the paper, Sec. 6.5).
- Local yarn frame ``(a, b, z)``: ``b`` along the yarn, ``a = b x z`` across it. Warp:
  ``a = +x, b = +y``; weft: ``a = -y, b = +x``, a proper rotation, so both yarn families
  share one twist handedness. ``xi in [-1, 1]`` runs across the yarn along ``a``,
  ``eta in [-1, 1]`` along the float along ``b``.
- Angles: ``v = xi * ROLL_MAX`` and ``u = eta * u_max`` (Jin et al.'s linear maps); Jin's
  normal would be ``R_a(-u) R_b(v) z = (sin v, sin u cos v, cos u cos v)`` (we use the
  height field's, below) and the fibre direction
  ``t_p = R_a(-u) R_b(v) (-sin psi, cos psi, 0)`` =
  ``(-cos v sin psi, cos u cos psi + sin u sin v sin psi, -sin u cos psi + cos u sin v sin psi)``
  in ``(a, b, z)``: orthonormal by construction; ``psi > 0`` turns the fibres from ``+b``
  towards ``-a`` at the yarn's crest.
- ``ROLL_MAX`` = 80 deg, not Jin et al.'s 90 deg: with 90 deg the yarn edges are vertical and
  Eq. 4's Jacobian ``1 / <n_s . n_p>`` is not integrable across the yarn under the linear
  ``v(xi)`` map, so Eq. 3-5 would diverge. At 80 deg the roll's steepest slope is
  ``beta tan 80``; the tapers steepen the float's boundary further (:func:`max_slope`).
- Height field, watertight: Jin et al.'s slopes integrated into two terms, an across
  term ``c_a a(xi)`` (the integral of ``tan v`` across the half width, ``a = 1`` on the
  crest line and 0 at the yarn's edges) and a lengthwise term ``c_l b(eta)`` (the integral
  of ``tan u`` along the float, 0 at its ends), each multiplied by a smoothstep taper of the
  *other* coordinate that falls from 1 to 0 over the last :data:`TAPER` of the half width
  or half length: ``h = beta [c_a a(xi) s(eta) + c_l b(eta) s(xi)]``. So the height is zero
  on the whole float boundary, where the yarn dives under the crossing one, and continuous
  everywhere (``tests/unit/materials/fabric/test_yarn.py``). The plain sum (the first
  version, before 2026-12) was zero only at the float's corners: its vertical walls, up to
  0.5 cells at float ends, blocked light in the visibility march but had no facets in
  Eq. 4's area integral, so ``A_P(wo)`` fell 2-13 % short of ``cos theta_o`` and 6-14 % of
  the incoming light vanished (issue 12). Inside the tapers' reach (``|xi|, |eta| <= 1 -
  TAPER``) the slopes are exactly Jin's ``tan v`` across and ``tan u`` along; near the
  boundary they steepen (:func:`max_slope` bounds them). The taper's width is the
  material's ``yarn_profile``: ``"smooth"`` (the default, :data:`TAPER` = 0.5, a different
  yarn from Jin's) or ``"jin"`` (:data:`JIN_TAPER` = 0.05: Jin's slopes on 90 % of each
  float, the watertight closure in a thin band at its boundary). The ply normal ``n_p`` is the
  height field's normal (``(-dh/da, -dh/db, 1)``, normalised), which makes Eq. 5's
  identity ``A_P = cos theta`` exact over whole tiles; Jin's normal map differs from it
  by the ``1 / cos u`` of its cross slope (not integrable) and on the tapers. The fibre
  direction ``t_p`` is Jin's, made orthogonal to ``n_p``. ``-ln cos x`` is evaluated by a
  fixed degree-10 polynomial in ``x^2`` (Chebyshev fit on ``[0, ROLL_MAX]``, absolute error
  below 2e-5, i.e. 5e-6 cells in height): the visibility march evaluates the height up to
  2 x 64 times per sample, and the polynomial costs a fraction of a log and a cosine.
- Height-field scaling ``beta`` (Table 1) scales heights, hence slopes:
  ``n_p ~ (beta n_x, beta n_y, n_z)``, ``t_p ~ (t_x, t_y, beta t_z)`` (still orthogonal, and
  identical to Jin et al.'s rescaling of the orientation map). ``beta = 0`` gives flat yarns:
  ``n_p = n_s`` and horizontal ``t_p``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from materials.fabric.array_ops import Array, ArrayOps, NumpyOps, Vec3, normalize
from materials.fabric.params import FabricParams, YarnPair

#: Largest roll angle across a yarn, radians (80 deg; see the module docstring).
ROLL_MAX = math.radians(80.0)
#: Smallest inclination used in the height formula (avoids 0/0 as ``u_max -> 0``).
_U_MIN = 1e-3
#: Largest inclination the height polynomial covers (``PARAM_RANGES`` allows 75 deg).
_U_MAX = ROLL_MAX
#: Per-cell table encoding: ``+-(length * _PACK + offset)``, + for a warp on top.
_PACK = 128.0
#: Public name of the packing factor (``march.py`` decodes the table too).
PACK = _PACK

#: Width of the taper that takes each term of the height to zero at the float's boundary,
#: as a fraction of the half width (across) and of the half length (along), for the
#: default ``yarn_profile`` ``"smooth"``.
#:
#: This makes a different yarn from Jin et al.'s: with ``TAPER = 0.5`` the height (and so
#: the normal) follows Jin's profile only where both ``|xi|`` and ``|eta|`` are below 0.5,
#: the inner 25 % of a float's area; outside it the smoothstep bends the surface down to
#: the base plane, which Jin's yarn does not do. At ``beta = 1``, ``u_max = 30`` degrees,
#: facets steeper than 70 degrees cover 25-31 % of the yarns' projected area here (plain,
#: twill 3x3, satin 5x5) against 12.7 % for Jin's profile, 16-17 % with ``"jin"``'s
#: closing band (``tests/unit/materials/fabric/test_yarn_profile.py``). The taper is what keeps the
#: height continuous at float boundaries (the watertight ground truth).
TAPER = 0.5
#: The taper width of ``yarn_profile`` ``"jin"``: Jin's slopes (``tan v`` across, ``tan u``
#: along) wherever ``|xi|, |eta| <= 1 - JIN_TAPER`` (90 % of a float's area), and a thin
#: band at the boundary that closes the height to zero, so the surface stays watertight.
#: Narrower bands only steepen the band's walls (slopes grow as ``1 / JIN_TAPER``), which
#: costs the render's rejection sampler (its bound is :func:`max_slope`).
JIN_TAPER = 0.05
#: Taper width of each ``yarn_profile`` (``FabricParams.yarn_profile``).
PROFILE_TAPERS = {"smooth": TAPER, "jin": JIN_TAPER}


def _lncos_coefficients(degree: int = 10) -> tuple[float, ...]:
    """Monomial coefficients in ``z = 2 x^2 / ROLL_MAX^2 - 1`` of ``-ln cos x``, x <= ROLL_MAX."""
    x = np.linspace(0.0, ROLL_MAX, 20001)
    z = 2.0 * x * x / (ROLL_MAX * ROLL_MAX) - 1.0
    cheb = np.polynomial.chebyshev.chebfit(z, -np.log(np.cos(x)), degree)
    return tuple(float(c) for c in np.polynomial.chebyshev.cheb2poly(cheb))


_LNCOS = _lncos_coefficients()


def neg_log_cos(ops: ArrayOps, x: Array) -> Array:
    """``-ln cos x`` for ``|x| <= ROLL_MAX`` by the fixed polynomial (abs. error < 2e-5)."""
    z = ops.minimum(x * x * (2.0 / (ROLL_MAX * ROLL_MAX)) - 1.0, 1.0)
    acc = z * _LNCOS[-1] + _LNCOS[-2]
    for c in _LNCOS[-3::-1]:
        acc = acc * z + c
    return acc


#: Yarn ids, as rasterised by :func:`rasterize`.
GAP, WARP, WEFT = 0, 1, 2


@dataclass(frozen=True, eq=False)
class YarnGeometry:
    """Scalars and per-cell tables of one material's yarn geometry (from :class:`FabricParams`).

    Angles in radians, lengths physical. ``cells`` is the pattern's ``(R * C,)`` table
    (row-major): ``+-(length * 128 + offset)`` with the float's length and the cell's offset
    in cells (``patterns.Pattern.float_tables``), positive where the warp is on top -- one
    gather per lookup.
    """

    rows: int
    cols: int
    cell: tuple[float, float]
    tile: tuple[float, float]
    gap: float
    u_max: YarnPair
    psi: YarnPair
    beta: YarnPair
    cells: np.ndarray
    h_max: float
    """Largest height anywhere on the tile (the visibility march stops above it)."""
    taper: float = TAPER
    """Width of the boundary taper (:data:`PROFILE_TAPERS` of the material's ``yarn_profile``)."""

    @classmethod
    def from_params(cls, params: FabricParams) -> YarnGeometry:
        pat = params.pattern
        rows, cols = pat.shape
        offset, length = pat.float_tables()
        u_max = YarnPair(*(min(max(math.radians(v), _U_MIN), _U_MAX) for v in params.u_max_deg))
        psi = YarnPair(*(math.radians(v) for v in params.psi_deg))
        cw, ch = pat.cell_size
        h_max = 0.0
        for is_warp in (True, False):
            on_top = pat.warp_up if is_warp else ~pat.warp_up
            half = (1 - params.gap) * (cw if is_warp else ch) / 2
            longest = float(length[on_top].max()) * (ch if is_warp else cw)
            um = u_max.warp if is_warp else u_max.weft
            b = params.beta.warp if is_warp else params.beta.weft
            crest = half / ROLL_MAX * -math.log(math.cos(ROLL_MAX))
            crest += longest / (2 * um) * -math.log(math.cos(um))
            h_max = max(h_max, b * crest)
        return cls(
            rows=rows,
            cols=cols,
            cell=(cw, ch),
            tile=pat.tile_size,
            gap=params.gap,
            u_max=u_max,
            psi=psi,
            beta=params.beta,
            cells=(np.where(pat.warp_up, 1.0, -1.0) * (length * _PACK + offset)).ravel(),
            h_max=h_max,
            taper=PROFILE_TAPERS[params.yarn_profile],
        )


class YarnTables(NamedTuple):
    """The pattern table uploaded to a backend (see :meth:`ArrayOps.table`)."""

    cells: Array


def tables(ops: ArrayOps, geo: YarnGeometry) -> YarnTables:
    """Upload ``geo``'s per-cell table to ``ops``'s backend."""
    return YarnTables(ops.table(geo.cells))


class Surface(NamedTuple):
    """The fabric surface at a batch of points (backend arrays, element-wise)."""

    warp: Array
    """Bool: a warp yarn is on top here (False in gaps)."""
    weft: Array
    """Bool: a weft yarn is on top here (False in gaps)."""
    normal: Vec3
    """Ply normal n_p, unit, in the macro frame (``n_s`` in gaps)."""
    tangent: Vec3
    """Ply orientation t_p (fibre direction), unit, orthogonal to n_p."""
    height: Array
    """Height above the fabric's base plane, physical units (0 in gaps)."""


class _Located(NamedTuple):
    warp_up: Array  # bool: the cell's top yarn is a warp
    in_yarn: Array  # bool: inside the top yarn's width (not in a gap strip)
    xi: Array  # across the yarn, along a, clamped to [-1, 1]
    eta: Array  # along the float, along b, in [-1, 1]
    crest: Array  # height before beta scaling
    slope_a: Array  # d crest / d a (physical), before beta scaling
    slope_b: Array  # d crest / d b (physical), before beta scaling


def _taper(ops: ArrayOps, x: Array, taper: float) -> tuple[Array, Array]:
    """``(s, ds/dx)`` of the smoothstep taper: 1 for ``|x| <= 1 - taper``, falling to 0 at
    ``|x| = 1`` as ``3 t^2 - 2 t^3`` with ``t = (1 - |x|) / taper``."""
    ax = ops.abs(x)
    tt = ops.minimum(ops.maximum((1.0 - ax) * (1.0 / taper), 0.0), 1.0)
    s = tt * tt * (3.0 - 2.0 * tt)
    ds_dt = 6.0 * tt * (1.0 - tt)
    sign = ops.where(x < 0.0, -1.0, 1.0)
    return s, -sign * ds_dt * (1.0 / taper)


def _locate(ops: ArrayOps, geo: YarnGeometry, tab: YarnTables, s: Array, t: Array) -> _Located:
    """Cell lookup, yarn coordinates and the unscaled height at tile points ``(s, t)``."""
    x = s - ops.floor(s)
    y = t - ops.floor(t)
    fx = x * float(geo.cols)
    fy = y * float(geo.rows)
    # min(): float32 round-off can give x == 1.0 exactly for tiny negative s.
    j = ops.minimum(ops.floor(fx), float(geo.cols - 1))
    i = ops.minimum(ops.floor(fy), float(geo.rows - 1))
    lx = fx - j
    ly = fy - i
    code = ops.gather(tab.cells, ops.index(i * float(geo.cols) + j))
    warp_up = code > 0.0
    packed = ops.abs(code)
    count = ops.floor(packed * (1.0 / _PACK))
    off = packed - count * _PACK
    k = 2.0 / (1.0 - geo.gap)
    # a = +x for a warp, -y for a weft (module docstring).
    xi_raw = ops.where(warp_up, (lx - 0.5) * k, (0.5 - ly) * k)
    along = ops.where(warp_up, ly, lx)
    eta = 2.0 * (off + along) / count - 1.0
    in_yarn = ops.abs(xi_raw) <= 1.0
    xi = ops.minimum(ops.maximum(xi_raw, -1.0), 1.0)
    cw, ch = geo.cell
    uw, uf = geo.u_max
    half = ops.where(warp_up, (1 - geo.gap) * cw / 2, (1 - geo.gap) * ch / 2)
    um = ops.where(warp_up, uw, uf)
    top = ops.where(warp_up, -math.log(math.cos(uw)), -math.log(math.cos(uf)))
    cell_along = ops.where(warp_up, ch, cw)
    g_roll = -math.log(math.cos(ROLL_MAX))
    # Jin's integrated slopes as unit profiles: across a(xi) (tan v), along b(eta) (tan u).
    v, u = xi * ROLL_MAX, eta * um
    prof_a = ops.maximum(g_roll - neg_log_cos(ops, v), 0.0) * (1.0 / g_roll)
    prof_b = ops.maximum(top - neg_log_cos(ops, u), 0.0) / top
    tan_v = ops.sin(v) / ops.cos(v)
    tan_u = ops.sin(u) / ops.cos(u)
    c_a = half * (g_roll / ROLL_MAX)  # the across term's crest height
    c_l = count * cell_along * top / (2.0 * um)  # the lengthwise term's crest height
    s_xi, ds_xi = _taper(ops, xi, geo.taper)
    s_eta, ds_eta = _taper(ops, eta, geo.taper)
    # Watertight: each term tapers to zero where the other one does (module docstring).
    crest = c_a * prof_a * s_eta + c_l * prof_b * s_xi
    deta_db = 2.0 / (count * cell_along)
    slope_a = -tan_v * s_eta + c_l * prof_b * ds_xi / half
    slope_b = (c_a * prof_a * ds_eta) * deta_db - tan_u * s_xi
    return _Located(warp_up, in_yarn, xi, eta, crest, slope_a, slope_b)


def height(ops: ArrayOps, geo: YarnGeometry, tab: YarnTables, s: Array, t: Array) -> Array:
    """Height at tile points ``(s, t)`` (physical units, 0 in gaps); cheaper than surface()."""
    loc = _locate(ops, geo, tab, s, t)
    beta = ops.where(loc.warp_up, geo.beta.warp, geo.beta.weft)
    return ops.where(loc.in_yarn, beta * loc.crest, 0.0)


def surface(ops: ArrayOps, geo: YarnGeometry, tab: YarnTables, s: Array, t: Array) -> Surface:
    """Yarn id, ply normal, ply orientation and height at tile points ``(s, t)``."""
    loc = _locate(ops, geo, tab, s, t)
    w = loc.warp_up
    v = loc.xi * ROLL_MAX
    u = loc.eta * ops.where(w, geo.u_max.warp, geo.u_max.weft)
    sv, cv, su, cu = ops.sin(v), ops.cos(v), ops.sin(u), ops.cos(u)
    sp = ops.where(w, math.sin(geo.psi.warp), math.sin(geo.psi.weft))
    cp = ops.where(w, math.cos(geo.psi.warp), math.cos(geo.psi.weft))
    beta = ops.where(w, geo.beta.warp, geo.beta.weft)
    # The normal of the height field: (-beta dh/da, -beta dh/db, 1) in (a, b, z); Jin's
    # fibre direction t_p, with slopes scaled by beta, made orthogonal to it.
    n_a, n_b = -beta * loc.slope_a, -beta * loc.slope_b
    t_a = -cv * sp
    t_b = cu * cp + su * sv * sp
    t_z = (-su * cp + cu * sv * sp) * beta
    nx, ny = ops.where(w, n_a, n_b), ops.where(w, n_b, -n_a)
    tx, ty = ops.where(w, t_a, t_b), ops.where(w, t_b, -t_a)
    normal, _ = normalize(ops, (nx, ny, 1.0 + 0.0 * nx))
    along_n = tx * normal[0] + ty * normal[1] + t_z * normal[2]
    tangent, t_len = normalize(
        ops, (tx - along_n * normal[0], ty - along_n * normal[1], t_z - along_n * normal[2])
    )
    # beta = 0 with a vertical fibre (impossible for |u|, |v| < 90 deg unless |psi| is
    # extreme) would leave no horizontal direction: fall back to the yarn axis b.
    ok = t_len > 1e-6
    axis_x = ops.where(w, 0.0, 1.0)
    axis_y = ops.where(w, 1.0, 0.0)
    tangent = (
        ops.where(ok, tangent[0], axis_x),
        ops.where(ok, tangent[1], axis_y),
        ops.where(ok, tangent[2], 0.0),
    )
    yarn = loc.in_yarn
    normal = (
        ops.where(yarn, normal[0], 0.0),
        ops.where(yarn, normal[1], 0.0),
        ops.where(yarn, normal[2], 1.0),
    )
    tangent = (
        ops.where(yarn, tangent[0], 1.0),
        ops.where(yarn, tangent[1], 0.0),
        ops.where(yarn, tangent[2], 0.0),
    )
    h = ops.where(yarn, beta * loc.crest, 0.0)
    return Surface(yarn & w, yarn & ~w, normal, tangent, h)


class TileMaps(NamedTuple):
    """Rasterised tile, arrays indexed ``[row, col]`` with row ``r`` at ``t = (r + 0.5) / res``.

    Row 0 is the bottom of the tile (``t`` small): flip rows for a top-down image file.
    """

    normal: np.ndarray
    """``(res, res, 3)`` float32 ply normals n_p, macro frame."""
    tangent: np.ndarray
    """``(res, res, 3)`` float32 ply orientations t_p, macro frame."""
    height: np.ndarray
    """``(res, res)`` float32 heights, physical units."""
    yarn: np.ndarray
    """``(res, res)`` uint8 yarn ids: 0 gap, 1 warp, 2 weft."""


def rasterize(params: FabricParams, resolution: int) -> TileMaps:
    """n_p, t_p, height and yarn id over one tile at ``resolution x resolution`` pixel centres.

    For the normal/orientation maps of the paper's encoder (Sec. 4.2) and EXR export.
    """
    if not 1 <= resolution <= 8192:
        raise ValueError(f"resolution must be in [1, 8192], got {resolution}")
    ops = NumpyOps()
    geo = YarnGeometry.from_params(params)
    centres = (np.arange(resolution, dtype=np.float32) + 0.5) / np.float32(resolution)
    t, s = np.meshgrid(centres, centres, indexing="ij")
    surf = surface(ops, geo, tables(ops, geo), s, t)
    yarn = np.where(surf.warp, WARP, np.where(surf.weft, WEFT, GAP)).astype(np.uint8)
    return TileMaps(
        normal=np.stack(surf.normal, axis=-1).astype(np.float32),
        tangent=np.stack(surf.tangent, axis=-1).astype(np.float32),
        height=np.asarray(surf.height, dtype=np.float32),
        yarn=yarn,
    )


def max_slope(params: FabricParams) -> float:
    """An upper bound of ``|n_xy| / n_z`` (the height field's gradient) over the tile.

    With ``|s| <= 1``, ``|ds/dx| <= 1.5 / taper`` and unit profiles, the across slope is at
    most ``tan ROLL_MAX + c_l 1.5 / (taper half)`` and the along slope at most
    ``tan u_max + c_a 1.5 / taper * 2 / (count cell)``, for the family's longest (``c_l``)
    and shortest (``count``) floats; their norm, times ``beta``, bounds the gradient.
    """
    geo = YarnGeometry.from_params(params)
    pat = params.pattern
    offset, length = pat.float_tables()
    cw, ch = geo.cell
    g_roll = -math.log(math.cos(ROLL_MAX))
    out = 0.0
    for is_warp in (True, False):
        on_top = pat.warp_up if is_warp else ~pat.warp_up
        if not on_top.any():
            continue
        um = geo.u_max.warp if is_warp else geo.u_max.weft
        beta = geo.beta.warp if is_warp else geo.beta.weft
        half = (1 - geo.gap) * (cw if is_warp else ch) / 2
        cell_along = ch if is_warp else cw
        top = -math.log(math.cos(um))
        longest, shortest = float(length[on_top].max()), float(length[on_top].min())
        c_a = half * g_roll / ROLL_MAX
        c_l = longest * cell_along * top / (2.0 * um)
        across = math.tan(ROLL_MAX) + c_l * 1.5 / (geo.taper * half)
        along = math.tan(um) + c_a * 1.5 / geo.taper * 2.0 / (shortest * cell_along)
        out = max(out, beta * math.hypot(across, along))
    return out
