"""A procedural BTF surface as real geometry on a scene's floor: the height field of a
``generate.btf`` job tiled over the square, for the ``{"btf_surface": ...}`` material.

The surface ``generate.btf`` path-traced is one periodic patch (side 1, heights in patch
units; :mod:`~evaluators.render.btf.patch`). Here it covers the floor square of a scene
(``plane_points``, ``cloth_plane``), whose uv runs over ``[0, 1]^2``, ``uv_scale`` times per
side, so that it lines up texel for texel with a ``{"btf": ...}`` or ``{"model": ...}``
render of the same job at the same ``uv_scale``:

- **Coordinates.** The floor point of uv ``(u, v)`` carries patch coordinates ``(p_x, p_y) =
  (s u, s v)``; texel ``[j, i]`` of the maps (and of every slice) is centred at ``p = ((i +
  0.5) / n, (j + 0.5) / n)`` modulo 1. Mitsuba's ``rectangle`` (the floor) has ``u`` along
  world +x and ``v`` along world -z (away from the default cameras), its normal +y, and its
  shading frame ``(dp/du, dp/dv, n)``: the patch's x, y and z.
- **Scale.** One patch spans ``2 h / s`` world units for a square of half-side ``h``; its
  heights are multiplied by the same factor (the patch is scaled uniformly, so slopes,
  shadowing and masking are those ``generate.btf`` rendered). A non-square scale has no
  such equivalent and is refused by the material source.
- **Mesh.** One vertex per texel centre inside the square plus a row and a column on each of
  its edges (heights bilinear and periodic there), two triangles per cell, face normals as
  shading normals, vertex uv = patch coordinates (so the ``principled`` BSDF's repeating
  albedo and roughness bitmaps tile with it): the mesh of
  :func:`~evaluators.render.btf.patch.procedural_mesh`, cut to the square.
"""

from __future__ import annotations

import math
import types
from dataclasses import dataclass
from typing import Any

import numpy as np

from evaluators.render.meshes import grid_faces, triangle_mesh

#: Most vertices of a relief mesh (about 0.2 GB of Mitsuba geometry).
MAX_RELIEF_VERTICES = 1 << 22


@dataclass(frozen=True)
class Relief:
    """A periodic height field ``(n, n)`` (patch units) repeated ``scale`` times per side
    of a floor's uv square."""

    height: np.ndarray
    scale: float

    @property
    def vertices(self) -> int:
        """Vertex count of the mesh :func:`relief_arrays` builds."""
        return len(axis_coordinates(self.height.shape[1], self.scale)) * len(
            axis_coordinates(self.height.shape[0], self.scale)
        )


def axis_coordinates(n: int, scale: float) -> np.ndarray:
    """Patch coordinates of the vertices along one side: 0, every texel centre ``(i + 0.5)
    / n`` strictly inside ``(0, scale)``, and ``scale``."""
    count = max(0, math.ceil(scale * n - 0.5))
    centres = (np.arange(count) + 0.5) / n
    centres = centres[centres < scale - 1e-9]
    return np.concatenate([[0.0], centres, [float(scale)]])


def periodic_bilinear(values: np.ndarray, px: np.ndarray, py: np.ndarray) -> np.ndarray:
    """``values`` (``(H, W)``, texel centres at ``((i + 0.5) / W, (j + 0.5) / H)``,
    periodic) at the grid ``py x px`` of patch coordinates: ``(len(py), len(px))``."""
    h, w = values.shape
    x = np.asarray(px, np.float64) * w - 0.5
    y = np.asarray(py, np.float64) * h - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0)[None, :], (y - y0)[:, None]
    i0, j0 = x0.astype(np.int64) % w, y0.astype(np.int64) % h
    i1, j1 = (i0 + 1) % w, (j0 + 1) % h
    v = np.asarray(values, np.float64)
    top = v[np.ix_(j0, i0)] * (1 - fx) + v[np.ix_(j0, i1)] * fx
    bottom = v[np.ix_(j1, i0)] * (1 - fx) + v[np.ix_(j1, i1)] * fx
    return top * (1 - fy) + bottom * fy


def relief_arrays(relief: Relief, half_size: float) -> tuple[np.ndarray, ...]:
    """``(positions (V, 3), uv (V, 2), faces (F, 3) uint32)`` in world units of the relief
    on the floor square of half-side ``half_size`` (y = 0, normal +y, u along +x, v along
    -z); counter-clockwise seen from +y."""
    s = float(relief.scale)
    n_rows, n_cols = relief.height.shape
    px = axis_coordinates(n_cols, s)
    py = axis_coordinates(n_rows, s)
    tile = 2.0 * half_size / s
    hh = periodic_bilinear(relief.height, px, py) * tile
    xx, zz = np.meshgrid(-half_size + tile * px, half_size - tile * py, indexing="xy")
    pos = np.stack([xx, hh, zz], axis=-1).reshape(-1, 3)
    uu, vv = np.meshgrid(px, py, indexing="xy")
    uv = np.stack([uu, vv], axis=-1).reshape(-1, 2)
    return pos, uv, grid_faces(len(px), len(py))


def relief_mesh(mi: types.ModuleType, relief: Relief, half_size: float, bsdf: Any) -> Any:
    """The ``mi.Mesh`` of :func:`relief_arrays` carrying ``bsdf`` (a loaded BSDF or dict)."""
    pos, uv, faces = relief_arrays(relief, half_size)
    return triangle_mesh(mi, "btf_relief", pos, faces, bsdf, uv=uv)
