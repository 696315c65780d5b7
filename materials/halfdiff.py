"""Half/difference angles (Rusinkiewicz 1998) and the MERL table index, in one place.

Every part of matforge that touches MERL tables (the writer and reader, tabulation of
Mitsuba and analytic sources, the measurement simulation, the table BSDF and scoring) maps
directions to bins through this module.

Conventions
-----------
- Directions are unit vectors in the local shading frame, z up (the surface normal).
  ``wi`` is the first argument everywhere; the difference vector is computed from ``wi``,
  exactly as MERL's reference ``std_coords_to_half_diff_coords`` rotates its "in" vector.
- Rusinkiewicz, "A New Change of Variables for Efficient BRDF Representation", EGWR 1998:
  ``h = normalize(wi + wo)`` with polar angles ``(theta_h, phi_h)``; the difference vector is
  ``d = Rot_y(-theta_h) Rot_z(-phi_h) wi`` with polar angles ``(theta_d, phi_d)``. In that
  half frame ``wo`` is ``d`` mirrored about z, so ``phi_d(wo, wi) = phi_d(wi, wo) + pi``.
- The MERL layout (Matusik et al. 2003, "A Data-Driven Reflectance Model"; reference code
  ``BRDFRead.cpp``): table shape ``(90, 90, P)`` indexed ``(theta_h, theta_d, phi_d)``,
  ``phi_d`` fastest, with

  * ``i_h = floor(sqrt(theta_h / (pi/2)) * 90)`` (square-root spacing, dense near the
    specular peak), clamped to ``[0, 89]``;
  * ``i_d = floor(theta_d / (pi/2) * 90)``, clamped to ``[0, 89]``;
  * ``i_p = floor(phi_d' / pi * 180)``, clamped to ``[0, P-1]``, where for ``P = 180``
    ``phi_d' = phi_d mod pi`` (reciprocity: the BRDF is unchanged under
    ``phi_d -> phi_d + pi``) and for the 360 variant ``phi_d' = phi_d mod 2 pi``.
    Every phi_d bin is 1 degree wide in both variants.

  The reference folds ``phi_d < 0`` by adding pi; ``mod pi`` is the same map except at
  ``phi_d = pi`` exactly, where the reference clamps to bin 179 and we wrap to bin 0, which
  is the same direction pair up to reciprocity.
- Continuous bin coordinates ``u`` put bin ``i`` on ``[i, i+1)``; its centre is ``i + 0.5``.
  The inverse map used for tabulation returns bin centres in these coordinates:
  ``theta_h = ((i_h + 0.5) / 90)**2 * pi/2``, ``theta_d = (i_d + 0.5) / 90 * pi/2``,
  ``phi_d = (i_p + 0.5) * pi / 180``, with ``phi_h = 0`` (any phi_h gives the same value for an
  isotropic BRDF).

The core formulas (:func:`halfdiff_components`, :func:`directions_components`,
:func:`merl_coordinates`) are written over separate x, y, z components with the elementwise
functions injected through :class:`ArrayOps`, so the Dr.Jit table BSDF can call the very same
code with ``drjit_ops(dr)``. The ``(N, 3)`` numpy wrappers below are thin.
"""

from __future__ import annotations

import math
import types
from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np

#: Table resolution in theta_h and theta_d (both variants).
RES_THETA_H = 90
RES_THETA_D = 90
#: Accepted phi_d resolutions: 180 (canonical, folded by reciprocity) or 360 (unfolded).
PHI_D_VARIANTS = (180, 360)
#: The value tabulation writes for missing or below-horizon bins; any negative entry is
#: treated as missing when reading or looking up.
MISSING = -1.0

_HALF_PI = 0.5 * math.pi


class ArrayOps(NamedTuple):
    """Elementwise functions for one array library, injected into the generic formulas."""

    sqrt: Callable[[Any], Any]
    atan2: Callable[[Any, Any], Any]
    cos: Callable[[Any], Any]
    sin: Callable[[Any], Any]
    floor: Callable[[Any], Any]
    minimum: Callable[[Any, Any], Any]
    maximum: Callable[[Any, Any], Any]
    #: ``where(condition, a, b)``: elementwise choice (``np.where``, ``dr.select``).
    where: Callable[[Any, Any, Any], Any]


NUMPY_OPS = ArrayOps(
    np.sqrt, np.arctan2, np.cos, np.sin, np.floor, np.minimum, np.maximum, np.where
)


def drjit_ops(dr: types.ModuleType) -> ArrayOps:
    """The :class:`ArrayOps` of Dr.Jit; pass the ``drjit`` module (imported after Mitsuba)."""
    return ArrayOps(dr.sqrt, dr.atan2, dr.cos, dr.sin, dr.floor, dr.minimum, dr.maximum, dr.select)


def halfdiff_components(
    ix: Any, iy: Any, iz: Any, ox: Any, oy: Any, oz: Any, ops: ArrayOps = NUMPY_OPS
) -> tuple[Any, Any, Any, Any]:
    """Rusinkiewicz angles of direction pairs given as components (generic core).

    Parameters
    ----------
    ix, iy, iz, ox, oy, oz
        Components of unit vectors ``wi`` and ``wo`` in the local frame (z up), any shape.
    ops
        The array library's elementwise functions.

    Returns
    -------
    theta_h, phi_h, theta_d, phi_d
        Radians; ``theta_h, theta_d`` in ``[0, pi]`` (``[0, pi/2]`` above the horizon),
        ``phi_h, phi_d`` in ``(-pi, pi]`` as returned by ``atan2``.
    """
    # The half vector need not be normalised: only its direction enters through atan2.
    hx, hy, hz = ix + ox, iy + oy, iz + oz
    # Polar angles via atan2(sin, cos), not acos(cos): acos loses half the digits near 0,
    # where the square-root theta_h bins are narrowest (in float32, ~3e-4 rad).
    theta_h = ops.atan2(ops.sqrt(hx * hx + hy * hy), hz)
    phi_h = ops.atan2(hy, hx)
    cp, sp = ops.cos(phi_h), ops.sin(phi_h)
    ct, st = ops.cos(theta_h), ops.sin(theta_h)
    # d = Rot_y(-theta_h) Rot_z(-phi_h) wi  (Rusinkiewicz 1998, Sec. 3)
    x1 = ix * cp + iy * sp
    y1 = iy * cp - ix * sp
    dx = x1 * ct - iz * st
    dz = x1 * st + iz * ct
    theta_d = ops.atan2(ops.sqrt(dx * dx + y1 * y1), dz)
    phi_d = ops.atan2(y1, dx)
    return theta_h, phi_h, theta_d, phi_d


def halfdiff_angles(
    ix: Any, iy: Any, iz: Any, ox: Any, oy: Any, oz: Any, ops: ArrayOps = NUMPY_OPS
) -> tuple[Any, Any, Any]:
    """``(theta_h, theta_d, phi_d)`` of :func:`halfdiff_components`, without trigonometry.

    The same rotation ``d = Rot_y(-theta_h) Rot_z(-phi_h) wi``, but the cosines and sines
    of ``phi_h`` and ``theta_h`` are read off the half vector ``h = wi + wo`` directly
    (``cos phi_h = h_x / r``, ``sin phi_h = h_y / r``, ``cos theta_h = h_z / |h|``,
    ``sin theta_h = r / |h|`` with ``r = sqrt(h_x^2 + h_y^2)``) instead of evaluating
    ``cos``/``sin`` of angles from ``atan2``: three ``atan2`` calls instead of four, and no
    ``sin``/``cos``. Equal to :func:`halfdiff_components` up to float rounding; where
    ``r = 0`` (``h`` along z) ``phi_h`` is taken as 0, as ``atan2(0, 0)`` gives there. This
    is the table BSDF's hot path; ``halfdiff_components`` stays the reference.
    """
    hx, hy, hz = ix + ox, iy + oy, iz + oz
    r2 = hx * hx + hy * hy
    r = ops.sqrt(r2)
    theta_h = ops.atan2(r, hz)
    has_r = r > 0.0
    inv_r = 1.0 / ops.where(has_r, r, 1.0)
    cp = ops.where(has_r, hx * inv_r, 1.0)
    sp = hy * inv_r
    norm = ops.sqrt(r2 + hz * hz)
    inv_norm = 1.0 / ops.where(norm > 0.0, norm, 1.0)
    ct, st = hz * inv_norm, r * inv_norm
    x1 = ix * cp + iy * sp
    y1 = iy * cp - ix * sp
    dx = x1 * ct - iz * st
    dz = x1 * st + iz * ct
    theta_d = ops.atan2(ops.sqrt(dx * dx + y1 * y1), dz)
    phi_d = ops.atan2(y1, dx)
    return theta_h, theta_d, phi_d


def directions_components(
    theta_h: Any, phi_h: Any, theta_d: Any, phi_d: Any, ops: ArrayOps = NUMPY_OPS
) -> tuple[tuple[Any, Any, Any], tuple[Any, Any, Any]]:
    """Inverse of :func:`halfdiff_components`: angles to ``(wi, wo)`` components.

    ``wi = Rot_z(phi_h) Rot_y(theta_h) d`` with ``d`` the unit vector at ``(theta_d, phi_d)``;
    ``wo`` is the same rotation of ``d`` mirrored about the half vector, ``(-dx, -dy, dz)``.
    Returns ``((ix, iy, iz), (ox, oy, oz))``; either may lie below the horizon.
    """
    sd = ops.sin(theta_d)
    dx, dy, dz = sd * ops.cos(phi_d), sd * ops.sin(phi_d), ops.cos(theta_d)
    ct, st = ops.cos(theta_h), ops.sin(theta_h)
    cp, sp = ops.cos(phi_h), ops.sin(phi_h)

    def rotate(x: Any, y: Any, z: Any) -> tuple[Any, Any, Any]:
        x1 = x * ct + z * st
        z1 = z * ct - x * st
        return x1 * cp - y * sp, x1 * sp + y * cp, z1

    return rotate(dx, dy, dz), rotate(-dx, -dy, dz)


def merl_coordinates(
    theta_h: Any, theta_d: Any, phi_d: Any, phi_d_bins: int = 180, ops: ArrayOps = NUMPY_OPS
) -> tuple[Any, Any, Any]:
    """Continuous MERL bin coordinates ``(u_h, u_d, u_p)``: bin ``i`` covers ``[i, i+1)``.

    ``u_h = sqrt(theta_h / (pi/2)) * 90``, ``u_d = theta_d / (pi/2) * 90`` and
    ``u_p = (phi_d mod period) / period * phi_d_bins`` with ``period = pi`` for 180 bins
    (reciprocity fold) and ``2 pi`` for 360. Not clamped; see :func:`merl_indices`.
    """
    period = _phi_d_period(phi_d_bins)
    u_h = ops.sqrt(ops.maximum(theta_h, 0.0) * (1.0 / _HALF_PI)) * RES_THETA_H
    u_d = theta_d * (RES_THETA_D / _HALF_PI)
    folded = phi_d - period * ops.floor(phi_d * (1.0 / period))
    u_p = folded * (phi_d_bins / period)
    return u_h, u_d, u_p


def _phi_d_period(phi_d_bins: int) -> float:
    if phi_d_bins not in PHI_D_VARIANTS:
        raise ValueError(f"phi_d_bins must be one of {PHI_D_VARIANTS}, got {phi_d_bins}")
    return math.pi if phi_d_bins == 180 else 2.0 * math.pi


def to_halfdiff(
    wi: np.ndarray, wo: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(N, 3)`` direction pairs to ``(theta_h, phi_h, theta_d, phi_d)``, each ``(N,)``."""
    wi, wo = _as_pairs(wi, wo)
    return halfdiff_components(wi[:, 0], wi[:, 1], wi[:, 2], wo[:, 0], wo[:, 1], wo[:, 2])


def from_halfdiff(
    theta_h: np.ndarray, phi_h: np.ndarray | float, theta_d: np.ndarray, phi_d: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Angles (radians, broadcastable) to ``(wi, wo)``, each ``(N, 3)`` float64.

    Inputs are broadcast against each other and flattened in C order; trigonometry runs on
    the inputs before broadcasting, so separable grids (e.g. ``(90, 1, 1)``, ``(1, 90, 1)``,
    ``(1, 1, 180)``) are cheap.
    """
    th, ph, td, pd = (np.asarray(a, np.float64) for a in (theta_h, phi_h, theta_d, phi_d))
    shape = np.broadcast_shapes(th.shape, ph.shape, td.shape, pd.shape)
    i, o = directions_components(th, ph, td, pd)
    return (
        np.stack([np.broadcast_to(c, shape).ravel() for c in i], axis=-1),
        np.stack([np.broadcast_to(c, shape).ravel() for c in o], axis=-1),
    )


def merl_indices(
    theta_h: np.ndarray, theta_d: np.ndarray, phi_d: np.ndarray, phi_d_bins: int = 180
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bin indices ``(i_h, i_d, i_p)`` (int64 arrays) of angles in radians, clamped."""
    u_h, u_d, u_p = merl_coordinates(
        np.asarray(theta_h, np.float64),
        np.asarray(theta_d, np.float64),
        np.asarray(phi_d, np.float64),
        phi_d_bins,
    )
    return (
        np.clip(np.floor(u_h), 0, RES_THETA_H - 1).astype(np.int64),
        np.clip(np.floor(u_d), 0, RES_THETA_D - 1).astype(np.int64),
        np.clip(np.floor(u_p), 0, phi_d_bins - 1).astype(np.int64),
    )


def flat_index(
    i_h: np.ndarray, i_d: np.ndarray, i_p: np.ndarray, phi_d_bins: int = 180
) -> np.ndarray:
    """Offset into one colour plane of the file: ``i_p + P * (i_d + 90 * i_h)``."""
    return i_p + phi_d_bins * (i_d + RES_THETA_D * i_h)


def direction_indices(
    wi: np.ndarray, wo: np.ndarray, phi_d_bins: int = 180
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """MERL bin indices of ``(N, 3)`` direction pairs (see the module conventions)."""
    theta_h, _, theta_d, phi_d = to_halfdiff(wi, wo)
    return merl_indices(theta_h, theta_d, phi_d, phi_d_bins)


def bin_centers(phi_d_bins: int = 180) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """1-D bin-centre angles (radians): ``theta_h (90,)``, ``theta_d (90,)``, ``phi_d (P,)``.

    Centres in the continuous coordinates of :func:`merl_coordinates`, so
    ``merl_indices(*bin_centers())`` returns each bin's own index.
    """
    _phi_d_period(phi_d_bins)
    u = np.arange(RES_THETA_H) + 0.5
    theta_h = (u / RES_THETA_H) ** 2 * _HALF_PI
    theta_d = (np.arange(RES_THETA_D) + 0.5) / RES_THETA_D * _HALF_PI
    phi_d = (np.arange(phi_d_bins) + 0.5) * (math.pi / 180.0)
    return theta_h, theta_d, phi_d


def bin_directions(phi_d_bins: int = 180, phi_h: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """One direction pair per bin, at its centre, in table (C) order.

    Returns
    -------
    wi, wo
        ``(90 * 90 * P, 3)`` float64; row ``flat_index(i_h, i_d, i_p)`` is the pair of bin
        ``(i_h, i_d, i_p)`` at azimuth ``phi_h`` (default 0). Some pairs lie below the
        horizon (``wi.z <= 0`` or ``wo.z <= 0``); callers mark those bins missing.
    """
    th, td, pd = bin_centers(phi_d_bins)
    return from_halfdiff(th[:, None, None], phi_h, td[None, :, None], pd[None, None, :])


def lookup(
    rgb: np.ndarray, wi: np.ndarray, wo: np.ndarray, *, interpolate: bool = False
) -> np.ndarray:
    """Look up a MERL table at ``(N, 3)`` direction pairs.

    Parameters
    ----------
    rgb
        ``(90, 90, P, 3)`` physical BRDF values in 1/sr (``MerlTable.rgb``), ``P`` 180 or 360;
        negative entries are missing.
    wi, wo
        ``(N, 3)`` unit directions in the local frame, z up.
    interpolate
        ``False``: the value of the bin containing the pair (MERL's reference lookup).
        ``True``: multilinear interpolation between bin centres in the continuous coordinates
        ``(u_h, u_d, u_p)`` (square-root theta_h spacing, linear theta_d and phi_d); theta_h
        and theta_d are clamped at the table edges, phi_d wraps around (period pi for 180
        bins, by reciprocity; 2 pi for 360). Missing corners get zero weight and the others
        are renormalised.

    Returns
    -------
    ``(N, 3)`` float64 BRDF values in 1/sr. Pairs with ``wi.z <= 0`` or ``wo.z <= 0`` give 0;
    pairs whose bins are all missing give :data:`MISSING`.
    """
    rgb = np.asarray(rgb)
    if (
        rgb.ndim != 4
        or rgb.shape[:2] != (RES_THETA_H, RES_THETA_D)
        or rgb.shape[3] != 3
        or rgb.shape[2] not in PHI_D_VARIANTS
    ):
        raise ValueError(f"table must have shape (90, 90, 180 or 360, 3), got {rgb.shape}")
    wi, wo = _as_pairs(wi, wo)
    n_p = rgb.shape[2]
    theta_h, _, theta_d, phi_d = to_halfdiff(wi, wo)
    u_h, u_d, u_p = merl_coordinates(theta_h, theta_d, phi_d, n_p)
    if not interpolate:
        i_h = np.clip(np.floor(u_h), 0, RES_THETA_H - 1).astype(np.int64)
        i_d = np.clip(np.floor(u_d), 0, RES_THETA_D - 1).astype(np.int64)
        i_p = np.clip(np.floor(u_p), 0, n_p - 1).astype(np.int64)
        out = rgb[i_h, i_d, i_p].astype(np.float64)
    else:
        out = _interpolate(rgb, u_h, u_d, u_p)
    above = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    return np.where(above[:, None], out, 0.0)


def _interpolate(rgb: np.ndarray, u_h: np.ndarray, u_d: np.ndarray, u_p: np.ndarray) -> np.ndarray:
    n_p = rgb.shape[2]
    axes = []
    for u, n, periodic in ((u_h, RES_THETA_H, False), (u_d, RES_THETA_D, False), (u_p, n_p, True)):
        p = u - 0.5  # bin centres sit at integer p
        i0 = np.floor(p)
        w1 = p - i0
        i0 = i0.astype(np.int64)
        i1 = i0 + 1
        if periodic:
            i0, i1 = i0 % n, i1 % n
        else:  # clamp: beyond the outer centres both corners are the edge bin
            i0, i1 = np.clip(i0, 0, n - 1), np.clip(i1, 0, n - 1)
        axes.append(((i0, 1.0 - w1), (i1, w1)))
    acc = np.zeros(u_h.shape + (3,))
    wsum = np.zeros(u_h.shape + (3,))
    for ih, wh in axes[0]:
        for id_, wd in axes[1]:
            for ip, wp in axes[2]:
                v = rgb[ih, id_, ip]
                w = (wh * wd * wp)[:, None] * (v >= 0)
                acc += w * np.where(v >= 0, v, 0.0)
                wsum += w
    return np.where(wsum > 0, acc / np.maximum(wsum, 1e-300), MISSING)


def _as_pairs(wi: np.ndarray, wo: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    wi = np.asarray(wi, dtype=np.float64)
    wo = np.asarray(wo, dtype=np.float64)
    if wi.ndim != 2 or wi.shape[1] != 3 or wi.shape != wo.shape:
        raise ValueError(f"wi and wo must both have shape (N, 3), got {wi.shape} and {wo.shape}")
    return wi, wo
