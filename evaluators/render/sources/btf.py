"""``{"btf": "job:<id>"}``: a BTF job's slices rendered as a table BSDF; and what the BTF
materials share: the ``uv_scale`` sibling and the BTF branch of ``{"model": ...}``.

::

    {"btf": "job:<generate.btf or import.btf id>", "uv_scale": 4}
    {"model": "job:<train.btf id>", "uv_scale": 4}
    {"btf_surface": "job:<generate.btf id>", "uv_scale": 4}     # (sources/btf_surface.py)

``{"btf": REF}`` loads the whole BTF (every slice, float32) into the ``btf_table`` BSDF
(:mod:`evaluators.render.bsdfs.btf_table`): bilinear between texels, barycentric between
measured directions. It refuses a BTF over
:data:`~evaluators.render.bsdfs.btf_table.MAX_TABLE_BYTES` (2 GiB); render a trained model of
it instead.

``{"model": "job:<train.btf id>"}`` (a whole-job reference: a BTF model is two files,
``model.json`` and ``textures.npz``) renders the trained model through the ``btf_model``
BSDF (:mod:`evaluators.render.bsdfs.btf_model`); :mod:`.model` hands such references here.

``uv_scale`` (optional sibling key, default 1): how many times the patch repeats per unit
of the shape's uv, a number or ``[s_u, s_v]``. The patch coordinates of a shading point are
``(s_u u, s_v v)``; the patch is periodic, texel ``[j, i]`` centred at ``((i + 0.5) / W,
(j + 0.5) / H)``, ``u`` along its columns (x), ``v`` along its rows (y). On
``plane_points`` (an 8 x 8 square, uv over ``[0, 1]^2``, u along world +x, v along world
-z) the patch is ``8 / s`` world units wide; on the spheres (Mitsuba's uv: ``u = phi / 2 pi``
around the z axis, which points at the default camera, ``v = theta / pi`` from +z) it
repeats ``s_u`` times around and ``s_v`` times pole to pole (``[2 s, s]`` gives square
tiles at the equator; an integer ``s_u`` hides the seam at ``phi = 0``).
"""

from __future__ import annotations

import json
import math
import types
from typing import TYPE_CHECKING, Annotated, Any

from pydantic import AfterValidator, Field, WithJsonSchema

from evaluators.render.bsdfs.btf_model import BTF_MODEL_NAME, register_btf_model_bsdf
from evaluators.render.bsdfs.btf_table import (
    BTF_TABLE_NAME,
    MAX_TABLE_BYTES,
    build_table,
    put_table,
    register_btf_table_bsdf,
)
from evaluators.render.sources.common import register_material_source
from jobapi.errors import FormatError, JobFailed
from jobapi.params import JobRef, StrictModel, job_id_of
from models.btf.data import BTF_KINDS, BtfDataset
from storage.formats.btf import parse_index

if TYPE_CHECKING:
    from jobapi.context import JobContext

#: The ``format`` of a BTF ``model.json`` (:data:`models.btf.portable.FORMAT`; repeated
#: here so that validating a spec does not import torch).
BTF_MODEL_FORMAT = "matforge.btf-model/1"
#: Largest ``uv_scale``.
MAX_UV_SCALE = 4096.0


def _check_uv_scale(value: float | list[float]) -> float | list[float]:
    values = value if isinstance(value, list) else [value]
    if isinstance(value, list) and len(value) != 2:
        raise ValueError("must be a number or a pair [s_u, s_v]")
    for v in values:
        if not (math.isfinite(v) and 0.0 < v <= MAX_UV_SCALE):
            raise ValueError(f"must be positive and at most {MAX_UV_SCALE:g}, got {v}")
    return value


_SCALE_SCHEMA = {"type": "number", "exclusiveMinimum": 0, "maximum": MAX_UV_SCALE}
#: ``uv_scale``: a positive number, or ``[s_u, s_v]``.
UvScale = Annotated[
    float | list[float],
    AfterValidator(_check_uv_scale),
    WithJsonSchema(
        {"anyOf": [_SCALE_SCHEMA, {"type": "array", "items": _SCALE_SCHEMA, "minItems": 2,
                                   "maxItems": 2}]}
    ),
]  # fmt: skip

UV_SCALE_DESCRIPTION = (
    "How many times the BTF's patch repeats per unit of the shape's uv: a number or "
    "[s_u, s_v] (default 1). plane_points is 8 x 8 world units over uv [0, 1]^2."
)


class BtfSiblings(StrictModel):
    """The keys next to ``"btf"`` (and ``"btf_surface"``) in a material object."""

    uv_scale: UvScale | None = Field(default=None, description=UV_SCALE_DESCRIPTION)


def uv_scale_pair(value: dict[str, Any]) -> tuple[float, float]:
    """``(s_u, s_v)`` of a material object's ``uv_scale`` (default ``(1, 1)``)."""
    s = value.get("uv_scale")
    if s is None:
        return 1.0, 1.0
    if isinstance(s, list | tuple):
        return float(s[0]), float(s[1])
    return float(s), float(s)


def _scale_props(value: dict[str, Any]) -> dict[str, float]:
    su, sv = uv_scale_pair(value)
    return {"uv_scale_u": su, "uv_scale_v": sv}


def resolve_btf(value: dict[str, Any], ctx: JobContext, mi: types.ModuleType) -> Any:
    """Resolve ``{"btf": REF, ...}`` to an instantiated ``btf_table`` BSDF.

    Raises :class:`JobFailed` naming ``material.btf`` when the job is missing, not a
    succeeded ``generate.btf``/``import.btf`` job, malformed, or larger than the table's
    limit.
    """
    field = "material.btf"
    job_id = job_id_of(value["btf"])
    job = ctx.input_job(job_id, field)
    if job.kind not in BTF_KINDS:
        raise JobFailed(
            f"{field}: job {job_id} is a {job.kind} job, not a BTF ({' or '.join(BTF_KINDS)}); "
            f"a trained BTF model renders as {{'model': 'job:<train.btf id>'}}"
        )
    try:
        index = parse_index(ctx.read_ref(f"job:{job_id}/btf.json"))
    except FormatError as exc:
        raise JobFailed(f"{field}: {exc}") from None
    h, w = index.resolution
    nbytes = index.count * h * w * 3 * 4
    if nbytes > MAX_TABLE_BYTES:
        raise JobFailed(
            f"{field}: the BTF of job {job_id} ({index.count} slices of {h}x{w}) takes "
            f"{nbytes / 2**30:.1f} GiB as float32, more than the table BSDF's "
            f"{MAX_TABLE_BYTES / 2**30:.0f} GiB; render a trained model of it "
            f"({{'model': 'job:<train.btf id>'}}) or a smaller BTF"
        )
    data = BtfDataset.open(f"job:{job_id}", ctx, field)
    if data.slices is None:  # cannot happen below the limit; guards a changed reader
        raise JobFailed(f"{field}: the BTF of job {job_id} did not load into memory")
    try:
        register_btf_table_bsdf(mi)
    except RuntimeError as exc:
        raise JobFailed(f"{field}: {exc}") from None
    table = build_table(mi, data.wi, data.wo, data.slices)
    return mi.load_dict({"type": BTF_TABLE_NAME, "table": put_table(table), **_scale_props(value)})


def resolve_btf_model(value: dict[str, Any], ctx: JobContext, mi: types.ModuleType) -> Any:
    """Resolve ``{"model": "job:<id>", ...}`` (a whole-job reference) to a ``btf_model``
    BSDF: the job's ``model.json`` must be a ``matforge.btf-model/1`` document (a
    ``train.btf`` job). :class:`JobFailed` naming ``material.model`` otherwise."""
    from models.btf.portable import read_model, read_textures

    field = "material.model"
    job_id = job_id_of(value["model"])
    job = ctx.input_job(job_id, field)
    names = {a.name for a in job.artifacts}
    hint = (
        "a whole-job reference 'job:<id>' names a trained BTF model (train.btf); a BRDF "
        "or fabric model takes its artifact, e.g. {'model': 'job:<id>/model.json', "
        "'material': NAME}"
    )
    if "model.json" not in names or "textures.npz" not in names:
        raise JobFailed(f"{field}: job {job_id} is a {job.kind} job without a BTF model; {hint}")
    model_path = ctx.resolve(f"job:{job_id}/model.json")
    textures_path = ctx.resolve(f"job:{job_id}/textures.npz")
    try:
        doc = json.loads(model_path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise JobFailed(f"{field}: job {job_id}: model.json is not JSON ({exc})") from None
    if not isinstance(doc, dict) or doc.get("format") != BTF_MODEL_FORMAT:
        raise JobFailed(f"{field}: job {job_id} is a {job.kind} job, not a BTF model; {hint}")
    try:
        read_model(doc, read_textures(textures_path.read_bytes()))
    except ValueError as exc:
        raise JobFailed(f"{field}: job {job_id}: {exc}") from None
    try:
        register_btf_model_bsdf(mi)
    except RuntimeError as exc:
        raise JobFailed(f"{field}: {exc}") from None
    return mi.load_dict(
        {
            "type": BTF_MODEL_NAME,
            "model": str(model_path),
            "textures": str(textures_path),
            **_scale_props(value),
        }
    )


register_material_source(
    "btf",
    resolve_btf,
    value_type=JobRef,
    siblings=BtfSiblings,
    summary="A BTF's slices as a table (bilinear in space, barycentric between measured "
    "directions): {'btf': 'job:<generate.btf or import.btf id>', optional 'uv_scale': s or "
    "[s_u, s_v]}; at most 2 GiB of float32.",
)
