"""Interpolation between a BTF's measured directions: barycentric weights over a
triangulation of the hemisphere, in numpy (the set-up) and Dr.Jit (the evaluation).

A BTF is measured at a finite set of light directions and a finite set of view directions
(UBO2014: 151 of each; :data:`~materials.btf.directions.SMALL_DIRECTIONS`: 6). To evaluate
it at any other direction ``w``, :func:`direction_weights` gives up to three of the set's
directions and weights (non-negative, summing to 1):

- **Projection.** Directions map to the unit disk by the azimuthal equidistant projection
  ``p(w) = theta / (pi / 2) (cos phi, sin phi)``: rings of constant ``theta`` (how measured
  sets are laid out) become concentric circles evenly spaced in ``theta``, so a weight is
  linear in ``theta`` along a meridian and the horizon is the unit circle.
- **Inside the hull** of the projected set: the barycentric coordinates of ``p(w)`` in the
  triangle of the set's Delaunay triangulation (Qhull through ``scipy.spatial.Delaunay``)
  that holds it. Continuous, piecewise linear, and exact at the measured directions (the
  weight is 1 there, so a measured value comes back unchanged). ``scipy.interpolate.
  LinearNDInterpolator`` over the same projected points is the independent reference.
- **Outside the hull** (beyond the outermost ring, towards the horizon, or in a gap of a
  sparse set): the closest point of the hull's boundary, linear along that edge. The
  values are held constant outwards; continuous across the hull.
- **Degenerate sets** (one direction, or all of them on one line of the disk, e.g. two
  directions): the closest point of the polyline through them (one direction: weight 1).

Weights below :data:`SNAP` are set to 0 and the rest renormalised, so a query at a measured
direction (up to float32 rounding of the projection) gets exactly one weight of 1.

Point location uses a ``G x G`` grid over ``[-1, 1]^2`` listing, per cell, the triangles
whose bounding box overlaps the cell (at most ``K``, padded with -1); the kernel tests those
``K`` and keeps the one where ``p(w)`` lies deepest inside. The hull's edges are visited by a
symbolic loop, only by lanes that found no triangle.
"""

from __future__ import annotations

import math
import types
from dataclasses import dataclass
from typing import Any

import numpy as np

#: Weights below this are dropped (and the rest renormalised): exactness at the measured
#: directions despite float32 rounding of the projection.
SNAP = 1e-5
#: A point lies in a triangle when its smallest barycentric coordinate is at least -this.
INSIDE_TOLERANCE = 1e-5
#: Most triangles listed per grid cell; the grid is refined until no cell holds more.
MAX_CANDIDATES = 12
#: Finest point-location grid (cells per side).
MAX_GRID = 512


def project(w: np.ndarray) -> np.ndarray:
    """The azimuthal equidistant projection of unit vectors ``(N, 3)`` (z up): ``(N, 2)``
    float64 points of the unit disk (the horizon is the unit circle)."""
    w = np.asarray(w, np.float64)
    theta = np.arccos(np.clip(w[:, 2], -1.0, 1.0))
    s = np.hypot(w[:, 0], w[:, 1])
    k = np.where(s > 1e-7, theta / np.maximum(s, 1e-300), 1.0) * (2.0 / math.pi)
    return np.stack([w[:, 0] * k, w[:, 1] * k], axis=1)


@dataclass(frozen=True)
class DirectionMesh:
    """A direction set ready for interpolation (see the module docstring).

    ``directions`` ``(n, 3)`` float32 unit vectors; ``points`` their projections ``(n, 2)``;
    ``triangles`` ``(T, 3)`` int32 vertex indices with ``frames`` ``(T, 7)`` float32
    ``(a_x, a_y, (b - a)_x, (b - a)_y, (c - a)_x, (c - a)_y, 1 / det)``; ``grid`` cells per
    side and ``candidates`` ``(grid^2, K)`` int32 triangle indices (-1: none); ``edges``
    ``(E, 2)`` int32 of the hull (or the polyline of a degenerate set) with ``segments``
    ``(E, 5)`` float32 ``(a_x, a_y, (b - a)_x, (b - a)_y, 1 / |b - a|^2)`` (0 for a point).
    """

    directions: np.ndarray
    points: np.ndarray
    triangles: np.ndarray
    frames: np.ndarray
    grid: int
    candidates: np.ndarray
    edges: np.ndarray
    segments: np.ndarray

    def __len__(self) -> int:
        return int(self.directions.shape[0])


def _triangulate(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(triangles (T, 3), hull edges (E, 2))`` of the Delaunay triangulation, or no
    triangles and the polyline through the points when they are fewer than 3 or collinear."""
    from scipy.spatial import Delaunay, QhullError

    n = len(points)
    centred = points - points.mean(axis=0)
    flat = n < 3 or np.linalg.matrix_rank(centred, tol=1e-9) < 2
    if not flat:
        try:
            tri = Delaunay(points)
        except QhullError:
            flat = True
    if flat:
        if n == 1:
            return np.zeros((0, 3), np.int32), np.zeros((1, 2), np.int32)
        # Order along the line's direction (the principal axis of the centred points).
        axis = np.linalg.svd(centred, full_matrices=False)[2][0]
        order = np.argsort(centred @ axis, kind="stable")
        return np.zeros((0, 3), np.int32), np.stack([order[:-1], order[1:]], 1).astype(np.int32)
    simplices = np.asarray(tri.simplices, np.int64)
    a, b, c = (points[simplices[:, k]] for k in range(3))
    det = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    keep = np.abs(det) > 1e-12  # Qhull's triangulated output may hold flat slivers
    return simplices[keep].astype(np.int32), np.asarray(tri.convex_hull, np.int32)


def _candidates(points: np.ndarray, triangles: np.ndarray) -> tuple[int, np.ndarray]:
    """``(G, (G * G, K) int32)``: per cell of a ``G x G`` grid over ``[-1, 1]^2``, the
    triangles whose bounding box (padded) overlaps it, refining ``G`` until ``K`` is at
    most :data:`MAX_CANDIDATES`."""
    t = len(triangles)
    if t == 0:
        return 1, np.full((1, 1), -1, np.int32)
    corners = points[triangles]  # (T, 3, 2)
    lo, hi = corners.min(axis=1) - 1e-6, corners.max(axis=1) + 1e-6
    g = max(4, 1 << math.ceil(math.log2(max(2.0, math.sqrt(t)))))
    while True:
        c0 = np.clip(np.floor((lo + 1.0) * 0.5 * g), 0, g - 1).astype(np.int64)
        c1 = np.clip(np.floor((hi + 1.0) * 0.5 * g), 0, g - 1).astype(np.int64)
        cells: list[list[int]] = [[] for _ in range(g * g)]
        for k in range(t):
            for iy in range(c0[k, 1], c1[k, 1] + 1):
                row = iy * g
                for ix in range(c0[k, 0], c1[k, 0] + 1):
                    cells[row + ix].append(k)
        most = max(len(c) for c in cells)
        if most <= MAX_CANDIDATES or g >= MAX_GRID:
            break
        g *= 2
    table = np.full((g * g, max(1, most)), -1, np.int32)
    for i, c in enumerate(cells):
        table[i, : len(c)] = c
    return g, table


def build_direction_mesh(directions: np.ndarray) -> DirectionMesh:
    """The :class:`DirectionMesh` of distinct unit directions ``(n, 3)`` above the plane."""
    d = np.asarray(directions, np.float32)
    if d.ndim != 2 or d.shape[1] != 3 or len(d) < 1:
        raise ValueError(f"directions must be a non-empty (n, 3) array, got {d.shape}")
    if np.any(d[:, 2] <= 0.0):
        raise ValueError("directions must lie above the plane (z > 0)")
    points = project(d)
    if len(np.unique(np.round(points, 9), axis=0)) != len(points):
        raise ValueError("directions must be distinct")
    triangles, edges = _triangulate(points)
    a = points[triangles[:, 0]]
    e1 = points[triangles[:, 1]] - a
    e2 = points[triangles[:, 2]] - a
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    frames = np.column_stack([a, e1, e2, 1.0 / np.where(det == 0, 1.0, det)])
    grid, candidates = _candidates(points, triangles)
    sa = points[edges[:, 0]]
    sd = points[edges[:, 1]] - sa
    len2 = np.sum(sd * sd, axis=1)
    inv = np.where(len2 > 0, 1.0 / np.where(len2 > 0, len2, 1.0), 0.0)
    return DirectionMesh(
        directions=d,
        points=points,
        triangles=triangles,
        frames=frames.astype(np.float32).reshape(-1, 7),
        grid=grid,
        candidates=candidates,
        edges=edges,
        segments=np.column_stack([sa, sd, inv]).astype(np.float32).reshape(-1, 5),
    )


# -- Dr.Jit ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class JitDirectionMesh:
    """A :class:`DirectionMesh` as flat Dr.Jit arrays (row-major) and its sizes."""

    n: int
    n_triangles: int
    n_edges: int
    grid: int
    k: int
    triangles: Any  # UInt32 (T * 3)
    frames: Any  # Float (T * 7)
    candidates: Any  # Int32 (G * G * K)
    edges: Any  # UInt32 (E * 2)
    segments: Any  # Float (E * 5)


def jit_direction_mesh(mi: types.ModuleType, mesh: DirectionMesh) -> JitDirectionMesh:
    """Upload ``mesh`` to the variant of ``mi`` (a vectorised Mitsuba module)."""

    def flat(arr: np.ndarray, kind: Any, dtype: Any) -> Any:
        a = np.ascontiguousarray(arr, dtype=dtype).ravel()
        return kind(a) if a.size else kind(np.zeros(1, dtype))

    return JitDirectionMesh(
        n=len(mesh),
        n_triangles=int(len(mesh.triangles)),
        n_edges=int(len(mesh.edges)),
        grid=int(mesh.grid),
        k=int(mesh.candidates.shape[1]),
        triangles=flat(mesh.triangles, mi.UInt32, np.uint32),
        frames=flat(mesh.frames, mi.Float, np.float32),
        candidates=flat(mesh.candidates, mi.Int32, np.int32),
        edges=flat(mesh.edges, mi.UInt32, np.uint32),
        segments=flat(mesh.segments, mi.Float, np.float32),
    )


def project_jit(mi: types.ModuleType, w: Any) -> tuple[Any, Any]:
    """:func:`project` in Dr.Jit: ``(x, y)`` of a ``Vector3f``."""
    import drjit as dr

    theta = dr.acos(dr.clip(w.z, -1.0, 1.0))
    s = dr.sqrt(dr.maximum(w.x * w.x + w.y * w.y, 0.0))
    k = dr.select(s > 1e-7, theta / dr.maximum(s, 1e-30), 1.0) * (2.0 / math.pi)
    return w.x * k, w.y * k


def direction_weights(
    mi: types.ModuleType, mesh: JitDirectionMesh, w: Any, active: Any = True
) -> tuple[list[Any], list[Any]]:
    """``([i0, i1, i2], [w0, w1, w2])``: indices into the mesh's directions (``UInt32``) and
    their weights (``Float``, >= 0, summing to 1) for the unit vectors ``w`` (``Vector3f``,
    z up); see the module docstring. Lanes outside ``active`` get weights 0."""
    import drjit as dr

    active = mi.Bool(active)
    qx, qy = project_jit(mi, w)
    found = mi.Bool(False)
    idx = [mi.UInt32(0), mi.UInt32(0), mi.UInt32(0)]
    lam = [mi.Float(0.0), mi.Float(0.0), mi.Float(0.0)]
    if mesh.n_triangles:
        g = mesh.grid
        cx = dr.clip(mi.Int32(dr.floor((qx + 1.0) * (0.5 * g))), 0, g - 1)
        cy = dr.clip(mi.Int32(dr.floor((qy + 1.0) * (0.5 * g))), 0, g - 1)
        cell = mi.UInt32(cy * g + cx) * mesh.k
        best = mi.Float(-dr.inf)
        best_t = mi.UInt32(0)
        best_b = mi.Float(0.0)
        best_c = mi.Float(0.0)
        for j in range(mesh.k):
            t = dr.gather(mi.Int32, mesh.candidates, cell + j, active)
            valid = active & (t >= 0)
            base = mi.UInt32(dr.maximum(t, 0)) * 7
            f = [dr.gather(mi.Float, mesh.frames, base + c, valid) for c in range(7)]
            px, py = qx - f[0], qy - f[1]
            lb = (px * f[5] - py * f[4]) * f[6]
            lc = (f[2] * py - f[3] * px) * f[6]
            la = 1.0 - lb - lc
            score = dr.select(valid, dr.minimum(la, dr.minimum(lb, lc)), -dr.inf)
            better = score > best
            best = dr.select(better, score, best)
            best_t = dr.select(better, mi.UInt32(dr.maximum(t, 0)), best_t)
            best_b = dr.select(better, lb, best_b)
            best_c = dr.select(better, lc, best_c)
        found = active & (best >= -INSIDE_TOLERANCE)
        idx = [dr.gather(mi.UInt32, mesh.triangles, best_t * 3 + c, found) for c in range(3)]
        lam = [1.0 - best_b - best_c, best_b, best_c]

    # Outside the hull: the closest point of its boundary (a symbolic loop over the edges).
    outside = active & ~found

    def cond(i: Any, d2: Any, e: Any, s: Any) -> Any:
        return outside & (i < mesh.n_edges)

    def body(i: Any, d2: Any, e: Any, s: Any) -> tuple[Any, Any, Any, Any]:
        base = i * 5
        seg = [dr.gather(mi.Float, mesh.segments, base + c) for c in range(5)]
        px, py = qx - seg[0], qy - seg[1]
        t = dr.clip((px * seg[2] + py * seg[3]) * seg[4], 0.0, 1.0)
        dx, dy = px - t * seg[2], py - t * seg[3]
        dist = dx * dx + dy * dy
        closer = dist < d2
        return (
            i + 1,
            dr.select(closer, dist, d2),
            dr.select(closer, i, e),
            dr.select(closer, t, s),
        )

    _, _, edge, along = dr.while_loop(
        (mi.UInt32(0), mi.Float(dr.inf), mi.UInt32(0), mi.Float(0.0)), cond, body
    )
    ea = dr.gather(mi.UInt32, mesh.edges, edge * 2, outside)
    eb = dr.gather(mi.UInt32, mesh.edges, edge * 2 + 1, outside)
    idx = [
        dr.select(outside, ea, idx[0]),
        dr.select(outside, eb, idx[1]),
        dr.select(outside, ea, idx[2]),
    ]
    lam = [
        dr.select(outside, 1.0 - along, lam[0]),
        dr.select(outside, along, lam[1]),
        dr.select(outside, 0.0, lam[2]),
    ]
    lam = [dr.select(active & (v >= SNAP), v, 0.0) for v in lam]
    total = lam[0] + lam[1] + lam[2]
    # A division, not a reciprocal: x / x is exactly 1 where one weight is left.
    safe = dr.select(total > 0.0, total, 1.0)
    return idx, [v / safe for v in lam]
