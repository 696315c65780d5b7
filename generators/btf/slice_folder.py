"""A BTF job's slices as a folder of slice images, the layout ``import.btf`` reads
(:mod:`storage.formats.btf_folder`): ``images/slice_XXX.exr`` (linear RGB, float32) and
``angles.csv`` with each image's ``theta_i, phi_i, theta_o, phi_o`` in degrees.

With it a small ``generate.btf`` job becomes a measured-looking input for ``import.btf``
(the dashboard's browser test and its screenshots use one); the import reads it back bit
for bit (EXR float32 is lossless).
"""

from __future__ import annotations

import csv
import tempfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from storage.artifacts import ArtifactStore
from storage.formats.btf import parse_index, read_shard
from storage.formats.btf_folder import COLUMNS
from storage.formats.exr import exr_bytes
from storage.jobs import ArtifactRecord


def write_slice_folder(folder: Path, rgb: np.ndarray, angles: Sequence[Sequence[float]]) -> Path:
    """Write ``rgb`` (``(N, H, W, 3)`` linear) as ``folder/images/slice_XXX.exr`` and
    ``folder/angles.csv`` (``angles``: ``N`` rows of ``theta_i, phi_i, theta_o, phi_o``
    degrees); returns ``folder``. Raises ``ValueError`` when the counts differ."""
    if len(rgb) != len(angles):
        raise ValueError(f"{len(rgb)} slice images but {len(angles)} angle rows")
    (folder / "images").mkdir(parents=True, exist_ok=True)
    rows = []
    for k, (image, a) in enumerate(zip(rgb, angles, strict=True)):
        name = f"images/slice_{k:03d}.exr"
        (folder / name).write_bytes(exr_bytes(np.asarray(image)))
        rows.append([name, *(float(x) for x in a)])
    with open(folder / "angles.csv", "w", newline="", encoding="utf-8") as fh:
        writer = csv.writer(fh, lineterminator="\n")
        writer.writerow(COLUMNS)
        writer.writerows(rows)
    return folder


def job_slice_folder(
    artifacts: Sequence[ArtifactRecord], store: ArtifactStore, folder: Path
) -> Path:
    """The slices of a BTF job (its ``btf.json`` and shards, e.g. ``generate.btf``'s) as a
    slice folder at ``folder`` (:func:`write_slice_folder`); returns ``folder``."""
    digests = {a.name: a.digest for a in artifacts}
    if "btf.json" not in digests:
        raise ValueError("the job has no btf.json: not a BTF job")
    index = parse_index(store.read(digests["btf.json"]))
    parts = []
    with tempfile.TemporaryDirectory(prefix="matforge-btf-") as tmp:
        for name, _ in index.shards:
            path = Path(tmp) / name
            path.write_bytes(store.read(digests[name]))
            parts.append(read_shard(path, name).rgb)
    return write_slice_folder(folder, np.concatenate(parts), index.doc["directions"])
