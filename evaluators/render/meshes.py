"""Triangle meshes built from numpy arrays: the bent quad, BTF patches, relief floors."""

from __future__ import annotations

import types
from typing import Any

import numpy as np


def grid_faces(cols: int, rows: int) -> np.ndarray:
    """``(F, 3)`` uint32 triangles of a row-major grid of ``rows x cols`` vertices, two per
    cell (cell by cell, row-major), counter-clockwise when the columns run along +x and the
    rows along +y."""
    a = (np.arange(cols - 1)[None, :] + (np.arange(rows - 1) * cols)[:, None]).ravel()
    first = np.stack([a, a + 1, a + cols + 1], axis=1)
    second = np.stack([a, a + cols + 1, a + cols], axis=1)
    return np.stack([first, second], axis=1).reshape(-1, 3).astype(np.uint32)


def triangle_mesh(
    mi: types.ModuleType,
    name: str,
    positions: np.ndarray,
    faces: np.ndarray,
    bsdf: Any,
    *,
    uv: np.ndarray | None = None,
    normals: np.ndarray | None = None,
) -> Any:
    """An ``mi.Mesh`` of ``positions`` ``(V, 3)`` and ``faces`` ``(F, 3)`` carrying ``bsdf``
    (a loaded BSDF or a plugin dict), with optional ``uv`` ``(V, 2)`` and vertex
    ``normals`` ``(V, 3)`` (without them the faces' normals shade)."""
    import drjit as dr

    props = mi.Properties()
    props["bsdf"] = mi.load_dict(bsdf) if isinstance(bsdf, dict) else bsdf
    mesh = mi.Mesh(
        name, len(positions), len(faces), props=props,
        has_vertex_normals=normals is not None, has_vertex_texcoords=uv is not None,
    )  # fmt: skip
    params = mi.traverse(mesh)
    params["vertex_positions"] = dr.ravel(mi.Point3f(*np.asarray(positions, np.float32).T))
    if normals is not None:
        params["vertex_normals"] = dr.ravel(mi.Normal3f(*np.asarray(normals, np.float32).T))
    if uv is not None:
        params["vertex_texcoords"] = dr.ravel(mi.Point2f(*np.asarray(uv, np.float32).T))
    params["faces"] = dr.ravel(mi.Vector3u(*np.asarray(faces, np.uint32).T))
    params.update()
    return mesh
