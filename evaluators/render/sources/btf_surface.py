"""``{"btf_surface": "job:<generate.btf id>"}``: the surface a ``generate.btf`` job
path-traced, rendered as itself: the reference that renders of its BTF (``{"btf": ...}``)
and of models trained on it (``{"model": ...}``) are scored against.

::

    {"btf_surface": "job:<generate.btf id>", "uv_scale": 4}

Named for what it renders: not a BTF (a function tabulated or learnt from slices) but the
surface the slices were taken of, geometry and all.

- A **procedural** surface (``{"procedural": ...}`` in the job's ``btf.json``) is rebuilt
  from the job's ``height.exr``, ``albedo.exr`` and ``roughness.exr``: the ``principled``
  BSDF of :func:`evaluators.render.btf.patch.principled_dict` (wrapped by the
  ``btf_surface`` BSDF, :mod:`evaluators.render.bsdfs.btf_surface`, which carries the
  height field), and the relief mesh of :mod:`evaluators.render.btf.relief` in place of the
  scene's floor, tiled ``uv_scale`` times per side with heights scaled with the tile. Only
  the floor scenes (``plane_points``, ``cloth_plane``) can replace their geometry; the
  others refuse it. ``uv_scale`` must be one number here (the relief scales uniformly).
- A **flat** surface (``{"bsdf": {...}}``) is the job's Mitsuba BSDF on the scene's own
  shape, in any scene (``uv_scale`` does not apply).

Conventions (uv of the floor to patch coordinates, orientation, scale) are those of
:mod:`evaluators.render.btf.relief` and :mod:`.btf`, so this render lines up texel for
texel with ``{"btf": REF, "uv_scale": s}`` of the same job.
"""

from __future__ import annotations

import types
from typing import TYPE_CHECKING, Any

import numpy as np

from evaluators.render.bsdfs.btf_surface import BTF_SURFACE_NAME, register_btf_surface_bsdf
from evaluators.render.btf.patch import principled_dict
from evaluators.render.btf.relief import MAX_RELIEF_VERTICES, Relief
from evaluators.render.sources.btf import BtfSiblings, uv_scale_pair
from evaluators.render.sources.common import register_material_source
from jobapi.errors import FormatError, JobFailed
from jobapi.params import JobRef, job_id_of
from materials.btf.surfaces import SurfaceMaps
from storage.formats.btf import parse_index
from storage.formats.exr import read_exr

if TYPE_CHECKING:
    from jobapi.context import JobContext


def _map(ctx: JobContext, job_id: str, name: str, field: str) -> np.ndarray:
    try:
        return read_exr(ctx.resolve(f"job:{job_id}/{name}"), name)
    except FormatError as exc:
        raise JobFailed(f"{field}: {exc}") from None


def resolve_btf_surface(value: dict[str, Any], ctx: JobContext, mi: types.ModuleType) -> Any:
    """Resolve ``{"btf_surface": REF, ...}``: the job's flat BSDF dict, or a ``btf_surface``
    BSDF carrying the procedural surface's relief. :class:`JobFailed` naming the field when
    the job is not a succeeded ``generate.btf`` job, its files are malformed, or the relief
    mesh would exceed :data:`~evaluators.render.btf.relief.MAX_RELIEF_VERTICES`."""
    field = "material.btf_surface"
    job_id = job_id_of(value["btf_surface"])
    ctx.input_job(job_id, field, "generate.btf")
    try:
        index = parse_index(ctx.read_ref(f"job:{job_id}/btf.json"))
    except FormatError as exc:
        raise JobFailed(f"{field}: {exc}") from None
    surface = index.doc.get("surface")
    if isinstance(surface, dict) and isinstance(surface.get("bsdf"), dict):
        return dict(surface["bsdf"])
    if not isinstance(surface, dict) or "procedural" not in surface:
        raise JobFailed(f"{field}: job {job_id}'s btf.json describes no surface")
    su, sv = uv_scale_pair(value)
    if su != sv:
        raise JobFailed(
            f"material.uv_scale: a btf_surface's relief scales with its tile, so the tile "
            f"must stay square: give one number, not [{su:g}, {sv:g}]"
        )
    height = _map(ctx, job_id, "height.exr", field)[..., 0]
    albedo = _map(ctx, job_id, "albedo.exr", field)
    roughness = _map(ctx, job_id, "roughness.exr", field)[..., 0]
    if height.shape != albedo.shape[:2] or height.shape != roughness.shape:
        raise JobFailed(f"{field}: job {job_id}'s height, albedo and roughness maps differ in size")
    # Heights are in the patch's units; btf.json records its side (1 for generate.btf).
    side = float((index.doc.get("patch") or {}).get("side") or 1.0)
    relief = Relief(height=np.ascontiguousarray(height / side, np.float32), scale=su)
    if relief.vertices > MAX_RELIEF_VERTICES:
        raise JobFailed(
            f"material.uv_scale: {su:g} repeats of the {height.shape[0]}^2 patch make a mesh of "
            f"{relief.vertices} vertices, more than {MAX_RELIEF_VERTICES}; lower uv_scale"
        )
    maps = SurfaceMaps(height=height, albedo=albedo, roughness=roughness)
    try:
        register_btf_surface_bsdf(mi)
    except RuntimeError as exc:
        raise JobFailed(f"{field}: {exc}") from None
    bsdf = mi.load_dict({"type": BTF_SURFACE_NAME, "bsdf": principled_dict(mi, maps)})
    bsdf.relief = relief
    return bsdf


register_material_source(
    "btf_surface",
    resolve_btf_surface,
    value_type=JobRef,
    siblings=BtfSiblings,
    summary="The surface a generate.btf job path-traced, as itself: {'btf_surface': "
    "'job:<generate.btf id>', optional 'uv_scale': s}; a procedural surface replaces the "
    "floor of plane_points or cloth_plane with its relief mesh (principled BSDF with its "
    "maps), a flat one is its Mitsuba BSDF.",
)
