"""A BTF dataset (a ``generate.btf`` or ``import.btf`` job) as slices for training and
scoring.

Source: ``data: "job:<id>"`` (in a batch file ``step:<name>``), a succeeded job whose
``btf.json`` lists its ``slices-XXXX.npz`` shards (:mod:`storage.formats.btf`). Slices
come back as float32 ``(H, W, 3)``; when the whole BTF fits in :data:`MEMORY_LIMIT` bytes
it is loaded once, otherwise every pass streams the shards one at a time (a paper-scale
BTF is tens of gigabytes).

Held-out slices: a fixed fraction of the slices, chosen by a permutation seeded with
:data:`HOLDOUT_SEED` alone (not the job's seed), so models trained with different seeds and
settings are scored on the same slices.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from jobapi.errors import JobFailed
from jobapi.params import job_id_of
from storage.errors import FormatError
from storage.formats.btf import BtfIndex, Shard, iter_shards, parse_index, read_shard

if TYPE_CHECKING:
    from jobapi.context import JobContext

#: Seed of the held-out split.
HOLDOUT_SEED = 0xB7F_5EED
#: Largest BTF (float32 bytes) kept in memory; larger ones stream.
MEMORY_LIMIT = 4 * 2**30
BTF_KINDS = ("generate.btf", "import.btf")


@dataclass
class BtfDataset:
    """The slices of one BTF job: ``wi``, ``wo`` ``(N, 3)`` float32, ``resolution``
    ``(H, W)``, the index, and (when small) every slice in memory."""

    ref: str
    index: BtfIndex
    wi: np.ndarray
    wo: np.ndarray
    ctx: JobContext
    job_id: str
    slices: np.ndarray | None = field(default=None, repr=False)

    @property
    def resolution(self) -> tuple[int, int]:
        return self.index.resolution

    def __len__(self) -> int:
        return self.index.count

    @classmethod
    def open(cls, ref: str, ctx: JobContext, field_name: str = "data") -> BtfDataset:
        """Open (and check) the BTF of the job ``ref`` names; ``JobFailed`` naming
        ``field_name`` if it is not a succeeded BTF job or its files are malformed."""
        job_id = job_id_of(ref)
        job = ctx.input_job(job_id, field_name)
        if job.kind not in BTF_KINDS:
            raise JobFailed(f"{field_name}: job {job_id} is a {job.kind} job, not a BTF")
        try:
            index = parse_index(ctx.read_ref(f"job:{job_id}/btf.json"))
        except FormatError as exc:
            raise JobFailed(f"{field_name}: {exc}") from None
        ds = cls(ref=ref, index=index, wi=np.empty((0, 3)), wo=np.empty((0, 3)), ctx=ctx,
                 job_id=job_id)  # fmt: skip
        wis, wos, parts = [], [], []
        small = index.count * index.resolution[0] * index.resolution[1] * 12 <= MEMORY_LIMIT
        for _, shard in ds._shards():
            wis.append(shard.wi)
            wos.append(shard.wo)
            if small:
                parts.append(shard.rgb.astype(np.float32))
        ds.wi = np.concatenate(wis).astype(np.float32)
        ds.wo = np.concatenate(wos).astype(np.float32)
        if small:
            ds.slices = np.concatenate(parts)
        return ds

    def _shards(self) -> Iterator[tuple[int, Shard]]:
        try:
            yield from iter_shards(
                self.index, lambda name: self.ctx.resolve(f"job:{self.job_id}/{name}")
            )
        except FormatError as exc:
            raise JobFailed(f"data: {exc}") from None

    def iter_slices(
        self, indices: np.ndarray, rng: np.random.Generator | None = None
    ) -> Iterator[tuple[int, np.ndarray]]:
        """``(index, slice (H, W, 3) float32)`` for each of ``indices``: in a random order
        drawn from ``rng`` (else in order). Streamed BTFs shuffle the shards and the slices
        within each shard, reading one shard at a time."""
        idx = np.asarray(indices, np.int64)
        if self.slices is not None:
            for i in idx if rng is None else rng.permutation(idx):
                yield int(i), self.slices[int(i)]
            return
        starts = np.cumsum([0] + [c for _, c in self.index.shards])
        owner = np.searchsorted(starts, idx, side="right") - 1
        shard_ids = np.unique(owner)
        for k in shard_ids if rng is None else rng.permutation(shard_ids):
            name = self.index.shards[int(k)][0]
            try:
                shard = read_shard(self.ctx.resolve(f"job:{self.job_id}/{name}"), name)
            except FormatError as exc:
                raise JobFailed(f"data: {exc}") from None
            mine = idx[owner == k]
            for i in mine if rng is None else rng.permutation(mine):
                yield int(i), shard.rgb[int(i - starts[k])].astype(np.float32)

    def split(self, holdout: float) -> tuple[np.ndarray, np.ndarray]:
        """``(train, test)`` slice indices: ``holdout`` of them (at least one, at most all
        but one) held out by the fixed permutation."""
        n = len(self)
        k = min(max(1, int(round(holdout * n))), n - 1) if n > 1 and holdout > 0 else 0
        perm = np.random.default_rng(HOLDOUT_SEED).permutation(n)
        return np.sort(perm[k:]), np.sort(perm[:k])
