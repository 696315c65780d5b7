"""Training data of ``train.fabric``: a ``generate.fabric`` job's shards, maps and materials.

Source: ``dataset: "job:<id>"`` (in a batch file ``step:<name>``, which resolves to it), a
succeeded ``generate.fabric`` job. As ``train.brdf`` reads a ``generate.merl`` job, its
``materials.json`` lists every material, and the sibling artifacts it names are read
through the job's refs: ``shard-XXXX.npz`` (``material, center, size, wi, wo, value,
stderr``, layout in :mod:`generators.fabric.kind`), ``maps/<name>-normal.exr`` and
``maps/<name>-orientation.exr`` (read with :func:`storage.formats.exr.read_exr`, then
resampled to the network's ``map_resolution`` by :func:`models.fabric.networks.map_tensor`).

Held-out queries: per material a fixed fraction is set aside for ``metrics.json`` and never
trained on. The choice is a permutation seeded by :data:`HOLDOUT_SEED` and the material's
name, independent of the job's seed, so models trained with different seeds are scored on
the same queries. (Not every k-th query: the design is Latin-hypercube stratified per
factor, so a stride would pick particular size strata.)
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from jobapi.documents import DocumentError, check_typed
from jobapi.errors import JobFailed
from models.fabric.networks import map_tensor, param_vector
from storage.errors import FormatError
from storage.formats.exr import read_exr
from storage.formats.fabric_documents import FabricMaterial, FabricMaterials
from storage.formats.npz import read_npz

if TYPE_CHECKING:
    from jobapi.context import JobContext

#: Seed of the held-out split (with a hash of the material's name).
HOLDOUT_SEED = 0x5EED_FAB
#: The component order a dataset must declare (Eq. 7).
DATASET_COMPONENTS = ["C_warp", "C_weft", "S_warp", "S_weft"]
_KEYS = ("material", "center", "size", "wi", "wo", "value")


@dataclass(frozen=True, eq=False)
class MaterialData:
    """One material of the dataset.

    ``query`` is ``(N, 8)`` float32 ``cx, cy, size, wi.x, wi.y, wi.z, wo.x, wo.y`` (tile
    units, macro frame); ``value`` ``(N, 4)`` float32 components (Eq. 7, unit albedos);
    ``train`` and ``test`` index rows; ``stderr`` ``(N, 4)`` float32 the values' Monte
    Carlo standard errors (``None`` where the shards lack them); ``maps`` ``(6, R, R)``;
    ``params`` ``(5,)``
    (:data:`models.fabric.networks.PARAM_NAMES`); ``record`` the ``materials.json`` params.
    """

    name: str
    pattern: str
    record: dict[str, Any]
    maps: np.ndarray
    params: np.ndarray
    query: np.ndarray
    value: np.ndarray
    train: np.ndarray
    test: np.ndarray
    stderr: np.ndarray | None = None
    #: Side of the dataset's own maps (before :func:`map_tensor` resampled them).
    map_source_resolution: int | None = None
    #: ``(N,)`` each kept row's index among the material's shard rows (``None``: unknown).
    rows: np.ndarray | None = None
    #: ``materials.json``'s ``split`` (``train``, ``unseen_material``, ``unseen_pattern``);
    #: ``None`` in a dataset without held-out sets.
    split: str | None = None

    def albedos(self) -> np.ndarray:
        """``(4, 3)`` albedos of Eq. 8: rows kd_warp, kd_weft, ks_warp, ks_weft."""
        r = self.record
        return np.array([r["kd_warp"], r["kd_weft"], r["ks_warp"], r["ks_weft"]], np.float64)


def holdout_split(name: str, n: int, fraction: float) -> tuple[np.ndarray, np.ndarray]:
    """``(train, test)`` sorted row indices; ``round(fraction n)`` rows (at least 1 when
    ``fraction > 0`` and ``n >= 2``) held out, chosen by :data:`HOLDOUT_SEED` and ``name``."""
    tag = int.from_bytes(hashlib.sha256(name.encode()).digest()[:8], "little")
    perm = np.random.default_rng([HOLDOUT_SEED, tag]).permutation(n)
    k = int(round(fraction * n))
    if fraction > 0 and n >= 2:
        k = min(max(k, 1), n - 1)
    return np.sort(perm[k:]), np.sort(perm[:k])


def _job_materials(ctx: JobContext, job_id: str) -> list[FabricMaterial]:
    """The materials of a ``generate.fabric`` job's ``materials.json``
    (:class:`~storage.formats.fabric_documents.FabricMaterials`); :class:`JobFailed` naming
    the field if it is not of that type."""
    ctx.input_job(job_id, "dataset", "generate.fabric")
    name = f"job:{job_id}/materials.json"
    raw = json.loads(ctx.read_ref(name))
    try:
        check_typed(name, raw, FabricMaterials)
    except DocumentError as exc:
        raise JobFailed(f"dataset: {exc}") from None
    doc = cast(FabricMaterials, raw)
    if doc["components"] != DATASET_COMPONENTS:
        raise JobFailed(f"dataset: job {job_id}'s components are not {DATASET_COMPONENTS}")
    if not doc["materials"]:
        raise JobFailed(f"dataset: job {job_id} lists no materials")
    return doc["materials"]


def _read_shard(ctx: JobContext, ref: str, index: int) -> dict[str, np.ndarray]:
    try:
        arrays = read_npz(ctx.resolve(ref), ref)
    except FormatError as exc:
        raise JobFailed(f"dataset: {exc}") from None
    missing = [k for k in _KEYS if k not in arrays]
    if missing:
        raise JobFailed(f"dataset: {ref} lacks arrays {', '.join(missing)}")
    if not np.all(arrays["material"] == index):
        raise JobFailed(f"dataset: {ref} holds queries of another material than #{index}")
    return arrays


def _read_map(ctx: JobContext, ref: str) -> np.ndarray:
    try:
        return read_exr(ctx.resolve(ref), ref)
    except FormatError as exc:
        raise JobFailed(f"dataset: {exc}") from None


def subsample(name: str, rows: np.ndarray, cap: int | None) -> np.ndarray:
    """At most ``cap`` of ``rows`` (sorted), a fixed-seed uniform choice; all if ``cap`` is
    ``None`` or not smaller (Sec. 5.2: "about 160 million queries out of the entire data")."""
    if cap is None or len(rows) <= cap:
        return rows
    tag = int.from_bytes(hashlib.sha256(name.encode()).digest()[:8], "little")
    rng = np.random.default_rng([HOLDOUT_SEED, tag, 1])
    return np.sort(rng.choice(rows, size=cap, replace=False))


def load_dataset(
    dataset: str,
    ctx: JobContext,
    resolution: int,
    holdout_fraction: float,
    train_queries: int | None = None,
) -> list[MaterialData]:
    """Every material of the ``generate.fabric`` job ``dataset`` (``job:<id>``), in order.

    ``train_queries`` caps the training queries kept per material (:func:`subsample`); the
    held-out queries are chosen first, from all of them. Only kept rows stay in memory.

    Raises :class:`JobFailed` for a missing, unfinished or other-kind job, unreadable or
    inconsistent shards or maps.
    """
    job_id = dataset.removeprefix("job:")
    out = []
    for i, rec in enumerate(_job_materials(ctx, job_id)):
        ctx.check_cancelled()
        shards = [_read_shard(ctx, f"job:{job_id}/{s}", i) for s in rec["shards"]]
        if not shards:
            raise JobFailed(f"dataset: material {rec['name']!r} has no shards")
        cat = {k: np.concatenate([s[k] for s in shards]) for k in _KEYS}
        has_se = all("stderr" in s for s in shards)
        se = np.concatenate([s["stderr"] for s in shards]) if has_se else None
        query = np.concatenate(
            [cat["center"], cat["size"][:, None], cat["wi"], cat["wo"][:, :2]], axis=1
        ).astype(np.float32)
        normal = _read_map(ctx, f"job:{job_id}/{rec['maps']['normal']}")
        orientation = _read_map(ctx, f"job:{job_id}/{rec['maps']['orientation']}")
        train, test = holdout_split(rec["name"], len(query), holdout_fraction)
        train = subsample(rec["name"], train, train_queries)
        keep = np.concatenate([train, test])
        query, value = query[keep], cat["value"][keep]
        train, test = np.arange(len(train)), np.arange(len(train), len(keep))
        out.append(
            MaterialData(
                name=rec["name"],
                pattern=rec["pattern"],
                record=rec["params"],
                maps=map_tensor(normal, orientation, resolution),
                params=param_vector(rec["params"]),
                query=query,
                value=value.astype(np.float32),
                train=train,
                test=test,
                stderr=None if se is None else se[keep].astype(np.float32),
                map_source_resolution=int(normal.shape[0]),
                rows=keep,
                split=rec.get("split"),
            )
        )
    return out
