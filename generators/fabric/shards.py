"""The shards of ``generate.fabric``: one task per ``shard_queries`` queries of a material.

:func:`estimate_shard` designs a shard's queries (:mod:`generators.fabric.queries`, or
:mod:`generators.fabric.scene_queries` with a scene), estimates them with
:func:`materials.fabric.aggregate.estimate` and returns the ``.npz`` bytes documented in
:mod:`generators.fabric.kind`; :func:`estimate_shards` runs them through the job's executor
in batches, each shard stored once as its artifact.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from generators.fabric.params import REPLICATES
from generators.fabric.queries import design_queries
from generators.fabric.scene_queries import SceneDesign, scene_queries
from materials.fabric.aggregate import FootprintQueries, estimate
from materials.fabric.params import FabricParams
from materials.fabric.yarn import YarnGeometry
from storage.formats.npz import npz_bytes

if TYPE_CHECKING:
    from jobapi.context import JobContext


@dataclass(frozen=True)
class ShardTask:
    """One shard: queries ``first .. first + count - 1`` of material ``material``."""

    material: int
    params: FabricParams
    design_seed: int
    first: int
    count: int
    btdf_fraction: float
    samples: int
    sampler: str
    sample_seed: int
    backend: str
    sizes: str = "strata"
    scene: SceneDesign | None = None


def _queries(task: ShardTask) -> Any:
    """The shard's queries: the scene's (:mod:`generators.fabric.scene_queries`) or the
    Sec. 5.1 design's (:mod:`generators.fabric.queries`)."""
    if task.scene is not None:
        tw, th = YarnGeometry.from_params(task.params).tile
        return scene_queries(
            task.scene, task.design_seed, task.first, task.count, tile_aspect=tw / th
        )
    return design_queries(
        task.design_seed, task.first, task.count, btdf_fraction=task.btdf_fraction,
        sizes=task.sizes,
    )  # fmt: skip


def estimate_shard(task: ShardTask) -> bytes:
    """Shard function: design and estimate the queries; the shard's ``.npz`` bytes."""
    q = _queries(task)
    # Store float32 and estimate at exactly the stored values.
    centre, size = q.centre.astype(np.float32), q.size.astype(np.float32)
    wi, wo = q.wi.astype(np.float32), q.wo.astype(np.float32)
    est = estimate(
        task.params,
        FootprintQueries(centre, size, wi, wo),
        samples=task.samples,
        sampler=task.sampler,  # type: ignore[arg-type]
        seed=task.sample_seed,
        replicates=REPLICATES,
        backend=task.backend,  # type: ignore[arg-type]
    )
    return npz_bytes(
        {
            "material": np.full(task.count, task.material, dtype=np.int32),
            "center": centre,
            "size": size,
            "wi": wi,
            "wo": wo,
            "value": est.mean.astype(np.float32),
            "stderr": est.stderr.astype(np.float32),
        }
    )


def estimate_shards(tasks: list[ShardTask], batch_shards: int, ctx: JobContext) -> None:
    """Estimate and store every shard, ``batch_shards`` per executor call (progress
    0.02 - 0.95)."""
    for lo in range(0, len(tasks), batch_shards):
        batch = tasks[lo : lo + batch_shards]
        hi = lo + len(batch)
        # Each shard is stored once, as its npz artifact, which is also its shard record
        # (a re-run after a crash registers the stored shards again instead of computing
        # them); no pickled copy of the result beside it.
        ctx.map_artifact_shards(
            estimate_shard,
            batch,
            [f"shard-{i:04d}.npz" for i in range(lo, hi)],
            media_type="application/x-npz",
            label="shard",
            progress_range=(0.02 + 0.93 * lo / len(tasks), 0.02 + 0.93 * hi / len(tasks)),
        )
