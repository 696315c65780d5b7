"""``import.btf`` of a Bonn ``.btf`` file (UBO2014's own DFMF files, or FMF): the slices
are reconstructed from the factor matrices a few at a time (:mod:`storage.formats.ubo_btf`)
and streamed into the same ``slices-XXXX.npz`` shards as a folder of images gives.

Slices keep the file's order (views outermost, lights inner); the directions are the
file's own (UBO2014: its 151-direction dome for both light and view).
"""

from __future__ import annotations

import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from materials.btf.directions import to_vector
from storage.formats.btf import write_shard
from storage.formats.ubo_btf import GROUP, UboBtf, UboHeader


@dataclass(frozen=True)
class UboTask:
    """One shard of a Bonn ``.btf``: slices ``lo .. hi - 1`` in the file's order."""

    archive: str
    label: str
    lo: int
    hi: int
    scale: float
    dtype: str
    cosine_in_data: bool | None = None


def directions(header: UboHeader) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(angles (N, 4) degrees, wi (N, 3), wo (N, 3))`` of every slice, in order."""
    angles = header.angles_deg()
    return angles, to_vector(angles[:, 0], angles[:, 1]), to_vector(angles[:, 2], angles[:, 3])


def convert_ubo_shard(task: UboTask) -> bytes:
    """The shard's ``.npz`` bytes; memory holds ``GROUP`` decoded slices at a time."""
    btf = UboBtf(Path(task.archive), task.label)
    h = btf.header
    _, wi, wo = directions(h)
    scale = np.float32(task.scale)

    def slices() -> Iterator[np.ndarray]:
        for g in range(task.lo, task.hi, GROUP):
            group = btf.decode(
                range(g, min(g + GROUP, task.hi)), cosine_in_data=task.cosine_in_data
            )
            group *= scale
            yield from group
            del group

    stderr = np.full(task.hi - task.lo, np.nan, np.float32)
    with tempfile.TemporaryFile() as fh:
        write_shard(fh, wi[task.lo : task.hi], wo[task.lo : task.hi], slices(),
                    (h.height, h.width), stderr, task.dtype)  # fmt: skip
        fh.seek(0)
        return fh.read()
