"""Training data of ``train.brdf``: MERL tables, cosine-weighted pair batches, family splits.

Sources: a ``generate.merl`` job (``job:<id>``: every table listed in its ``materials.json``,
with names and families from there) or a list of table refs (``job:<id>/<name>.binary`` or
``sha256:...``; the family comes from the producing job's ``materials.json`` when it lists
the artifact, else ``"custom"``).

Batches (Sec. 3.3 of the hybrid-BRDF paper): at every step each material gets ``B`` pairs
``(wi, wo)``, independent and each cosine-weighted on the upper hemisphere (Malley's method,
as :func:`evaluators.metrics.brdf.direction_pairs`, but from the job's own generator). The
targets come from :func:`lookup_tables`, a torch twin of :func:`materials.halfdiff.lookup`
with ``interpolate=True`` (the reconstruction that ``score`` and ``metrics.json`` use): the
Rusinkiewicz angles and MERL coordinates are the shared generic formulas of
:mod:`materials.halfdiff` called with torch ops; only the multilinear gather is re-written
(tested against the numpy lookup).
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import PurePosixPath
from typing import TYPE_CHECKING, Any, cast

import numpy as np
import torch
from torch import Tensor

from jobapi.documents import DocumentError, check_typed
from jobapi.errors import JobFailed
from jobapi.params import JOB_REF
from materials import halfdiff as hd
from storage.errors import FormatError
from storage.formats.merl import MerlTable, merl_from_bytes
from storage.formats.merl_materials import MerlMaterial, MerlMaterials

if TYPE_CHECKING:
    from jobapi.context import JobContext


def _maximum(a: Any, b: Any) -> Any:
    return torch.clamp_min(a, b) if isinstance(b, int | float) else torch.maximum(a, b)


def _minimum(a: Any, b: Any) -> Any:
    return torch.clamp_max(a, b) if isinstance(b, int | float) else torch.minimum(a, b)


#: :class:`materials.halfdiff.ArrayOps` of torch, for the shared generic formulas.
TORCH_OPS = hd.ArrayOps(
    torch.sqrt, torch.atan2, torch.cos, torch.sin, torch.floor, _minimum, _maximum, torch.where
)


@dataclass(frozen=True, eq=False)
class MaterialTable:
    """One training material: ``name``, ``family``, its table and where it came from."""

    name: str
    family: str
    table: MerlTable
    ref: str


# -- loading -----------------------------------------------------------------------------------


def _job_materials(ctx: JobContext, job_id: str) -> list[MerlMaterial] | None:
    """The ``materials`` of a job's ``materials.json`` (a ``generate.merl`` job's,
    :class:`~storage.formats.merl_materials.MerlMaterials`), or ``None`` if it has none;
    :class:`JobFailed` naming the field if it is not of that type."""
    job = ctx.input_job(job_id, "dataset")
    if "materials.json" not in {a.name for a in job.artifacts}:
        return None
    doc = json.loads(ctx.read_ref(f"job:{job_id}/materials.json"))
    try:
        check_typed(f"job:{job_id}/materials.json", doc, MerlMaterials)
    except DocumentError as exc:
        raise JobFailed(f"dataset: {exc}") from None
    return cast(MerlMaterials, doc)["materials"]


def _read_table(ctx: JobContext, ref: str, label: str) -> MerlTable:
    try:
        return merl_from_bytes(ctx.read_ref(ref), label)
    except FormatError as exc:
        raise JobFailed(f"dataset: {exc}") from None


def load_dataset(dataset: str | Sequence[str], ctx: JobContext) -> list[MaterialTable]:
    """Read every table of ``dataset`` (``job:<id>`` or a list of refs), in order.

    Raises :class:`JobFailed` for a missing or unfinished job, a job without
    ``materials.json`` (``job:<id>`` form), an unreadable table, or a mix of phi_d layouts.
    """
    out: list[MaterialTable] = []
    if isinstance(dataset, str):
        job_id = dataset.removeprefix("job:")
        records = _job_materials(ctx, job_id)
        if not records:
            raise JobFailed(
                f"dataset: job {job_id} lists no materials (a generate.merl job has "
                "materials.json); give a list of table refs instead"
            )
        for rec in records:
            ref = f"job:{job_id}/{rec['artifacts']['table']}"
            out.append(MaterialTable(rec["name"], rec["family"], _read_table(ctx, ref, ref), ref))
    else:
        families: dict[str, dict[str, str]] = {}
        for ref in dataset:
            ctx.check_cancelled()
            name, family = _name_from_ref(ctx, ref, families)
            out.append(MaterialTable(name, family, _read_table(ctx, ref, ref), ref))
    _dedupe_names(out)
    bins = {m.table.phi_d_bins for m in out}
    if len(bins) > 1:
        raise JobFailed(f"dataset: tables mix phi_d layouts {sorted(bins)}; use one")
    return out


def _name_from_ref(ctx: JobContext, ref: str, cache: dict[str, dict[str, str]]) -> tuple[str, str]:
    m = JOB_REF.match(ref)
    if not m:
        rec = ctx.ref_record(ref)
        return PurePosixPath(rec.name).stem or rec.digest[:12], "custom"
    artifact = m["name"]
    if m["job"] not in cache:
        records = _job_materials(ctx, m["job"]) or []
        cache[m["job"]] = {
            a: r["family"]
            for r in records
            for a in (
                r["artifacts"]["table"],
                r["artifacts"]["picture"],
                r["artifacts"].get("truth"),
            )
            if a is not None
        }
    stem = str(PurePosixPath(artifact).with_suffix("")).replace("/", "-")
    return stem, cache[m["job"]].get(artifact, "custom")


def _dedupe_names(materials: list[MaterialTable]) -> None:
    seen: dict[str, int] = {}
    for i, m in enumerate(materials):
        k = seen.get(m.name, 0)
        seen[m.name] = k + 1
        if k:
            materials[i] = MaterialTable(f"{m.name}-{k + 1}", m.family, m.table, m.ref)


def split_by_family(
    materials: Sequence[MaterialTable], holdout_families: Sequence[str]
) -> tuple[list[MaterialTable], list[MaterialTable]]:
    """``(train, held_out)``: materials whose family is in ``holdout_families`` are held out
    (Table 3 of the paper holds out half of each material type; here whole families).

    Raises :class:`JobFailed` for a family that no material has, or when nothing is left to
    train on.
    """
    present = sorted({m.family for m in materials})
    unknown = sorted(set(holdout_families) - set(present))
    if unknown:
        raise JobFailed(
            f"holdout_families: no material of family {', '.join(unknown)}; the dataset "
            f"has {', '.join(present)}"
        )
    held = [m for m in materials if m.family in holdout_families]
    train = [m for m in materials if m.family not in holdout_families]
    if not train:
        raise JobFailed("holdout_families: every material is held out; nothing to train on")
    return train, held


def stack_tables(materials: Sequence[MaterialTable], device: str = "cpu") -> Tensor:
    """``(M, 90, 90, P, 3)`` float32 tensor of the tables (negative = missing)."""
    return torch.stack([torch.from_numpy(m.table.rgb.astype(np.float32)) for m in materials]).to(
        device
    )


# -- pairs and lookup ----------------------------------------------------------------------------


def cosine_pairs(
    m: int, b: int, generator: torch.Generator, device: str = "cpu"
) -> tuple[Tensor, Tensor]:
    """``(M, B, 3)`` float64 ``wi``, ``wo``: independent, each with pdf ``cos(theta) / pi``.

    Malley's method, ``z = sqrt(1 - u1)``, ``r = sqrt(u1)``, ``phi = 2 pi u2``, from one
    ``(4, M, B)`` draw of ``generator`` (rows 0-1 make ``wi``, rows 2-3 ``wo``).
    """
    u = torch.rand((4, m, b), generator=generator, dtype=torch.float64).to(device)

    def hemisphere(u1: Tensor, u2: Tensor) -> Tensor:
        z = torch.sqrt(1.0 - u1)
        r = torch.sqrt((1.0 - z * z).clamp_min(0.0))
        phi = (2.0 * math.pi) * u2
        return torch.stack([r * torch.cos(phi), r * torch.sin(phi), z], dim=-1)

    return hemisphere(u[0], u[1]), hemisphere(u[2], u[3])


def lookup_tables(tables: Tensor, wi: Tensor, wo: Tensor) -> Tensor:
    """Multilinear lookup of table ``m`` at pairs ``wi[m]``, ``wo[m]``.

    Torch twin of ``materials.halfdiff.lookup(..., interpolate=True)``: same coordinates
    (the shared generic formulas), clamped theta edges, periodic phi_d, missing corners
    weighted zero and the rest renormalised; ``-1`` where all eight corners are missing.

    ``tables``: ``(M, 90, 90, P, 3)``; ``wi``, ``wo``: ``(M, B, 3)`` float64 above the
    horizon. Returns ``(M, B, 3)`` in the tables' dtype.
    """
    m_count, _, _, n_p, _ = tables.shape
    theta_h, _, theta_d, phi_d = hd.halfdiff_components(
        wi[..., 0], wi[..., 1], wi[..., 2], wo[..., 0], wo[..., 1], wo[..., 2], TORCH_OPS
    )
    u_h, u_d, u_p = hd.merl_coordinates(theta_h, theta_d, phi_d, n_p, TORCH_OPS)
    corners = []  # per axis: (M, B, 2) indices and weights of the two neighbouring centres
    for u, n, periodic in (
        (u_h, hd.RES_THETA_H, False),
        (u_d, hd.RES_THETA_D, False),
        (u_p, n_p, True),
    ):
        p = u - 0.5  # bin centres sit at integer p
        i0f = torch.floor(p)
        w1 = p - i0f
        i = torch.stack([i0f, i0f + 1.0], dim=-1).long()
        i = i % n if periodic else i.clamp(0, n - 1)
        corners.append((i, torch.stack([1.0 - w1, w1], dim=-1)))
    (ih, wh), (id_, wd), (ip, wp) = corners
    material = torch.arange(m_count, device=wi.device).reshape(-1, 1, 1, 1, 1)
    idx = (
        (material * hd.RES_THETA_H + ih[..., :, None, None]) * hd.RES_THETA_D
        + id_[..., None, :, None]
    ) * n_p + ip[..., None, None, :]
    # Coordinates in float64 (bin edges), weights and values in the tables' dtype.
    weight = (wh[..., :, None, None] * wd[..., None, :, None] * wp[..., None, None, :]).reshape(
        *wi.shape[:-1], 8, 1
    )
    values = tables.reshape(-1, 3).index_select(0, idx.reshape(-1))
    values = values.reshape(*wi.shape[:-1], 8, 3)
    weight = torch.where(values >= 0, weight.to(values.dtype), 0.0)
    acc = (weight * values.clamp_min(0.0)).sum(dim=-2)
    wsum = weight.sum(dim=-2)
    return torch.where(wsum > 0, acc / wsum.clamp_min(1e-30), hd.MISSING)


@dataclass
class Batch:
    """One step's data: ``wi``, ``wo`` ``(M, B, 3)`` and ``reference`` ``(M, B, 3)`` in the
    model's dtype, ``cos_i`` ``(M, B, 1)``, ``valid`` ``(M, B)`` (reference has data)."""

    wi: Tensor
    wo: Tensor
    reference: Tensor
    cos_i: Tensor
    valid: Tensor


def draw_batch(
    tables: Tensor, pairs: int, generator: torch.Generator, dtype: torch.dtype = torch.float32
) -> Batch:
    """``pairs`` cosine-weighted pairs per material and their table values (Sec. 3.3)."""
    wi, wo = cosine_pairs(tables.shape[0], pairs, generator, str(tables.device))
    ref = lookup_tables(tables, wi, wo)
    valid = (ref >= 0).all(dim=-1)
    return Batch(
        wi=wi.to(dtype),
        wo=wo.to(dtype),
        reference=ref.to(dtype),
        cos_i=wi[..., 2:3].to(dtype),
        valid=valid,
    )
