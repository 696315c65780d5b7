"""The surface a BTF slice sees, as Mitsuba shapes.

World frame: z up, the material's patch is ``[-0.5, 0.5]^2`` at z = 0 (side 1, the unit of
:mod:`materials.btf.surfaces`' heights); texel ``[row = y, column = x]`` of an ``n x n`` map
has its centre at ``(x, y) = ((i + 0.5) / n - 0.5, (j + 0.5) / n - 0.5)``.

- A **flat** surface is a ``rectangle`` of side 6 carrying the user's BSDF dict: every ray
  that reaches the central patch from the hemisphere (theta <= 85 degrees) hits it, and
  so does every light path that could shade it.
- A **procedural** surface is its height field as a triangle mesh, one vertex per texel
  centre, tiled 3 x 3 (periodic heights) so that the central patch's edges see neighbours,
  not a cliff: shadowing, masking and interreflection near the edges are those of an
  infinite surface (to the relief's horizontal reach, far below one tile). The material is
  Mitsuba's ``principled`` BSDF with the albedo as ``base_color`` and the roughness map as
  ``roughness`` (bilinear, repeating bitmaps), dielectric, ``specular`` 0.5 (IOR 1.5).
"""

from __future__ import annotations

import types
from typing import Any

import numpy as np

from evaluators.render.meshes import grid_faces, triangle_mesh
from materials.btf.surfaces import SurfaceMaps

#: Tiles per side of the procedural mesh (odd: the central one is the patch).
TILES = 3
#: Side of the flat rectangle (patch units).
FLAT_SIDE = 6.0
#: The principled BSDF's ``specular`` (0.5: IOR 1.5).
SPECULAR = 0.5


def heightfield_arrays(height: np.ndarray, tiles: int = TILES) -> tuple[np.ndarray, ...]:
    """``(positions (V, 3), uv (V, 2), faces (F, 3) uint32)`` of the periodic height field
    ``height`` (``(n, n)``, patch units) tiled ``tiles x tiles`` about the origin, one vertex
    per texel centre, two triangles per cell, counter-clockwise seen from +z."""
    n = int(height.shape[0])
    m = tiles * n + 1
    idx = np.arange(m) - n * (tiles // 2)
    coord = (idx + 0.5) / n - 0.5
    xx, yy = np.meshgrid(coord, coord, indexing="xy")
    hh = np.asarray(height, np.float64)[np.ix_(idx % n, idx % n)]
    pos = np.stack([xx, yy, hh], axis=-1).reshape(-1, 3)
    uu, vv = np.meshgrid((idx + 0.5) / n, (idx + 0.5) / n, indexing="xy")
    uv = np.stack([uu, vv], axis=-1).reshape(-1, 2)
    return pos, uv, grid_faces(m, m)


def _bitmap(mi: types.ModuleType, arr: np.ndarray) -> dict[str, Any]:
    return {
        "type": "bitmap",
        "bitmap": mi.Bitmap(np.ascontiguousarray(arr, dtype=np.float32)),
        "raw": True,
        "wrap_mode": "repeat",
        "filter_type": "bilinear",
    }


def principled_dict(mi: types.ModuleType, maps: SurfaceMaps) -> dict[str, Any]:
    """The procedural patch's ``principled`` BSDF dict (textures from ``maps``).

    Mitsuba's bitmap row 0 is ``v = 0``, so texel ``[j, i]`` sits at ``uv = ((i + 0.5) / n,
    (j + 0.5) / n)``: the map's rows are y, as in the BTF convention.
    """
    return {
        "type": "principled",
        "base_color": _bitmap(mi, maps.albedo),
        "roughness": _bitmap(mi, maps.roughness[..., None]),
        "metallic": 0.0,
        "specular": SPECULAR,
    }


def procedural_mesh(mi: types.ModuleType, maps: SurfaceMaps, bsdf: Any = None) -> Any:
    """The tiled height-field ``mi.Mesh`` of ``maps`` carrying ``bsdf`` (default: its
    :func:`principled_dict`). Shading normals are the faces' (no vertex normals), so the
    geometry the light sees is exactly the one that shadows and masks."""
    pos, uv, faces = heightfield_arrays(maps.height)
    material = principled_dict(mi, maps) if bsdf is None else bsdf
    return triangle_mesh(mi, "btf_patch", pos, faces, material, uv=uv)


def flat_shape(mi: types.ModuleType, bsdf: Any) -> dict[str, Any]:
    """A flat ``rectangle`` at z = 0, normal +z, side :data:`FLAT_SIDE`, carrying ``bsdf``
    (a loaded BSDF or a plugin dict)."""
    return {
        "type": "rectangle",
        "bsdf": bsdf,
        "to_world": mi.ScalarTransform4f().scale([FLAT_SIDE / 2, FLAT_SIDE / 2, 1.0]),
    }
