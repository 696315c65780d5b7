"""``import.btf``: a folder of measured BTF slices (EXR or PNG images plus their angles),
uploaded as a ``.btf.zip``, or a Bonn ``.btf`` file (UBO2014's own DFMF files, or FMF;
:mod:`generators.btf.import_ubo`), turned into the shard layout of ``generate.btf``.

The folder's layout and checks are :mod:`storage.formats.btf_folder`'s (the upload route
runs the same checks, so a malformed archive is refused before it enters the store). The
CLI packs a directory for you: ``matforge import path/to/folder`` uploads
``folder.btf.zip``. Slices keep the list's order; each shard is converted in a worker and
kept when done (resumable). Artifacts: ``slices-XXXX.npz`` (``stderr`` is NaN: a
measurement's error is not known), ``btf.json``, ``preview.png``.
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal

import numpy as np
from pydantic import Field

from generators.btf.import_ubo import UboTask, convert_ubo_shard, directions
from generators.btf.kind import summarize
from generators.btf.preview import PreviewCollector
from jobapi.errors import FormatError, JobFailed, TooLargeError
from jobapi.kinds import Figure, Kind, register
from jobapi.params import Ref, StoredAs, StrictModel
from materials.btf.directions import check_pairs, pair_count_label, to_vector
from storage.formats.btf import BtfIndexDocument, index_document, shard_name, write_shard
from storage.formats.btf_folder import SliceEntry, SliceFolder
from storage.formats.npz import MAX_NPZ_BYTES
from storage.formats.ubo_btf import UboBtf, check_pixels

if TYPE_CHECKING:
    from jobapi.context import JobContext


#: What ``archive`` must have been stored as: the upload check of a ``.btf.zip`` (the slice
#: folder, :func:`storage.formats.btf_folder.validate_btf_archive`) or of a Bonn ``.btf``.
ARCHIVE = StoredAs(
    (".btf.zip", ".btf"),
    hint="upload the slice folder as '<name>.btf.zip' (`matforge import DIR` packs a folder) "
    "or a Bonn file as '<name>.btf'",
)


class ImportBtfParams(StrictModel):
    """Parameters of ``import.btf``.

    Example::

        {"kind": "import.btf", "params": {"archive": "sha256:<digest of leather.btf.zip>",
         "png": "srgb", "scale": 1.0}}
    """

    archive: Annotated[Ref, ARCHIVE] = Field(
        description="The slice folder as an uploaded '<name>.btf.zip' (`matforge import DIR` "
        "packs a directory): images plus angles.csv (file,theta_i,phi_i,theta_o,phi_o) or "
        "angles.json, angles in degrees; or an uploaded Bonn '<name>.btf' file (UBO2014's "
        "DFMF, or FMF). Only an object checked as one of these when it was stored is read: "
        "the store's record of its upload decides, not its bytes."
    )
    png: Literal["srgb", "linear"] = Field(
        default="srgb", description="How PNG slices are encoded: 'srgb' (decoded) or 'linear'."
    )
    scale: float = Field(
        default=1.0,
        gt=0.0,
        le=1e6,
        description="Factor from the images' values to the BTF (L_o / E_perp, 1/sr).",
    )
    shard_slices: int = Field(
        default=151,
        ge=1,
        le=151 * 151,
        description="Slices per shard. A shard holds at most 1 GiB (the shard readers' "
        "limit), so large slices need fewer per shard; the job says how many fit.",
    )
    dtype: Literal["float32", "float16"] = Field(
        default="float32", description="Stored type of the slices."
    )
    cosine: Literal["file", "in_data", "not_in_data"] = Field(
        default="file",
        description="Bonn .btf files only: whether the stored values already carry "
        "cos(theta_i). 'file' trusts the file's cosine flag; 'in_data' / 'not_in_data' "
        "override it (the slices are multiplied by cos(theta_i) when it is not in the data).",
    )


@dataclass(frozen=True)
class ImportTask:
    """One shard: which listed images to convert (picklable)."""

    archive: str
    label: str
    entries: tuple[SliceEntry, ...]
    png_srgb: bool
    scale: float
    dtype: str
    resolution: tuple[int, int]


def convert_shard(task: ImportTask) -> bytes:
    """The shard's ``.npz`` bytes: the listed images, scaled, with their directions.

    The slices are decoded one at a time and streamed into the shard file: memory holds
    one decoded slice and, at the end, the shard's bytes, never a stack of decoded
    slices (three 8192 x 4096 slices used to take several gigabytes)."""
    scale = np.float32(task.scale)

    def slices(folder: SliceFolder) -> Iterator[np.ndarray]:
        for e in task.entries:
            rgb = folder.read(e, png_srgb=task.png_srgb)
            rgb *= scale  # in place: the float32 product, as before, with no second image
            yield rgb
            del rgb

    angles = np.asarray([e.angles() for e in task.entries], np.float64)
    wi, wo = to_vector(angles[:, 0], angles[:, 1]), to_vector(angles[:, 2], angles[:, 3])
    stderr = np.full(len(task.entries), np.nan, np.float32)
    with SliceFolder(Path(task.archive), task.label) as folder, tempfile.TemporaryFile() as fh:
        folder.resolution = task.resolution
        write_shard(fh, wi, wo, slices(folder), task.resolution, stderr, task.dtype)
        fh.seek(0)
        return fh.read()


def check_shard_size(per: int, resolution: tuple[int, int], dtype: str) -> None:
    """Refuse, before decoding, shards bigger than a shard reader accepts
    (:data:`storage.formats.npz.MAX_NPZ_BYTES`): such a dataset could never be read back,
    and converting a shard holds its bytes in memory."""
    h, w = resolution
    # Per slice: its pixels, wi and wo (3 float32 each) and stderr (one float32); and the
    # four arrays' .npy headers, at most 256 bytes each.
    per_slice = h * w * 3 * np.dtype(dtype).itemsize + 28
    if per * per_slice + 4 * 256 > MAX_NPZ_BYTES:
        fits = max(0, (MAX_NPZ_BYTES - 4 * 256) // per_slice)
        raise JobFailed(
            f"shard_slices: a shard of {per} slices of {w}x{h} {dtype} holds about "
            f"{per * per_slice} bytes, over the {MAX_NPZ_BYTES} bytes a shard may hold; "
            + (f"use shard_slices <= {fits}" if fits else "the slices are too large")
        )


def run_import_btf(params: ImportBtfParams, ctx: JobContext) -> None:
    """Check the folder, convert its images shard by shard, write the index and preview.

    The archive is read as what its upload was checked as (``archive``'s :data:`ARCHIVE`:
    a slice folder for a ``.btf.zip``, a Bonn file for a ``.btf``), from the store's record,
    and refused naming the field when it was stored as anything else. Before any pixel is
    decoded: every image's header is read, and the pixels of all of them together must
    stay within the operator's cap (``ctx.limits.archive_pixels``,
    ``MATFORGE_ARCHIVE_MPIX``), whatever cap the archive was stored under; and a shard
    must fit the shard readers' limit."""
    stored_as, label = ctx.stored_format(params.archive, "archive", ARCHIVE)
    path = ctx.resolve(params.archive)
    if stored_as == ".btf":
        run_import_ubo(params, ctx, path, label)
        return
    try:
        with SliceFolder(path, label) as folder:
            resolution = folder.check_images(ctx.limits.archive_pixels)
            entries = list(folder.entries)
    except (FormatError, TooLargeError) as exc:
        raise JobFailed(f"archive: {exc}") from None
    check_shard_size(min(params.shard_slices, len(entries)), resolution, params.dtype)
    angles = np.asarray([e.angles() for e in entries], np.float64)
    wi, wo = to_vector(angles[:, 0], angles[:, 1]), to_vector(angles[:, 2], angles[:, 3])
    check_pairs(wi, wo, max_theta=89.0)
    per = params.shard_slices
    tasks = [
        ImportTask(
            archive=str(path), label=label, entries=tuple(entries[lo : lo + per]),
            png_srgb=params.png == "srgb", scale=params.scale, dtype=params.dtype,
            resolution=resolution,
        )
        for lo in range(0, len(entries), per)
    ]  # fmt: skip
    ctx.progress(0.0, f"{pair_count_label(len(entries))} of {resolution[1]}x{resolution[0]}")
    counts = [len(t.entries) for t in tasks]
    shards = Shards(convert_shard, tasks, counts, resolution, angles, wi, wo)
    _write(params, ctx, label, shards, files=[e.file for e in entries], png=params.png)


@dataclass(frozen=True)
class Shards:
    """What both sources (a folder, a Bonn ``.btf``) convert: the tasks, one per shard, the
    function that turns one into a shard's bytes, each shard's slice count, and the slices'
    directions (degrees ``(N, 4)`` and unit vectors ``(N, 3)``, float64)."""

    convert: Callable[[Any], bytes]
    tasks: Sequence[Any]
    counts: list[int]
    resolution: tuple[int, int]
    angles: np.ndarray
    wi: np.ndarray
    wo: np.ndarray


def _write(
    params: ImportBtfParams, ctx: JobContext, label: str, shards: Shards, **index: Any
) -> None:
    """Convert the shards (streamed to the store, the preview collected on the way), then
    write ``btf.json`` (with the source's own ``index`` keys) and ``preview.png``."""
    names = [shard_name(k) for k in range(len(shards.tasks))]
    preview = PreviewCollector(shards.counts, names, shards.resolution)
    try:
        ctx.map_artifact_shards(
            shards.convert, shards.tasks, names, media_type="application/x-npz",
            on_result=preview, label="shard", progress_range=(0.0, 0.95),
        )  # fmt: skip
    except FormatError as exc:
        raise JobFailed(f"archive: {exc}") from None
    doc = index_document(
        shards.resolution,
        list(zip(names, shards.counts, strict=True)),
        source="import.btf",
        archive=params.archive,
        archive_name=label,
        directions=np.round(shards.angles, 6).tolist(),
        scale=params.scale,
        dtype=params.dtype,
        stderr=None,
        **index,
    )
    ctx.put_json("btf.json", doc)
    count = sum(shards.counts)
    title = f"import.btf: {label}, {pair_count_label(count)}"
    ctx.put_bytes("preview.png", preview.png(shards.wi, shards.wo, title), "image/png")
    ctx.progress(1.0, f"{count} slices in {len(shards.tasks)} shards")


def run_import_ubo(params: ImportBtfParams, ctx: JobContext, path: Path, label: str) -> None:
    """:func:`run_import_btf` for a Bonn ``.btf``: header checked (and the decoded size
    against ``ctx.limits.archive_pixels``) before any slice is reconstructed."""
    try:
        btf = UboBtf(path, label)
        h = btf.header
        check_pixels(h, label, ctx.limits.archive_pixels)
    except (FormatError, TooLargeError) as exc:
        raise JobFailed(f"archive: {exc}") from None
    resolution = (h.height, h.width)
    check_shard_size(min(params.shard_slices, h.count), resolution, params.dtype)
    angles, wi, wo = directions(h)
    try:
        check_pairs(wi, wo, max_theta=89.0)
    except ValueError as exc:
        raise JobFailed(f"archive: {label}: {exc}") from None
    per = params.shard_slices
    cosine_in_data = {"file": None, "in_data": True, "not_in_data": False}[params.cosine]
    tasks = [
        UboTask(
            str(path), label, lo, min(lo + per, h.count), params.scale, params.dtype, cosine_in_data
        )  # fmt: skip
        for lo in range(0, h.count, per)
    ]
    ctx.progress(0.0, f"{label}: {h.variant}, {pair_count_label(h.count)} of "
                 f"{h.width}x{h.height}")  # fmt: skip
    shards = Shards(
        convert_ubo_shard, tasks, [t.hi - t.lo for t in tasks], resolution, angles, wi, wo
    )
    _write(
        params,
        ctx,
        label,
        shards,
        ubo={
            "variant": h.variant,
            "signature": h.signature,
            "color_model": h.color_model,
            "cosine_flag": h.cosine_flag,
            "cosine": params.cosine,
            "lights": len(h.lights),
            "views": len(h.views),
            "rgb_scale": list(h.rgb_scale),
            "channels": h.channels,
        },  # fmt: skip
    )


register(
    Kind(
        name="import.btf",
        params=ImportBtfParams,
        runner=run_import_btf,
        description="Measured BTF slices (a folder of EXR/PNG images with their angles, as "
        "a decompressed UBO2014 archive gives, or a Bonn .btf file: UBO2014's DFMF, or FMF) "
        "into generate.btf's shard layout.",
        artifacts=("slices-0000.npz", "btf.json", "preview.png"),
        documents={"btf.json": BtfIndexDocument},
        figures=(Figure("preview.png", caption="A few of the imported slices.", lead=True),),
        summary=summarize,
    )
)
